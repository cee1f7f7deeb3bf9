//! What the studio shows about one person and one piece of footage: the frames, what
//! tracking found in each (detected landmarks, crop, confidence, the tracked record), the
//! personal corrections ModelNet learned and the blendshapes they make, and for the
//! built-in demo the person's true corrections beside them.
//!
//! Pure data and the measurements the panels show (correction sizes in mm, per-frame
//! overlays); no egui, no GPU, so the panels and the headless writer share it and tests
//! can check it directly.

use std::sync::Arc;

use face::camera::Intrinsics;
use face::names::ict_to_arkit;
use face::{
    BlendshapeWeights, FaceModel, NUM_BLENDSHAPES, PersonalCorrections, PersonalizedBlendshapes,
};
use glam::Vec2;
use image::RgbImage;
use retarget::tracks::{TrackedFrame, Tracks};
use tracking::pipeline::FrameOutput;
use tracking::record::{CameraRecord, FrameRecord, TracksDocument};
use tracking::session::{FrameObservations, Session, SessionInfo};

use crate::demo::DemoSession;

/// [`StudioSession::source`] of the built-in demo.
pub const DEMO_SOURCE: &str = "built-in demo";

/// Sessions without footage (`likeness personalize`) show grey frames of the camera's size
/// in its place; more bytes of them than this are refused, not allocated.
pub const MAX_PLACEHOLDER_BYTES: u64 = 2 << 30;

/// One person's session in the studio.
pub struct StudioSession {
    /// Where the footage came from (file, folder, "built-in demo").
    pub source: String,
    pub fps: f64,
    pub frames: Vec<RgbImage>,
    /// Per frame: the detected landmarks and the network crop.
    pub observations: Vec<FrameObservations>,
    /// Per frame: the final tracking (with the personalized blendshapes).
    pub records: Vec<FrameRecord>,
    /// dS_0, dS_i, dR_0, dR_i as ModelNet predicted them.
    pub corrections: PersonalCorrections,
    pub blendshapes: Arc<PersonalizedBlendshapes>,
    /// The true corrections, when known (the demo's synthetic person).
    pub truth: Option<PersonalCorrections>,
    /// Frames ModelNet saw.
    pub selected_frames: Vec<usize>,
    pub intrinsics: Intrinsics,
    /// Per blendshape: the largest personal correction |F(A_i dS_i)| over the vertices, mm.
    pub correction_mm: [f32; NUM_BLENDSHAPES],
}

impl StudioSession {
    pub fn from_demo(model: &FaceModel, demo: DemoSession) -> Self {
        let mut session = Self::from_tracking(
            model,
            DEMO_SOURCE.into(),
            demo.config.fps,
            demo.frames,
            demo.outputs,
            demo.records,
            demo.learned,
            demo.learned_blendshapes,
            demo.selected_frames,
            demo.intrinsics,
        );
        session.truth = Some(demo.truth);
        session
    }

    /// A session from tracked and personalized footage (frames, outputs and records are
    /// aligned by position).
    #[allow(clippy::too_many_arguments)] // each is one part of the pipeline's result
    pub fn from_tracking(
        model: &FaceModel,
        source: String,
        fps: f64,
        frames: Vec<RgbImage>,
        outputs: Vec<FrameOutput>,
        records: Vec<FrameRecord>,
        corrections: PersonalCorrections,
        blendshapes: Arc<PersonalizedBlendshapes>,
        selected_frames: Vec<usize>,
        intrinsics: Intrinsics,
    ) -> Self {
        let correction_mm = correction_sizes_mm(model, &blendshapes);
        let observations = outputs
            .iter()
            .map(|o| FrameObservations {
                detected: o
                    .observations
                    .as_ref()
                    .map(|obs| obs.points.iter().map(|p| p.pixel.to_array()).collect())
                    .unwrap_or_default(),
                crop: o.crop.map(|c| c.to_array()),
            })
            .collect();
        Self {
            source,
            fps,
            frames,
            observations,
            records,
            corrections,
            blendshapes,
            truth: None,
            selected_frames,
            intrinsics,
            correction_mm,
        }
    }

    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    /// The tracked weights of frame `k` (zeros without a face).
    pub fn weights(&self, k: usize) -> BlendshapeWeights {
        let mut w = BlendshapeWeights::default();
        if let Some(track) = self.records.get(k).and_then(|r| r.track.as_ref()) {
            for (o, v) in w.0.iter_mut().zip(&track.weights) {
                *o = *v;
            }
        }
        w
    }

    /// What the panels draw over frame `k`.
    pub fn overlay(&self, k: usize) -> FrameOverlay {
        let observed = self.observations.get(k);
        let detected = observed
            .map(|o| o.detected.iter().map(|p| Vec2::from(*p)).collect())
            .unwrap_or_default();
        let track = self.records.get(k).and_then(|r| r.track.as_ref());
        FrameOverlay {
            detected,
            model: track
                .map(|t| t.landmarks_68.iter().map(|p| Vec2::from(*p)).collect())
                .unwrap_or_default(),
            face_box: track.map(|t| t.face_box),
            crop: observed.and_then(|o| o.crop),
            confidence: track.map(|t| t.confidence),
        }
    }

