//! Errors of the tracking crate: every one names the file, model or input it is about.

use std::path::PathBuf;

/// What went wrong while loading a model, reading footage or tracking a frame.
#[derive(Debug, thiserror::Error)]
pub enum TrackingError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("model file {path} is missing: {hint}")]
    MissingModel { path: PathBuf, hint: String },
    #[error("the ONNX Runtime library could not be loaded: {0}")]
    Runtime(String),
    #[error("inference with {backend} on {model} failed: {reason}")]
    Inference {
        backend: &'static str,
        model: String,
        reason: String,
    },
    #[error("{model} produced NaN or infinite values in `{output}`")]
    NonFinite { model: String, output: String },
    #[error("{model}: unexpected output {reason}")]
    BadOutput { model: String, reason: String },
    #[error("invalid manifest {path}: {reason}")]
    Manifest { path: PathBuf, reason: String },
    #[error("invalid input: {0}")]
    InvalidInput(String),
    #[error("cannot decode {path}: {reason}")]
    Decode { path: PathBuf, reason: String },
    #[error("invalid session file {path}: {reason}")]
    Session { path: PathBuf, reason: String },
    /// An error of this crate's code that ran elsewhere (the browser's face-locating Web
    /// Worker), worded as it was there.
    #[error("{0}")]
    Relayed(String),
    #[error(transparent)]
    Face(#[from] face::FaceError),
    #[error(transparent)]
    Write(#[from] files::WriteError),
}

pub type Result<T, E = TrackingError> = std::result::Result<T, E>;

/// `map_err` helper for I/O on a path.
pub fn io_error(path: impl Into<PathBuf>) -> impl FnOnce(std::io::Error) -> TrackingError {
    let path = path.into();
    move |source| TrackingError::Io { path, source }
}
