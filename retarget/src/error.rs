use std::path::PathBuf;

/// Everything that can go wrong while loading, mapping or exporting a puppet. Every variant
/// names the file and the problem, so the studio and the CLI can show it as is.
#[derive(Debug, thiserror::Error)]
pub enum RetargetError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    #[error("{path}: {reason}")]
    InvalidPuppet { path: PathBuf, reason: String },

    #[error(
        "{path}: requires the glTF extension(s) {names} which Likeness does not support; \
         export the puppet without them (e.g. in Blender: no Draco / meshopt compression, \
         PNG or JPEG textures)",
        names = .extensions.join(", ")
    )]
    UnsupportedExtension {
        path: PathBuf,
        extensions: Vec<String>,
    },

    #[error("{path}: mapping data: {reason}")]
    InvalidMapping { path: PathBuf, reason: String },

    #[error("{path}: tracks: {reason}")]
    InvalidTracks { path: PathBuf, reason: String },

    #[error("cannot write {path}: {reason}")]
    Write { path: PathBuf, reason: String },

    #[error(transparent)]
    Face(#[from] face::FaceError),

    #[error(transparent)]
    File(#[from] files::WriteError),
}

pub type Result<T, E = RetargetError> = std::result::Result<T, E>;

pub(crate) fn io_error(
    path: &std::path::Path,
) -> impl FnOnce(std::io::Error) -> RetargetError + '_ {
    move |source| RetargetError::Io {
        path: path.to_owned(),
        source,
    }
}
