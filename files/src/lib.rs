//! # files: how Likeness writes files
//!
//! Owns the one way every file the project writes reaches the disk ([`write_atomically`],
//! [`write_atomically_with`]): the bytes go to a temporary file with a unique name in the
//! target's own folder (created exclusively, so two writers never share one), are synced,
//! renamed over the target and the folder is synced, so a reader, a crash, a kill or a
//! full disk never sees a partial file under the final name, and of two concurrent writers
//! the one that finishes last wins whole. A temporary left by a killed run is removed by the
//! next write to the same folder ([`remove_stale_temporaries`]). It also tells whether two
//! paths are one file ([`same_file`]), which the command line uses to refuse an output that
//! is one of its inputs.
//!
//! It must not know what it writes (no formats, no GPU, UI or inference); callers turn
//! [`WriteError`] into their own errors.
//!
//! Written on `std` alone: `tempfile` names its files without the writer's process id,
//! which is what tells a killed run's leftovers from another live writer's work.

use std::ffi::OsStr;
use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime};

/// Every temporary this crate makes ends with this.
pub const TEMPORARY_SUFFIX: &str = ".likeness-tmp";

/// Temporaries of writers that may still be running, or of older versions that put no
/// process id in the name, are removed only when older than this.
pub const STALE_AFTER: Duration = Duration::from_secs(15 * 60);

#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    #[error("cannot write {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot write {path}: the folder {folder} does not exist")]
    NoFolder { path: PathBuf, folder: PathBuf },
    #[error("cannot write {path}: it is not a file path")]
    NotAFile { path: PathBuf },
}

impl WriteError {
    /// The file that could not be written.
    pub fn path(&self) -> &Path {
        match self {
            Self::Io { path, .. } | Self::NoFolder { path, .. } | Self::NotAFile { path } => path,
        }
    }
}

/// Writes `bytes` to `path` atomically (see the crate documentation).
pub fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_atomically_with(path, |file| file.write_all(bytes))
}

/// Like [`write_atomically`], with `body` writing the content into the temporary file.
pub fn write_atomically_with(
    path: &Path,
    body: impl FnOnce(&mut File) -> std::io::Result<()>,
) -> Result<(), WriteError> {
    let io = |source| WriteError::Io {
        path: path.to_owned(),
        source,
    };
    // A page has no file system (std's process id would panic there); the browser build
    // hands files to the user as downloads instead.
    if cfg!(target_arch = "wasm32") {
        return Err(io(std::io::Error::new(
            std::io::ErrorKind::Unsupported,
            "a browser page cannot write files",
        )));
    }
    let name = path.file_name().ok_or_else(|| WriteError::NotAFile {
        path: path.to_owned(),
    })?;
    let folder = folder_of(path);
    if !folder.is_dir() {
        return Err(WriteError::NoFolder {
            path: path.to_owned(),
            folder: folder.to_owned(),
        });
    }
    remove_stale_temporaries(folder, name);
    let (temporary, file) = create_temporary(folder, name).map_err(io)?;
    let written = (|| {
        {
            // Closed at the end of this block, before the rename (Windows cannot rename
            // an open file).
            let mut file = file;
            body(&mut file)?;
            file.flush()?;
            file.sync_all()?;
        }
        std::fs::rename(&temporary, path)
    })();
    if let Err(e) = written {
        // A full disk or a failed body leaves nothing behind.
        let _ = std::fs::remove_file(&temporary);
        return Err(io(e));
    }
    sync_folder(folder);
    Ok(())
}

fn folder_of(path: &Path) -> &Path {
    path.parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."))
}

/// `.{name}.{pid}.{n}.likeness-tmp`, created exclusively (`O_EXCL`): the process id says
/// whose it is, the counter and clock make it unique within the process.
fn create_temporary(folder: &Path, name: &OsStr) -> std::io::Result<(PathBuf, File)> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let pid = std::process::id();
    loop {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let nanos = SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos());
        let temporary = folder.join(format!(
            ".{}.{pid}.{n}-{nanos:x}{TEMPORARY_SUFFIX}",
            name.to_string_lossy()
        ));
        let mut options = OpenOptions::new();
        options.write(true).create_new(true);
        match options.open(&temporary) {
            Ok(file) => return Ok((temporary, file)),
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
}

