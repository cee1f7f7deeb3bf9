//! # tracking: footage in, tracking and a personalized model out
//!
//! Owns embedded inference of the project's TrackNet and ModelNet (ONNX Runtime through
//! `ort` natively, tract in pure Rust for wasm32 and as the fallback), the preprocessing
//! the training code used, real-footage face detection and landmarks (OpenSeeFace's 66
//! points; MediaPipe's BlazeFace and 468-point Face Mesh; RetinaFace as the fallback
//! detector), test-time refinement, temporal
//! smoothing, frame selection for personalization, footage sources and the per-frame
//! tracking records.
//!
//! It builds on `face` for the model (equations (2) and (3), camera, landmarks) and must not
//! depend on a GPU, a UI or the retargeting crate: the studio and the CLI wire those.

pub mod backend;
pub mod bundle;
pub mod error;

pub use backend::{BackendChoice, BackendKind, InferenceBackend, Tensor, load_model};
pub use error::{Result, TrackingError};
pub mod params;
pub mod preprocess;

pub use params::FaceParams;
pub mod evaluate;
pub mod identity;
pub mod mediapipe;
pub mod networks;
pub mod openseeface;
pub mod personalize;
pub mod pipeline;
pub mod record;
pub mod refine;
pub mod retinaface;
pub mod select;
pub mod session;
pub mod smooth;
pub mod source;
