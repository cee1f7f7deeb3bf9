//! # retarget: tracked motion onto external puppets
//!
//! Owns everything between the tracker's ARKit-52 weights and a character: loading glTF,
//! GLB and VRM puppets (`puppet`), naming conventions (`names`), VRM expressions (`vrm`),
//! the mapping data with its JSON sidecar (`mapping`), the compiled mapping and its report
//! (`driver`), reading tracks (`tracks`), exports as glTF animation, Live Link Face CSV and
//! JSON (`export`), the personalized rig as GLB (`rig`) and the project's own puppets
//! (`generator`).
//!
//! It must not depend on a GPU, a UI or an inference runtime (the renderer draws what it
//! loads; the studio wires them), and it never panics on a file from outside: every
//! malformed input is a [`RetargetError`] naming the file and the problem.

pub mod accessor;
pub mod driver;
pub mod error;
pub mod export;
pub mod generator;
pub mod glb;
pub mod mapping;
pub mod names;
pub mod puppet;
pub mod rig;
pub mod tracks;
pub mod uri;
pub mod vrm;

pub use driver::{MappingReport, PuppetPose, Retargeter};
pub use error::{Result, RetargetError};
pub use mapping::MappingData;
pub use puppet::Puppet;
pub use tracks::Tracks;
