//! Where a puppet's buffers and images come from: the binary chunk, `data:` URIs, or files
//! beside the puppet, and nothing else.
//!
//! A `.gltf` from the internet names its external files itself, and whatever it names is
//! read and (for exports) embedded into a GLB the user then shares. So a relative URI is
//! resolved only inside the puppet's own folder: no scheme (`file:`, `http:`, `C:`), no
//! absolute path, no `..` component, no link leading out of the folder, only regular files
//! (not `/dev/zero`, a FIFO or a folder), and never more bytes than the caller allows.
//!
//! Written by hand because the `gltf` crate's importer (`gltf::import_buffers`,
//! `gltf::image::Data::from_source`) reads any path a URI names and has no size bound.

use std::io::Read;
use std::path::{Component, Path, PathBuf};

use base64::Engine;

/// Largest image file or embedded image read, in bytes (a 8k x 8k PNG is ~100 MB at most).
pub const MAX_IMAGE_BYTES: u64 = 128 << 20;

/// The folder a puppet's relative URIs resolve in, made canonical once.
#[derive(Clone, Debug)]
pub struct PuppetFolder {
    root: PathBuf,
}

impl PuppetFolder {
    /// `dir` is the folder holding the puppet file (`""` means the current folder).
    pub fn new(dir: &Path) -> Result<Self, String> {
        let dir = if dir.as_os_str().is_empty() {
            Path::new(".")
        } else {
            dir
        };
        let root = dir
            .canonicalize()
            .map_err(|e| format!("cannot open the puppet's folder {}: {e}", dir.display()))?;
        Ok(Self { root })
    }

    pub fn path(&self) -> &Path {
        &self.root
    }

    /// The file a relative URI names inside this folder, or why it may not be read.
    pub fn resolve(&self, uri: &str) -> Result<PathBuf, String> {
        let relative = relative_path(uri)?;
        let joined = self.root.join(&relative);
        let canonical = joined
            .canonicalize()
            .map_err(|e| format!("`{uri}` cannot be opened beside the puppet: {e}"))?;
        if !canonical.starts_with(&self.root) {
            return Err(format!(
                "`{uri}` leads out of the puppet's folder (through a link); only files inside {} are read",
                self.root.display()
            ));
        }
        let meta = std::fs::metadata(&canonical)
            .map_err(|e| format!("`{uri}` cannot be opened beside the puppet: {e}"))?;
        if !meta.is_file() {
            return Err(format!(
                "`{uri}` is not a regular file (a folder, device or pipe); it is not read"
            ));
        }
        Ok(canonical)
    }

    /// Reads the file `uri` names, refusing it when it holds more than `max_bytes`
    /// (`what` names it in messages, e.g. "buffer 0"). With `take_prefix`, a larger file
    /// gives its first `max_bytes` bytes instead (a buffer's `byteLength` may be shorter
    /// than its file).
    pub fn read(
        &self,
        uri: &str,
        max_bytes: u64,
        take_prefix: bool,
        what: &str,
    ) -> Result<Vec<u8>, String> {
        let path = self
            .resolve(uri)
            .map_err(|reason| format!("{what}: {reason}"))?;
        let file = std::fs::File::open(&path)
            .map_err(|e| format!("{what}: `{uri}` cannot be opened: {e}"))?;
        // The handle, not the name, is checked again: the name may have changed since.
        let meta = file
            .metadata()
            .map_err(|e| format!("{what}: `{uri}` cannot be read: {e}"))?;
        if !meta.is_file() {
            return Err(format!("{what}: `{uri}` is not a regular file"));
        }
        if meta.len() > max_bytes && !take_prefix {
            return Err(format!(
                "{what}: `{uri}` has {} bytes, more than the {max_bytes} allowed",
                meta.len()
            ));
        }
        let mut bytes = Vec::new();
        file.take(max_bytes)
            .read_to_end(&mut bytes)
            .map_err(|e| format!("{what}: `{uri}` cannot be read: {e}"))?;
        Ok(bytes)
    }
}

