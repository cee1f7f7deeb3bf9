use std::path::PathBuf;

/// Where a user outside this workplace downloads the template, repeated in every error
/// about a missing or unreadable model so that the message alone is enough to fix it.
pub const TEMPLATE_DOWNLOAD_HINT: &str = "get the ICT FaceKit light model (MIT licence) from \
https://github.com/ICT-VGL/ICT-FaceKit (folder FaceXModel/) and pass that folder with \
--facemodel or LIKENESS_FACEMODEL, or use the converted ict_face_model.safetensors";

/// Everything that can go wrong in the `face` crate.
#[derive(Debug, thiserror::Error)]
pub enum FaceError {
    #[error("face model not found at {path}: {reason}; {hint}", hint = TEMPLATE_DOWNLOAD_HINT)]
    TemplateNotFound { path: PathBuf, reason: String },

    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    #[error("malformed face model {path}: {reason}; {hint}", hint = TEMPLATE_DOWNLOAD_HINT)]
    MalformedTemplate { path: PathBuf, reason: String },

    #[error("invalid input: {0}")]
    InvalidInput(String),

    #[error(
        "unknown blendshape name `{0}` (expected one of the 53 ICT names or the 52 ARKit names)"
    )]
    UnknownBlendshape(String),

    #[error(transparent)]
    Write(#[from] files::WriteError),
}

pub type Result<T, E = FaceError> = std::result::Result<T, E>;
