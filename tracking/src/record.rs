//! The per-frame tracking record and the tracking document (`likeness track --out
//! tracks.json`), whose schema the README documents and `retarget::tracks` reads.

use std::path::Path;

use face::names::{ARKIT_NAMES, ICT_NAMES, NUM_ARKIT, ict_to_arkit};
use face::{NUM_BLENDSHAPES, NUM_LANDMARKS};
use serde::{Deserialize, Serialize};

use crate::error::{Result, TrackingError, io_error};
use crate::params::FaceParams;

/// Version of the tracking document's schema.
pub const TRACKS_VERSION: u32 = 1;

/// Tracking values of a frame with a face.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceTrack {
    /// w, aligned with `blendshape_names` (ICT).
    pub weights: Vec<f32>,
    /// The same motion on the 52 ARKit channels, aligned with `arkit_names`.
    pub arkit_weights: Vec<f32>,
    /// [yaw, pitch, roll] in degrees (face::camera conventions).
    pub rotation_deg: [f32; 3],
    /// Camera-space translation in centimetres (camera looks down -z).
    pub translation: [f32; 3],
    /// 27 SH lighting coefficients, r0..r8 g0..g8 b0..b8.
    pub sh: Vec<f32>,
    /// The model's 68 landmarks (iBUG layout) projected into the frame, in pixels.
    pub landmarks_68: Vec<[f32; 2]>,
    /// [x, y, width, height] in pixels: the bounding box of `landmarks_68`.
    pub face_box: [f32; 4],
    /// How sure the face locator is (mean landmark confidence of the detector, in [0, 1];
    /// 1 for input declared pre-cropped).
    pub confidence: f32,
}

/// One frame of the document.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FrameRecord {
    pub index: usize,
    pub time_s: f64,
    /// `false`: no face was found (or the frame could not be read); no tracking values.
    pub face: bool,
    #[serde(flatten, skip_serializing_if = "Option::is_none", default)]
    pub track: Option<FaceTrack>,
    /// Why there is no face, when known (unreadable frame, network failure).
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub note: Option<String>,
}

impl FrameRecord {
    pub fn no_face(index: usize, time_s: f64, note: Option<String>) -> Self {
        Self {
            index,
            time_s,
            face: false,
            track: None,
            note,
        }
    }

    pub fn with_face(
        index: usize,
        time_s: f64,
        params: &FaceParams,
        landmarks: &[glam::Vec2; NUM_LANDMARKS],
        confidence: f32,
    ) -> Self {
        let arkit: [f32; NUM_ARKIT] = ict_to_arkit(&params.weights);
        let deg = params.pose.degrees();
        let (mut lo, mut hi) = (
            glam::Vec2::splat(f32::INFINITY),
            glam::Vec2::splat(f32::NEG_INFINITY),
        );
        for p in landmarks {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
        Self {
            index,
            time_s,
            face: true,
            track: Some(FaceTrack {
                weights: params.weights.to_vec(),
                arkit_weights: arkit.to_vec(),
                rotation_deg: deg.to_array(),
                translation: params.pose.translation.to_array(),
                sh: params.gamma.to_vec(),
                landmarks_68: landmarks.iter().map(|p| p.to_array()).collect(),
                face_box: [lo.x, lo.y, hi.x - lo.x, hi.y - lo.y],
                confidence,
            }),
            note: None,
        }
    }
}

/// The camera the tracking is expressed in.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraRecord {
    pub width: u32,
    pub height: u32,
    pub focal_px: f32,
    pub cx: f32,
    pub cy: f32,
}

/// The whole tracking document.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TracksDocument {
    pub version: u32,
    /// The 53 ICT blendshape names, the order of every frame's `weights`.
    pub blendshape_names: Vec<String>,
    /// The 52 ARKit names, the order of every frame's `arkit_weights`.
    pub arkit_names: Vec<String>,
    pub source: String,
    pub fps: f64,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub camera: Option<CameraRecord>,
    /// How the frames were processed (backend, locator, refinement, smoothing).
    #[serde(default)]
    pub settings: serde_json::Value,
    /// `false` if processing stopped early (the error says why); the frames before it are
    /// all here.
    pub complete: bool,
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub error: Option<String>,
    pub frames: Vec<FrameRecord>,
}

impl TracksDocument {
    pub fn new(source: String, fps: f64) -> Self {
        Self {
            version: TRACKS_VERSION,
            blendshape_names: ICT_NAMES.iter().map(|s| s.to_string()).collect(),
            arkit_names: ARKIT_NAMES.iter().map(|s| s.to_string()).collect(),
            source,
            fps,
            camera: None,
            settings: serde_json::Value::Null,
            complete: true,
            error: None,
            frames: Vec::new(),
        }
    }

    /// Parses and checks a document (array lengths, finiteness, versions).
    pub fn from_json(text: &str) -> std::result::Result<Self, String> {
        let doc: Self = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if doc.version > TRACKS_VERSION {
            return Err(format!(
                "tracking document version {} is newer than this Likeness reads ({TRACKS_VERSION})",
                doc.version
            ));
        }
        if doc.blendshape_names != ICT_NAMES || doc.arkit_names != ARKIT_NAMES {
            return Err("`blendshape_names` / `arkit_names` are not Likeness's".into());
        }
        // In the flattened frame values a JSON number beyond the f32 range reads as an
        // infinite f32 (which would be written back as `null`); elsewhere serde refuses it.
        let finite = |values: &[f32]| values.iter().all(|v| v.is_finite());
        for f in &doc.frames {
            if let Some(t) = &f.track {
                if t.weights.len() != NUM_BLENDSHAPES
                    || t.arkit_weights.len() != NUM_ARKIT
                    || t.sh.len() != 27
                    || t.landmarks_68.len() != NUM_LANDMARKS
                {
                    return Err(format!("frame {}: arrays of the wrong length", f.index));
                }
                let all_finite = finite(&t.weights)
                    && finite(&t.arkit_weights)
                    && finite(&t.rotation_deg)
                    && finite(&t.translation)
                    && finite(&t.sh)
                    && t.landmarks_68.iter().all(|p| finite(p))
                    && finite(&t.face_box)
                    && t.confidence.is_finite();
                if !all_finite {
                    return Err(format!(
                        "frame {}: a value is not a finite 32-bit float",
                        f.index
                    ));
                }
            } else if f.face {
                return Err(format!(
                    "frame {}: `face` is true but it has no values",
                    f.index
                ));
            }
        }
        Ok(doc)
    }

    pub fn to_json(&self) -> String {
        // Serialising plain numbers and strings cannot fail.
        serde_json::to_string_pretty(self).unwrap_or_default()
    }

    /// Writes the document atomically (a temporary file renamed over `path`).
    pub fn save(&self, path: &Path) -> Result<()> {
        Ok(files::write_atomically(path, self.to_json().as_bytes())?)
    }

    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(io_error(path))?;
        Self::from_json(&text).map_err(|reason| TrackingError::Decode {
            path: path.to_owned(),
            reason,
        })
    }
}
