//! # face: the personalized face model of Likeness
//!
//! Owns the paper's model and nothing else: the template (ICT FaceKit) and its loading,
//! blendshape names, equation (2) (shape) and equation (3) (albedo) with UV-space
//! corrections, the attention masks A_i, the procedural mean albedo R_0, the UV parsing map
//! T, and the geometry every other crate needs (normals, Laplacian, deformation gradients,
//! landmarks, camera, spherical-harmonics shading).
//!
//! It must not depend on a GPU, a UI or an inference runtime, and must build for
//! `wasm32-unknown-unknown`: the renderer, tracking, retargeting and the studio all build
//! on it, and the training code checks its own copy of these equations against it.

pub mod albedo;
pub mod camera;
pub mod error;
pub mod gaze;
pub mod geometry;
pub mod ict_import;
pub mod masks;
pub mod model;
pub mod names;
pub mod parsing;
pub mod sampling;
pub mod sh;
pub mod template;
pub mod uv;

pub use error::{FaceError, Result};
pub use model::{BlendshapeWeights, FaceModel, PersonalCorrections, PersonalizedBlendshapes};
pub use names::{ARKIT_NAMES, ICT_NAMES, NUM_ARKIT, NUM_BLENDSHAPES};
pub use template::{NUM_LANDMARKS, Template};
