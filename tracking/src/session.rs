//! The session file (`likeness personalize --out person.likeness`): a person's
//! personalized model (ModelNet's corrections dS_0, dS_i, dR_0, dR_i) together with the
//! tracking of the footage it was learnt from.
//!
//! The container is safetensors: the four correction tensors in the layout ModelNet
//! produces (channel-first, row 0 at v = 1) and, in its string metadata, the format name,
//! a version, the tracking document and which frames ModelNet saw. Files are written
//! atomically; a file of a newer version, a foreign file or a damaged one is refused with
//! a message saying which.

use std::collections::HashMap;
use std::path::Path;

use face::uv::{CORRECTION_SIZE, UvMap};
use face::{NUM_BLENDSHAPES, PersonalCorrections};
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrackingError, io_error};
use crate::networks::chw_to_uv;
use crate::record::TracksDocument;

pub const SESSION_FORMAT: &str = "likeness-session";
/// Version 1: corrections as f32 tensors `dS0` [3,128,128], `dS` [53,3,128,128], `dR0`,
/// `dR`; metadata `format`, `version`, `info`, `tracks`.
/// Version 2 (the studio's sessions) adds, both optional: the footage as a u8 tensor
/// `frames` [N, H, W, 3] (RGB, rows top to bottom), aligned with the tracking's frames, and
/// metadata `observations` (per frame the detected landmarks and the crop). Version 1 files
/// still load, without footage.
pub const SESSION_VERSION: u32 = 2;

/// What the face locator saw in one frame (kept so the studio can show it again).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct FrameObservations {
    /// Detected landmarks, pixels.
    pub detected: Vec<[f32; 2]>,
    /// The network crop [x, y, width, height], pixels.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub crop: Option<[f32; 4]>,
}

/// How the personalized model was made.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionInfo {
    /// `likeness <version>`.
    pub created_by: String,
    /// The footage (file, folder, device).
    pub source: String,
    /// Indices (into the tracking frames) of the frames ModelNet saw.
    pub selected_frames: Vec<usize>,
    /// The inference backend that ran ModelNet.
    pub backend: String,
    /// SHA-256-free identity of the networks: the manifest's training commit, if known.
    #[serde(default)]
    pub networks: String,
}

/// A personalized model and its tracking.
#[derive(Clone, Debug, PartialEq)]
pub struct Session {
    pub info: SessionInfo,
    pub corrections: PersonalCorrections,
    pub tracks: TracksDocument,
    /// The footage, one image per tracking frame, all of one size (absent in files made by
    /// `likeness personalize`).
    pub footage: Option<Vec<image::RgbImage>>,
    /// Per tracking frame, when known (empty otherwise).
    pub observations: Vec<FrameObservations>,
}

fn uv_to_chw(map: &UvMap, out: &mut Vec<u8>) {
    let n = map.width * map.height;
    for c in 0..map.channels {
        for t in 0..n {
            out.extend_from_slice(&map.data[t * map.channels + c].to_le_bytes());
        }
    }
}