/// Makes the rename durable: on POSIX systems a new name reaches the disk only when its
/// folder is synced. Best effort (some systems cannot open a folder as a file).
fn sync_folder(folder: &Path) {
    if let Ok(dir) = File::open(folder)
        && let Err(e) = dir.sync_all()
    {
        tracing::debug!("cannot sync folder {}: {e}", folder.display());
    }
}

/// Removes the temporaries of `name` in `folder` that killed runs left: this crate's own
/// and older versions' `.{name}.{pid}.tmp` whose process is gone (or, where that cannot be
/// told, older than [`STALE_AFTER`]), and older versions' `.{name}.tmp` older than
/// [`STALE_AFTER`].
/// Returns how many were removed.
pub fn remove_stale_temporaries(folder: &Path, name: &OsStr) -> usize {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return 0;
    };
    let prefix = format!(".{}.", name.to_string_lossy());
    let mut removed = 0;
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let Some(rest) = file_name.to_str().and_then(|f| f.strip_prefix(&prefix)) else {
            continue;
        };
        let stale = if let Some(middle) = rest.strip_suffix(TEMPORARY_SUFFIX) {
            let pid = middle.split('.').next().and_then(|p| p.parse::<u32>().ok());
            match pid {
                Some(pid) if pid == std::process::id() => false,
                Some(pid) => match process_is_running(pid) {
                    Some(running) => !running,
                    None => is_older_than(&entry, STALE_AFTER),
                },
                None => false,
            }
        } else if rest == "tmp" {
            is_older_than(&entry, STALE_AFTER)
        } else if let Some(pid) = rest
            .strip_suffix(".tmp")
            .and_then(|p| p.parse::<u32>().ok())
        {
            // An older version's `.{name}.{pid}.tmp`.
            match process_is_running(pid) {
                Some(running) => !running && pid != std::process::id(),
                None => is_older_than(&entry, STALE_AFTER),
            }
        } else {
            false
        };
        if stale && entry.file_type().is_ok_and(|t| t.is_file()) {
            match std::fs::remove_file(entry.path()) {
                Ok(()) => {
                    tracing::info!(
                        "removed {}, left by an interrupted write",
                        entry.path().display()
                    );
                    removed += 1;
                }
                Err(e) => tracing::debug!("cannot remove {}: {e}", entry.path().display()),
            }
        }
    }
    removed
}

/// Whether process `pid` exists, where the system says (Linux: `/proc`).
fn process_is_running(pid: u32) -> Option<bool> {
    let proc_root = Path::new("/proc/self");
    if !proc_root.exists() {
        return None;
    }
    Some(Path::new("/proc").join(pid.to_string()).exists())
}

fn is_older_than(entry: &std::fs::DirEntry, age: Duration) -> bool {
    entry
        .metadata()
        .and_then(|m| m.modified())
        .ok()
        .and_then(|t| t.elapsed().ok())
        .is_some_and(|elapsed| elapsed > age)
}

/// Whether `a` and `b` are the same file (the same inode where both exist; else the same
/// absolute path, through the existing folder's canonical form).
pub fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        if let (Ok(ma), Ok(mb)) = (std::fs::metadata(a), std::fs::metadata(b)) {
            return ma.dev() == mb.dev() && ma.ino() == mb.ino();
        }
    }
    match (canonical_target(a), canonical_target(b)) {
        (Some(a), Some(b)) => a == b,
        _ => false,
    }
}

/// The canonical path a file would have: its folder made canonical, plus its name.
fn canonical_target(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    let folder = folder_of(path).canonicalize().ok()?;
    Some(folder.join(path.file_name()?))
}