    /// The session as a file (`tracking::session`, version 2: the footage and what was
    /// detected in it travel with the model and the tracking).
    pub fn to_file(&self) -> Session {
        let mut tracks = TracksDocument::new(self.source.clone(), self.fps);
        let k = &self.intrinsics;
        tracks.camera = Some(CameraRecord {
            width: k.width,
            height: k.height,
            focal_px: k.focal_px,
            cx: k.cx,
            cy: k.cy,
        });
        tracks.frames = self.records.clone();
        Session {
            info: SessionInfo {
                created_by: format!("likeness {} studio", env!("CARGO_PKG_VERSION")),
                source: self.source.clone(),
                selected_frames: self.selected_frames.clone(),
                backend: String::new(),
                networks: String::new(),
            },
            corrections: self.corrections.clone(),
            tracks,
            footage: Some(self.frames.clone()),
            observations: self.observations.clone(),
        }
    }

    /// A session from its file. Files written by `likeness personalize` hold no footage:
    /// their frames are shown grey (the model and the tracking are all there).
    pub fn from_file(model: &FaceModel, file: Session) -> Result<Self, String> {
        let Some(camera) = file.tracks.camera else {
            return Err("the session has no camera (its tracking has no frames)".into());
        };
        if camera.width == 0 || camera.height == 0 {
            return Err("the session's camera has no size".into());
        }
        tracking::source::check_frame_size(camera.width, camera.height)
            .map_err(|e| format!("the session's camera: {e}"))?;
        if ![camera.focal_px, camera.cx, camera.cy]
            .iter()
            .all(|v| v.is_finite())
            || camera.focal_px <= 0.0
        {
            return Err("the session's camera is not valid".into());
        }
        let count = file.tracks.frames.len();
        let frames = match file.footage {
            Some(frames)
                if frames
                    .iter()
                    .all(|f| f.dimensions() == (camera.width, camera.height)) =>
            {
                frames
            }
            Some(_) => return Err("the footage is not the size of the session's camera".into()),
            None => {
                let bytes = u64::from(camera.width) * u64::from(camera.height) * 3 * count as u64;
                if bytes > MAX_PLACEHOLDER_BYTES {
                    return Err(format!(
                        "the session has no footage, and grey frames in its place ({count} of \
                         {}x{}) would take {:.1} GB, more than the {} GB the studio allows them",
                        camera.width,
                        camera.height,
                        bytes as f64 / 1e9,
                        MAX_PLACEHOLDER_BYTES >> 30
                    ));
                }
                let grey = RgbImage::from_pixel(camera.width, camera.height, image::Rgb([96; 3]));
                vec![grey; count]
            }
        };
        let observations = if file.observations.len() == count {
            file.observations
        } else {
            vec![FrameObservations::default(); count]
        };
        // Last: the file's own data is checked before the model is built from it.
        let blendshapes = Arc::new(
            model
                .personalize(&file.corrections)
                .map_err(|e| format!("the personal corrections: {e}"))?,
        );
        let correction_mm = correction_sizes_mm(model, &blendshapes);
        Ok(Self {
            source: file.info.source,
            fps: if file.tracks.fps.is_finite() && file.tracks.fps > 0.0 {
                file.tracks.fps
            } else {
                30.0
            },
            frames,
            observations,
            records: file.tracks.frames,
            corrections: file.corrections,
            blendshapes,
            truth: None,
            selected_frames: file
                .info
                .selected_frames
                .into_iter()
                .filter(|&k| k < count)
                .collect(),
            intrinsics: Intrinsics {
                focal_px: camera.focal_px,
                cx: camera.cx,
                cy: camera.cy,
                width: camera.width,
                height: camera.height,
            },
            correction_mm,
        })
    }

    /// Writes the session atomically to `path`.
    pub fn save(&self, path: &std::path::Path) -> Result<(), String> {
        self.to_file()
            .save(path)
            .map_err(|e| format!("cannot save {}: {e}", path.display()))
    }