impl Session {
    /// The serialized file.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        self.corrections.validate()?;
        let n = CORRECTION_SIZE;
        let mut ds0 = Vec::new();
        uv_to_chw(&self.corrections.identity_shape, &mut ds0);
        let mut dr0 = Vec::new();
        uv_to_chw(&self.corrections.static_albedo, &mut dr0);
        let mut ds = Vec::new();
        for m in &self.corrections.expression_shapes {
            uv_to_chw(m, &mut ds);
        }
        let mut dr = Vec::new();
        for m in &self.corrections.dynamic_albedo {
            uv_to_chw(m, &mut dr);
        }
        fn view(bytes: &[u8], shape: Vec<usize>) -> Result<safetensors::tensor::TensorView<'_>> {
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape, bytes)
                .map_err(|e| TrackingError::InvalidInput(e.to_string()))
        }
        let err = |e: safetensors::SafeTensorError| TrackingError::InvalidInput(e.to_string());
        let mut tensors = vec![
            ("dS0", view(&ds0, vec![3, n, n])?),
            ("dS", view(&ds, vec![NUM_BLENDSHAPES, 3, n, n])?),
            ("dR0", view(&dr0, vec![3, n, n])?),
            ("dR", view(&dr, vec![NUM_BLENDSHAPES, 3, n, n])?),
        ];
        let mut footage_bytes = Vec::new();
        let mut footage_shape = Vec::new();
        if let Some(frames) = self.footage.as_ref().filter(|f| !f.is_empty()) {
            let (w, h) = frames[0].dimensions();
            if frames.iter().any(|f| f.dimensions() != (w, h)) {
                return Err(TrackingError::InvalidInput(
                    "the session's frames are not all of one size".into(),
                ));
            }
            if frames.len() != self.tracks.frames.len() {
                return Err(TrackingError::InvalidInput(format!(
                    "{} frames of footage for {} tracked frames",
                    frames.len(),
                    self.tracks.frames.len()
                )));
            }
            footage_bytes.reserve(frames.len() * (w * h * 3) as usize);
            for f in frames {
                footage_bytes.extend_from_slice(f.as_raw());
            }
            footage_shape = vec![frames.len(), h as usize, w as usize, 3];
        }
        if !footage_shape.is_empty() {
            tensors.push((
                "frames",
                safetensors::tensor::TensorView::new(
                    safetensors::Dtype::U8,
                    footage_shape,
                    &footage_bytes,
                )
                .map_err(|e| TrackingError::InvalidInput(e.to_string()))?,
            ));
        }
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), SESSION_FORMAT.to_string());
        meta.insert("version".to_string(), SESSION_VERSION.to_string());
        meta.insert(
            "info".to_string(),
            serde_json::to_string(&self.info)
                .map_err(|e| TrackingError::InvalidInput(e.to_string()))?,
        );
        meta.insert("tracks".to_string(), self.tracks.to_json());
        if !self.observations.is_empty() {
            meta.insert(
                "observations".to_string(),
                serde_json::to_string(&self.observations)
                    .map_err(|e| TrackingError::InvalidInput(e.to_string()))?,
            );
        }
        safetensors::serialize(tensors, Some(meta)).map_err(err)
    }

    /// Writes the session atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        Ok(files::write_atomically(path, &self.to_bytes()?)?)
    }

    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(io_error(path))?;
        Self::from_bytes(&bytes).map_err(|reason| TrackingError::Session {
            path: path.to_owned(),
            reason,
        })
    }

    pub fn from_bytes(bytes: &[u8]) -> std::result::Result<Self, String> {
        let (parts, st) = SessionParts::read(bytes)?;
        let n = CORRECTION_SIZE;
        let read = |name: &str, shape: &[usize]| -> std::result::Result<Vec<f32>, String> {
            let t = st
                .tensor(name)
                .map_err(|_| format!("tensor `{name}` is missing"))?;
            if t.dtype() != safetensors::Dtype::F32 || t.shape() != shape {
                return Err(format!(
                    "tensor `{name}` is {:?} {:?}, expected F32 {shape:?}",
                    t.dtype(),
                    t.shape()
                ));
            }
            let values: Vec<f32> = t
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            if values.iter().any(|v| !v.is_finite()) {
                return Err(format!("tensor `{name}` has NaN or infinite values"));
            }
            Ok(values)
        };
        let plane = 3 * n * n;
        let ds0 = read("dS0", &[3, n, n])?;
        let ds = read("dS", &[NUM_BLENDSHAPES, 3, n, n])?;
        let dr0 = read("dR0", &[3, n, n])?;
        let dr = read("dR", &[NUM_BLENDSHAPES, 3, n, n])?;
        let split = |v: &[f32]| {
            (0..NUM_BLENDSHAPES)
                .map(|i| chw_to_uv(&v[i * plane..(i + 1) * plane], n, n))
                .collect()
        };
        Ok(Self {
            info: parts.info,
            footage: parts.footage,
            observations: parts.observations,
            corrections: PersonalCorrections {
                identity_shape: chw_to_uv(&ds0, n, n),
                expression_shapes: split(&ds),
                static_albedo: chw_to_uv(&dr0, n, n),
                dynamic_albedo: split(&dr),
            },
            tracks: parts.tracks,
        })
    }
}