/// The relative path a URI stands for, or why it is not one the loader follows.
pub fn relative_path(uri: &str) -> Result<PathBuf, String> {
    if uri.is_empty() {
        return Err("an empty URI".into());
    }
    if has_scheme(uri) {
        return Err(format!(
            "`{uri}` is not a file beside the puppet (a URI with a scheme); only relative paths and `data:` URIs are read"
        ));
    }
    let decoded = percent_encoding::percent_decode_str(uri)
        .decode_utf8()
        .map_err(|_| format!("`{uri}` does not decode to UTF-8"))?;
    if decoded.contains('\0') {
        return Err(format!("`{uri}` holds a NUL byte"));
    }
    // Windows separators count as separators wherever the file came from.
    let normalised = decoded.replace('\\', "/");
    if normalised.starts_with('/') || has_scheme(&normalised) {
        return Err(format!(
            "`{uri}` is an absolute path; only paths inside the puppet's folder are read"
        ));
    }
    let mut path = PathBuf::new();
    for component in Path::new(&normalised).components() {
        match component {
            Component::Normal(part) => path.push(part),
            Component::CurDir => {}
            Component::ParentDir => {
                return Err(format!(
                    "`{uri}` climbs out with `..`; only paths inside the puppet's folder are read"
                ));
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err(format!(
                    "`{uri}` is an absolute path; only paths inside the puppet's folder are read"
                ));
            }
        }
    }
    if path.as_os_str().is_empty() {
        return Err(format!("`{uri}` names the puppet's folder, not a file"));
    }
    Ok(path)
}

/// `scheme:` at the start (RFC 3986: a letter, then letters, digits, `+`, `-`, `.`); a
/// Windows drive (`C:`) is one too, which is what we want.
fn has_scheme(uri: &str) -> bool {
    let Some(colon) = uri.find(':') else {
        return false;
    };
    let scheme = &uri[..colon];
    let mut chars = scheme.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || matches!(c, '+' | '-' | '.'))
}

/// The bytes of a `data:` URI (base64 or percent-encoded) with its media type, refused when
/// they would exceed `max_bytes`.
pub fn decode_data_uri(uri: &str, max_bytes: u64) -> Result<(Vec<u8>, String), String> {
    let rest = uri
        .strip_prefix("data:")
        .ok_or_else(|| "not a data URI".to_owned())?;
    let (header, payload) = rest
        .split_once(',')
        .ok_or_else(|| "a data URI without a `,` before its data".to_owned())?;
    let (media_type, base64) = match header.strip_suffix(";base64") {
        Some(m) => (m, true),
        None => (header, false),
    };
    // Base64 holds 3 bytes per 4 characters; refuse before decoding.
    let estimate = if base64 {
        payload.len() as u64 / 4 * 3
    } else {
        payload.len() as u64
    };
    if estimate > max_bytes {
        return Err(format!(
            "a data URI of about {estimate} bytes, more than the {max_bytes} allowed"
        ));
    }
    let bytes = if base64 {
        base64::engine::general_purpose::STANDARD
            .decode(payload.trim())
            .map_err(|e| format!("a data URI that is not valid base64: {e}"))?
    } else {
        percent_encoding::percent_decode_str(payload).collect()
    };
    Ok((bytes, media_type.to_owned()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_paths_inside_the_folder_are_followed() {
        for (uri, expect) in [
            ("tex.png", "tex.png"),
            ("./textures/skin%20base.png", "textures/skin base.png"),
            ("a/./b.bin", "a/b.bin"),
        ] {
            assert_eq!(relative_path(uri).unwrap(), PathBuf::from(expect), "{uri}");
        }
    }

    #[test]
    fn escapes_and_schemes_are_refused() {
        for uri in [
            "../../../../etc/passwd",
            "textures/../../secret",
            "%2e%2e/secret",
            "..\\..\\secret",
            "/etc/passwd",
            "%2Fetc%2Fpasswd",
            "\\\\server\\share\\x.png",
            "/proc/self/environ",
            "file:///etc/passwd",
            "http://example.com/x.png",
            "C:/Windows/win.ini",
            "C%3A/Windows/win.ini",
            "",
            ".",
            "a%00b",
        ] {
            assert!(relative_path(uri).is_err(), "{uri} was accepted");
        }
    }

    #[test]
    fn data_uris_decode_and_are_bounded() {
        let (bytes, mime) = decode_data_uri("data:image/png;base64,AAEC", 100).unwrap();
        assert_eq!(bytes, vec![0, 1, 2]);
        assert_eq!(mime, "image/png");
        let (bytes, _) = decode_data_uri("data:,a%20b", 100).unwrap();
        assert_eq!(bytes, b"a b");
        assert!(decode_data_uri("data:;base64,AAAAAAAA", 3).is_err());
        assert!(decode_data_uri("data:;base64,@@@@", 100).is_err());
        assert!(decode_data_uri("data:no-comma", 100).is_err());
    }
}