    /// The session file's bytes (a download in the browser).
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        self.to_file()
            .to_bytes()
            .map_err(|e| format!("cannot encode the session: {e}"))
    }

    /// A session from a file's bytes, called `name` in messages.
    pub fn from_bytes(model: &FaceModel, name: &str, bytes: &[u8]) -> Result<Self, String> {
        let file = Session::from_bytes(bytes).map_err(|e| format!("{name}: {e}"))?;
        Self::from_file(model, file).map_err(|e| format!("{name}: {e}"))
    }

    /// Reads a session file.
    pub fn load(model: &FaceModel, path: &std::path::Path) -> Result<Self, String> {
        let file = Session::load(path).map_err(|e| e.to_string())?;
        Self::from_file(model, file).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// The tracked frames as retargeting input (ARKit channels and head rotation), frames
    /// without a face left out and counted.
    pub fn tracks(&self) -> Tracks {
        let mut tracks = Tracks::default();
        for record in &self.records {
            let Some(track) = record.track.as_ref() else {
                tracks.frames_without_face += 1;
                continue;
            };
            let mut ict = [0.0f32; NUM_BLENDSHAPES];
            for (o, v) in ict.iter_mut().zip(&track.weights) {
                *o = *v;
            }
            tracks.frames.push(TrackedFrame {
                time_s: record.time_s as f32,
                arkit: ict_to_arkit(&ict),
                rotation_deg: Some(track.rotation_deg),
            });
        }
        tracks
    }

    /// The head rotation [yaw, pitch, roll] in degrees of frame `k` (zero without a face).
    pub fn rotation_deg(&self, k: usize) -> [f32; 3] {
        self.records
            .get(k)
            .and_then(|r| r.track.as_ref())
            .map_or([0.0; 3], |t| t.rotation_deg)
    }

    /// Blendshape indices ordered by the size of their personal correction, largest first.
    pub fn by_correction_size(&self) -> Vec<usize> {
        let mut order: Vec<usize> = (0..NUM_BLENDSHAPES).collect();
        order.sort_by(|&a, &b| self.correction_mm[b].total_cmp(&self.correction_mm[a]));
        order
    }
}

/// Landmarks, boxes and confidence of one frame, in frame pixels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FrameOverlay {
    /// The face locator's landmarks (OpenSeeFace, iBUG order where known).
    pub detected: Vec<Vec2>,
    /// The tracked model's 68 landmarks projected into the frame.
    pub model: Vec<Vec2>,
    /// [x, y, w, h] of the model's landmarks.
    pub face_box: Option<[f32; 4]>,
    /// [x, y, w, h] of the crop TrackNet saw.
    pub crop: Option<[f32; 4]>,
    pub confidence: Option<f32>,
}

impl FrameOverlay {
    /// The overlay of a frame straight from the tracker (before personalization), as a
    /// running job shows it.
    pub fn from_output(out: &tracking::pipeline::FrameOutput) -> Self {
        let track = out.record.track.as_ref();
        Self {
            detected: out
                .observations
                .as_ref()
                .map(|obs| obs.points.iter().map(|p| p.pixel).collect())
                .unwrap_or_default(),
            model: track
                .map(|t| t.landmarks_68.iter().map(|p| Vec2::from(*p)).collect())
                .unwrap_or_default(),
            face_box: track.map(|t| t.face_box),
            crop: out.crop.map(|c| c.to_array()),
            confidence: track.map(|t| t.confidence),
        }
    }
}

/// Per blendshape, the largest |F(A_i dS_i)| over the vertices, in millimetres.
pub fn correction_sizes_mm(
    model: &FaceModel,
    blendshapes: &PersonalizedBlendshapes,
) -> [f32; NUM_BLENDSHAPES] {
    std::array::from_fn(|i| {
        blendshapes
            .correction_magnitude(&model.template, i)
            .into_iter()
            .fold(0.0f32, f32::max)
            * 10.0
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A face model on a four-vertex template: `from_file` needs a model, not the ICT
    /// FaceKit's 26k vertices.
    fn tiny_model() -> FaceModel {
        FaceModel::new(face::Template::one_quad("tiny"))
    }

    /// A `likeness personalize` session (no footage) of `count` frames of `width` x
    /// `height`.
    fn file(width: u32, height: u32, count: usize) -> Session {
        let mut tracks = TracksDocument::new("clip.mp4".into(), 30.0);
        tracks.camera = Some(CameraRecord {
            width,
            height,
            focal_px: 500.0,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
        });
        tracks.frames = (0..count)
            .map(|k| FrameRecord::no_face(k, k as f64 / 30.0, None))
            .collect();
        Session {
            info: SessionInfo::default(),
            corrections: PersonalCorrections::zeros(),
            tracks,
            footage: None,
            observations: Vec::new(),
        }
    }

    #[test]
    fn a_session_without_footage_shows_grey_frames_of_its_camera() {
        let session = StudioSession::from_file(&tiny_model(), file(8, 6, 3)).expect("loads");
        assert_eq!(session.frame_count(), 3);
        assert!(session.frames.iter().all(|f| f.dimensions() == (8, 6)));
    }

    /// Found by the session fuzz target (fuzz/regressions/session/): grey frames for a
    /// camera of any size were allocated, and a file with a 100000 x 100000 camera, or
    /// 200 frames of 50 megapixels, ended the studio on an allocation failure.
    #[test]
    fn cameras_and_grey_footage_beyond_the_limits_are_refused_not_allocated() {
        let model = tiny_model();
        let e = StudioSession::from_file(&model, file(100_000, 100_000, 2))
            .err()
            .expect("a 100000 x 100000 camera");
        assert!(e.contains("camera") && e.contains("at most"), "{e}");
        let e = StudioSession::from_file(&model, file(8_000, 6_000, 200))
            .err()
            .expect("200 frames of 48 megapixels");
        assert!(e.contains("no footage") && e.contains("GB"), "{e}");
    }
}
