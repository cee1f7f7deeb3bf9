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
use face::{
    BlendshapeWeights, FaceModel, NUM_BLENDSHAPES, PersonalCorrections, PersonalizedBlendshapes,
};
use glam::Vec2;
use image::RgbImage;
use tracking::pipeline::FrameOutput;
use tracking::record::FrameRecord;

use crate::demo::DemoSession;

/// One person's session in the studio.
pub struct StudioSession {
    /// Where the footage came from (file, folder, "built-in demo").
    pub source: String,
    pub fps: f64,
    pub frames: Vec<RgbImage>,
    /// Per frame: detection, crop and TrackNet's output.
    pub outputs: Vec<FrameOutput>,
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
        let correction_mm = correction_sizes_mm(model, &demo.learned_blendshapes);
        Self {
            source: "built-in demo".into(),
            fps: demo.config.fps,
            frames: demo.frames,
            outputs: demo.outputs,
            records: demo.records,
            corrections: demo.learned,
            blendshapes: demo.learned_blendshapes,
            truth: Some(demo.truth),
            selected_frames: demo.selected_frames,
            intrinsics: demo.intrinsics,
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
        let output = self.outputs.get(k);
        let detected = output
            .and_then(|o| o.observations.as_ref())
            .map(|obs| obs.points.iter().map(|p| p.pixel).collect())
            .unwrap_or_default();
        let track = self.records.get(k).and_then(|r| r.track.as_ref());
        FrameOverlay {
            detected,
            model: track
                .map(|t| t.landmarks_68.iter().map(|p| Vec2::from(*p)).collect())
                .unwrap_or_default(),
            face_box: track.map(|t| t.face_box),
            crop: output.and_then(|o| o.crop).map(|c| c.to_array()),
            confidence: track.map(|t| t.confidence),
        }
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
