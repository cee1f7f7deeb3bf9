//! The writer's guarantees, each shown by doing what breaks a naive writer: concurrent
//! writers, a failing write, a kill -9 in the middle of a large write, leftovers of killed
//! runs, and an output that is an input.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use files::{
    STALE_AFTER, TEMPORARY_SUFFIX, WriteError, remove_stale_temporaries, same_file,
    write_atomically, write_atomically_with,
};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("likeness-files-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect()
}

/// Content that says who wrote it in every byte, so a mix of two writers shows.
fn content(writer: u8, len: usize) -> Vec<u8> {
    vec![writer; len]
}

#[test]
fn concurrent_writers_leave_one_whole_file_and_no_temporaries() {
    let dir = scratch("concurrent");
    let target = dir.join("out.glb");
    for round in 0..20 {
        let handles: Vec<_> = (0..4u8)
            .map(|w| {
                let target = target.clone();
                std::thread::spawn(move || {
                    write_atomically(&target, &content(w, 200_000 + 37 * usize::from(w) + round))
                })
            })
            .collect();
        for h in handles {
            h.join().unwrap().unwrap();
        }
        let bytes = std::fs::read(&target).unwrap();
        let w = bytes[0];
        assert_eq!(
            bytes,
            content(w, 200_000 + 37 * usize::from(w) + round),
            "round {round}: the file mixes writers or is cut"
        );
        assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
    }
}

#[test]
fn a_failing_write_keeps_the_old_file_and_leaves_nothing() {
    let dir = scratch("failing");
    let target = dir.join("session.likeness");
    write_atomically(&target, b"old").unwrap();
    let err = write_atomically_with(&target, |f| {
        use std::io::Write;
        f.write_all(&[7; 100_000])?;
        // What a full disk says.
        Err(std::io::Error::from_raw_os_error(28))
    })
    .unwrap_err();
    assert!(err.to_string().starts_with("cannot write"), "{err}");
    assert_eq!(std::fs::read(&target).unwrap(), b"old");
    assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
}

#[test]
fn a_missing_folder_or_a_folder_as_target_is_a_clear_error() {
    let dir = scratch("missing");
    let err = write_atomically(&dir.join("nope/x.json"), b"x").unwrap_err();
    assert!(matches!(err, WriteError::NoFolder { .. }), "{err}");
    assert!(err.to_string().contains("does not exist"), "{err}");
    let err = write_atomically(&dir, b"x").unwrap_err();
    assert!(err.to_string().starts_with("cannot write"), "{err}");
}

const CHILD_ENV: &str = "LIKENESS_FILES_CHILD_TARGET";

/// Not a test on its own: the child process the kill test starts (it writes until killed).
#[test]
fn child_writer() {
    let Ok(target) = std::env::var(CHILD_ENV) else {
        return;
    };
    let target = PathBuf::from(target);
    for k in 0u8.. {
        // 16 MB in 64 kB pieces, slow enough to be killed in the middle.
        write_atomically_with(&target, |f| {
            use std::io::Write;
            for _ in 0..256 {
                f.write_all(&[k % 200 + 1; 65536])?;
            }
            Ok(())
        })
        .unwrap();
    }
}

#[test]
fn a_killed_writer_leaves_the_old_or_the_new_file_and_its_temporary_is_removed_later() {
    let dir = scratch("kill");
    let target = dir.join("session.likeness");
    write_atomically(&target, b"old").unwrap();
    let exe = std::env::current_exe().unwrap();
    let mut saw_temporary = false;
    for attempt in 0..20u64 {
        let mut child = std::process::Command::new(&exe)
            .args(["--exact", "child_writer", "--test-threads=1"])
            .env(CHILD_ENV, &target)
            .stdout(std::process::Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_millis(150 + 37 * attempt));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        let bytes = std::fs::read(&target).unwrap();
        let whole =
            bytes == b"old" || (bytes.len() == 256 * 65536 && bytes.iter().all(|&b| b == bytes[0]));
        assert!(
            whole,
            "attempt {attempt}: {} bytes, not a whole file",
            bytes.len()
        );
        saw_temporary |= leftovers(&dir)
            .iter()
            .any(|n| n.ends_with(TEMPORARY_SUFFIX));
        // The next write removes what the killed process left.
        write_atomically(&target, b"old").unwrap();
        assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
    }
    assert!(saw_temporary, "no kill landed in the middle of a write");
}

#[test]
fn only_temporaries_of_dead_writers_and_old_leftovers_are_removed() {
    let dir = scratch("stale");
    let name = std::ffi::OsStr::new("take.json");
    let touch = |n: &str, age: Duration| {
        let p = dir.join(n);
        std::fs::write(&p, b"x").unwrap();
        let f = std::fs::File::options().write(true).open(&p).unwrap();
        f.set_modified(SystemTime::now() - age).unwrap();
    };
    let fresh = Duration::from_secs(1);
    let old = STALE_AFTER + Duration::from_secs(60);
    // pid 4194304 is above Linux's largest pid: never running.
    touch(&format!(".take.json.4194304.0-1{TEMPORARY_SUFFIX}"), fresh);
    touch(
        &format!(".take.json.{}.0-1{TEMPORARY_SUFFIX}", std::process::id()),
        old,
    );
    touch(".take.json.4194304.tmp", fresh); // an older version's, its process gone
    touch(".take.json.tmp", fresh); // an older version's, maybe still being written
    touch(".other.json.4194304.0-1.likeness-tmp", fresh); // another file's
    touch("take.json", old);
    assert_eq!(remove_stale_temporaries(&dir, name), 2);
    let mut left = leftovers(&dir);
    left.sort();
    assert_eq!(
        left,
        vec![
            ".other.json.4194304.0-1.likeness-tmp".to_owned(),
            format!(".take.json.{}.0-1{TEMPORARY_SUFFIX}", std::process::id()),
            ".take.json.tmp".to_owned(),
        ]
    );
    assert!(dir.join("take.json").exists());
}

#[test]
fn one_file_is_one_file_however_it_is_spelled() {
    let dir = scratch("same");
    let tracks = dir.join("tracks.json");
    std::fs::write(&tracks, b"{}").unwrap();
    std::fs::create_dir_all(dir.join("sub")).unwrap();
    let spelled = dir.join("sub/../tracks.json");
    let linked = dir.join("hard.json");
    std::fs::hard_link(&tracks, &linked).unwrap();
    for out in [&tracks, &spelled, &linked] {
        assert!(same_file(out, &tracks), "{}", out.display());
    }
    assert!(!same_file(&dir.join("anim.glb"), &tracks));
    assert!(!same_file(&dir.join("p.glb"), &tracks));
    // An output that does not exist yet is compared by its folder's canonical path.
    assert!(same_file(&dir.join("new.csv"), &dir.join("sub/../new.csv")));
    assert!(!same_file(&dir.join("new.csv"), &dir.join("other.csv")));
}