/// Everything of a session file but its corrections, with the checks of
/// [`Session::from_bytes`], which reads these first: for what needs the tracking and the
/// footage only, and for the fuzz targets, which reach every check of a file's own data
/// without the 21 MB of correction tensors in each case.
#[derive(Clone, Debug, PartialEq)]
pub struct SessionParts {
    pub version: u32,
    pub info: SessionInfo,
    pub tracks: TracksDocument,
    pub footage: Option<Vec<image::RgbImage>>,
    pub observations: Vec<FrameObservations>,
}

impl SessionParts {
    pub fn from_bytes(bytes: &[u8]) -> std::result::Result<Self, String> {
        Self::read(bytes).map(|(parts, _)| parts)
    }

    /// The parts and the file's tensors (for the corrections).
    fn read(bytes: &[u8]) -> std::result::Result<(Self, safetensors::SafeTensors<'_>), String> {
        let (_, metadata) = safetensors::SafeTensors::read_metadata(bytes)
            .map_err(|e| format!("not a Likeness session ({e})"))?;
        let meta = metadata.metadata().clone().unwrap_or_default();
        if meta.get("format").map(String::as_str) != Some(SESSION_FORMAT) {
            return Err("not a Likeness session (no `format: likeness-session`)".into());
        }
        let version: u32 = meta
            .get("version")
            .and_then(|v| v.parse().ok())
            .ok_or("the session has no readable version")?;
        if version > SESSION_VERSION {
            return Err(format!(
                "session version {version} is newer than this Likeness reads ({SESSION_VERSION}); update Likeness"
            ));
        }
        let info: SessionInfo = serde_json::from_str(meta.get("info").map_or("{}", String::as_str))
            .map_err(|e| format!("`info`: {e}"))?;
        let tracks = TracksDocument::from_json(meta.get("tracks").map_or("", String::as_str))
            .map_err(|e| format!("`tracks`: {e}"))?;
        let observations: Vec<FrameObservations> = match meta.get("observations") {
            None => Vec::new(),
            Some(text) => serde_json::from_str(text).map_err(|e| format!("`observations`: {e}"))?,
        };
        if !observations.is_empty() && observations.len() != tracks.frames.len() {
            return Err(format!(
                "{} observations for {} tracked frames",
                observations.len(),
                tracks.frames.len()
            ));
        }
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        if observations
            .iter()
            .any(|o| !o.detected.iter().all(|p| finite(p)) || !o.crop.is_none_or(|c| finite(&c)))
        {
            return Err("`observations` has NaN or infinite values".into());
        }
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| e.to_string())?;
        let footage = match st.tensor("frames") {
            Err(_) => None,
            Ok(t) => {
                let shape = t.shape();
                let [count, h, w, 3] = shape else {
                    return Err(format!(
                        "tensor `frames` is {shape:?}, expected [N, H, W, 3]"
                    ));
                };
                if t.dtype() != safetensors::Dtype::U8 {
                    return Err(format!("tensor `frames` is {:?}, expected U8", t.dtype()));
                }
                if *count != tracks.frames.len() {
                    return Err(format!(
                        "{count} frames of footage for {} tracked frames",
                        tracks.frames.len()
                    ));
                }
                let (w32, h32) = (
                    u32::try_from(*w).map_err(|_| "frames are too wide")?,
                    u32::try_from(*h).map_err(|_| "frames are too tall")?,
                );
                // Also when there are none: `w * h * 3` must not overflow.
                crate::source::check_frame_size(w32, h32)
                    .map_err(|e| format!("tensor `frames`: {e}"))?;
                let size = w * h * 3;
                let frames = t
                    .data()
                    .chunks_exact(size.max(1))
                    .map(|bytes| image::RgbImage::from_raw(w32, h32, bytes.to_vec()))
                    .collect::<Option<Vec<_>>>()
                    .ok_or("tensor `frames` has the wrong size")?;
                Some(frames)
            }
        };
        let parts = Self {
            version,
            info,
            tracks,
            footage,
            observations,
        };
        Ok((parts, st))
    }
}
