//! Face detection and 66-point landmarks on real footage with the OpenSeeFace models, and
//! the video logic that follows one face from frame to frame.
//!
//! The project's own networks are trained on synthetic faces and need a face crop; real
//! images and video need a detector and a landmark source to place that crop and to
//! supervise refinement. OpenSeeFace (BSD 2-Clause, upstream: the public GitHub repository
//! `emilianavt/OpenSeeFace`, folder `models/`) has a small detector (`mnv3_detection`) and
//! a fast 66-point landmark network (`lm_model0`) that run in real time on a CPU, in ONNX
//! Runtime natively and in tract (also in wasm32). `shared/models/README.md` describes
//! their inputs, outputs and decoding; the numbers below follow it and upstream's
//! `tracker.py`.
//!
//! Coordinates: every point and box is in frame pixels of the image passed in, continuous,
//! with pixel (row i, column j) covering [j, j+1) x [i, i+1), as in [`crate::preprocess`].
//!
//! # The 66-point layout
//!
//! The 66 points are *not* iBUG 68 with two inner-lip points left out. Points 0-47 (jaw,
//! brows, nose, eyes) are iBUG's; the mouth (48-65) has no separate outer and inner corners
//! but one corner per side, so its order differs from iBUG from point 48 on. Measured on
//! the real crop `shared/testdata/faces/openseeface-raw1.png` (the head rolled so that the
//! mouth rises about 15 degrees to the image-right, the mouth a little open; points in crop
//! pixels from `landmarks` on the whole crop; the test `landmark_overlay_is_written` draws
//! them, coloured by their iBUG role, into `target/tmp/landmarks-openseeface.png`):
//!
//! - 58 (98, 139) and 62 (145, 127) are the extreme left and right points of the mouth,
//!   beyond every other mouth point along the line through them: the two mouth corners.
//!   Point 54, which iBUG's order would make the right corner, sits on the lower lip at
//!   (136, 145), 10 px left of and 18 px below 62.
//! - 48-52 run left to right along the upper edge of the upper lip, (107, 129) to
//!   (136, 120), 50 being the middle (122, 120); none of them is a corner.
//! - 53-57 run right to left along the lower edge of the lower lip, (141, 137) to
//!   (108, 147), 55 the middle (128, 150).
//! - 59-61 run left to right along the upper lip's inner edge, (111, 131) to (133, 125),
//!   and 63-65 right to left along the lower lip's inner edge, (135, 135) to (113, 141),
//!   10-13 px below the point of 59-61 opposite; the dark mouth opening lies between.
//!
//! Upstream agrees: `tracker.py`'s feature extractor measures the mouth corners at points
//! 58 and 62, mouth opening as points 59-61 against 63-65, and the face's centre line
//! through points 50 and 55 (and 60, 64); its 3D reference face has 58 and 62 at the
//! widest x of the mouth. In iBUG 68 terms (48 and 54 outer corners, 49-53 upper outer,
//! 55-59 lower outer, 60 and 64 inner corners, 61-63 upper inner, 65-67 lower inner):
//! 48-52 -> 49-53, 53-57 -> 55-59, 58 -> 48, 62 -> 54, 59-61 -> 61-63, 63-65 -> 65-67.
//! The one corner per side is taken as iBUG's outer corner (48, 54): for a closed or
//! slightly open mouth inner and outer corners coincide within a pixel or two, and the
//! first 60 iBUG points (which place the crop, [`crate::preprocess::CROP_LANDMARKS`]) are
//! then all present. iBUG's inner corners 60 and 64 have no counterpart and stay `None`
//! rather than counting the corner twice.

use std::path::{Path, PathBuf};
use web_time::Instant;

use glam::Vec2;
use image::RgbImage;

use crate::backend::{BackendKind, InferenceBackend, Tensor, load_model};
use crate::error::{Result, TrackingError};
use crate::preprocess::{Normalisation, Rect, sample_rect};

/// Side of the square input of both networks, in pixels.
pub const INPUT_SIZE: usize = 224;
/// Points the landmark network predicts.
pub const LANDMARK_COUNT: usize = 66;
/// Points of the iBUG 68 layout the rest of the project uses.
pub const IBUG_LANDMARK_COUNT: usize = 68;

/// Upstream's detection threshold: a local maximum of the face-centre map is a face when it
/// reaches this confidence.
pub const DEFAULT_DETECTION_THRESHOLD: f32 = 0.6;
/// Two detections whose intersection over union reaches this are the same face; upstream
/// groups its candidate faces with the same ratio (`intersects(amount=0.3)`).
pub const DEFAULT_OVERLAP_THRESHOLD: f32 = 0.3;
/// Upstream's threshold on the mean landmark confidence for `lm_model0`: below it the crop
/// holds no face (or lost it), so the follower detects again.
pub const DEFAULT_MIN_LANDMARK_CONFIDENCE: f32 = 0.6;

/// The detector's output grid: 56 x 56 cells over the 224 x 224 input, 4 pixels a cell.
const DETECTOR_GRID: usize = 56;
const DETECTOR_CELL: f32 = 4.0;
/// Channel 1 of the detector output is the face radius in units of half the input side.
const DETECTOR_RADIUS_SCALE: f32 = 112.0;

/// The landmark network's heatmaps: 28 x 28, one per point, then two offset blocks.
const HEATMAP_SIZE: usize = 28;
const HEATMAP_CELLS: usize = HEATMAP_SIZE * HEATMAP_SIZE;
const LANDMARK_CHANNELS: usize = 3 * LANDMARK_COUNT;
/// Upstream's decoding: cell index * 223 / 27 plus 223 * logit(offset) / 16, which spans
/// pixel indices 0..=223 of the 224-pixel crop.
const LAST_PIXEL: f32 = (INPUT_SIZE - 1) as f32;
const LAST_CELL: f32 = (HEATMAP_SIZE - 1) as f32;
const LOGIT_FACTOR: f32 = 16.0;
/// Upstream clips offsets to (1e-7, 1 - 1e-7) before the logit so 0 and 1 stay finite.
const LOGIT_CLIP: f32 = 1e-7;

/// Upstream grows the detector box by 10% of its width on the left and on the right and
/// 12.5% of its height at the top and the bottom before cropping for the landmark network.
const CROP_GROWTH_X: f32 = 0.1;
const CROP_GROWTH_Y: f32 = 0.125;
/// Upstream skips crops narrower or shorter than 4 frame pixels: nothing to see in them.
const MIN_CROP_SIDE: f32 = 4.0;

/// Where upstream publishes the models, for error messages.
const UPSTREAM: &str = "the public GitHub repository emilianavt/OpenSeeFace, folder models/";

/// The model directory used when none is given: `$LIKENESS_MODELS/openseeface` when
/// `LIKENESS_MODELS` is set, else `shared/models/openseeface` beside the repository (the
/// workplace layout; a user elsewhere sets `LIKENESS_MODELS` or passes `--models`).
pub fn default_models_dir() -> PathBuf {
    match std::env::var_os("LIKENESS_MODELS").filter(|v| !v.is_empty()) {
        Some(root) => PathBuf::from(root).join("openseeface"),
        None => Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
            .join("../shared/models/openseeface"),
    }
}

/// The detector and landmark files for `kind` in `dir`. ONNX Runtime runs upstream's
/// `_opt` files, whose `FusedConv` nodes only it knows; tract runs the `_plain_b1`
/// rewrites of the same networks (standard operators, batch 1).
pub fn model_files(dir: &Path, kind: BackendKind) -> (PathBuf, PathBuf) {
    let suffix = match kind {
        BackendKind::OnnxRuntime => "opt",
        BackendKind::Tract => "plain_b1",
    };
    (
        dir.join(format!("mnv3_detection_{suffix}.onnx")),
        dir.join(format!("lm_model0_{suffix}.onnx")),
    )
}

/// What a user needs to know when a model file is not where it is looked for.
fn missing_model_hint(dir: &Path, kind: BackendKind) -> String {
    let place = if dir.is_dir() {
        format!("the directory {} lacks it", dir.display())
    } else {
        format!("the directory {} does not exist", dir.display())
    };
    let files = match kind {
        BackendKind::OnnxRuntime => "mnv3_detection_opt.onnx and lm_model0_opt.onnx come from",
        BackendKind::Tract => {
            "mnv3_detection_plain_b1.onnx and lm_model0_plain_b1.onnx are \
             upstream's mnv3_detection_opt.onnx and lm_model0_opt.onnx with ONNX Runtime's \
             FusedConv rewritten as Conv + activation and the batch fixed to 1 (see \
             shared/models/README.md); the originals come from"
        }
    };
    format!(
        "{place}. The OpenSeeFace models {files} {UPSTREAM}. Point Likeness at the folder \
         holding them with `--models DIR`, or set LIKENESS_MODELS to a directory that \
         holds them in a subfolder `openseeface`"
    )
}

/// A model file that exists but cannot be read or run is damaged (a partial download, a
/// different file under the same name): the error names the whole path and says what to
/// do. Errors that are not about the file (no ONNX Runtime library) pass unchanged.
fn damaged_model(path: &Path, error: TrackingError) -> TrackingError {
    match error {
        TrackingError::Inference { .. } => TrackingError::Decode {
            path: path.to_owned(),
            reason: format!(
                "{error} (the file is damaged or not this model; fetch it again from {UPSTREAM})"
            ),
        },
        other => other,
    }
}

/// A face the detector found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceDetection {
    /// Frame pixels. Square in the detector's 224 x 224 view of the frame, so its aspect
    /// ratio is the frame's.
    pub face_box: Rect,
    /// The face-centre map's value at the detection, 0..1.
    pub confidence: f32,
}

impl FaceDetection {
    pub fn area(&self) -> f32 {
        self.face_box.width * self.face_box.height
    }
}

/// The detection to follow when a frame shows several faces: the largest, because the
/// person in front of the camera (the one being tracked and personalized) is nearest to it,
/// while faces behind them, on posters or on screens are smaller; upstream instead keeps
/// the most confident, which can jump between people from frame to frame.
pub fn largest_face(detections: &[FaceDetection]) -> Option<FaceDetection> {
    detections
        .iter()
        .copied()
        .max_by(|a, b| a.area().total_cmp(&b.area()))
}

/// The 66 points of one face.
#[derive(Clone, Debug, PartialEq)]
pub struct Landmarks66 {
    /// Frame pixels, in OpenSeeFace's order (see the module documentation).
    pub points_in_frame: [Vec2; LANDMARK_COUNT],
    /// Each point's heatmap peak, 0..1.
    pub confidence: [f32; LANDMARK_COUNT],
    /// The mean of `confidence`: how much the network believes the crop holds a face.
    pub mean_confidence: f32,
    /// The frame rectangle the network saw (the face box grown and clipped to the frame).
    pub crop: Rect,
}

/// iBUG 68 index of each OpenSeeFace point; derived and checked on a real face (module
/// documentation).
pub const OPENSEEFACE_TO_IBUG68: [usize; LANDMARK_COUNT] = {
    let mut map = [0; LANDMARK_COUNT];
    let mut i = 0;
    while i < LANDMARK_COUNT {
        map[i] = match i {
            // Jaw, brows, nose, eyes: identical.
            0..=47 => i,
            // Upper outer lip without the corners.
            48..=52 => i + 1,
            // Lower outer lip without the corners.
            53..=57 => i + 2,
            // Left and right mouth corner.
            58 => 48,
            62 => 54,
            // Upper inner lip.
            59..=61 => i + 2,
            // Lower inner lip (63..=65).
            _ => i + 2,
        };
        i += 1;
    }
    map
};

impl Landmarks66 {
    /// The bounding box of all 66 points; `None` if it is empty or not finite.
    pub fn bounding_box(&self) -> Option<Rect> {
        Rect::bounding(self.points_in_frame.iter().copied()).filter(Rect::is_valid)
    }

    /// The points in the iBUG 68 layout with their confidences: every iBUG point but the
    /// inner mouth corners 60 and 64 (which OpenSeeFace does not have) is `Some`.
    pub fn to_ibug68(&self) -> [Option<(Vec2, f32)>; IBUG_LANDMARK_COUNT] {
        let mut out = [None; IBUG_LANDMARK_COUNT];
        for (i, &ibug) in OPENSEEFACE_TO_IBUG68.iter().enumerate() {
            out[ibug] = Some((self.points_in_frame[i], self.confidence[i]));
        }
        out
    }
}

/// The rectangle the landmark network sees for `face_box`: grown as upstream does and
/// clipped to the `width` x `height` frame (upstream clips too: the network was used on
/// crops that never extend past the image). `None` when too little of it is in the frame.
pub fn landmark_crop(face_box: Rect, width: u32, height: u32) -> Option<Rect> {
    if !face_box.is_valid() {
        return None;
    }
    let grow_x = CROP_GROWTH_X * face_box.width;
    let grow_y = CROP_GROWTH_Y * face_box.height;
    let x0 = (face_box.x - grow_x).max(0.0);
    let y0 = (face_box.y - grow_y).max(0.0);
    let x1 = (face_box.x + face_box.width + grow_x).min(width as f32);
    let y1 = (face_box.y + face_box.height + grow_y).min(height as f32);
    let crop = Rect {
        x: x0,
        y: y0,
        width: x1 - x0,
        height: y1 - y0,
    };
    (crop.is_valid() && crop.width >= MIN_CROP_SIDE && crop.height >= MIN_CROP_SIDE).then_some(crop)
}

/// Intersection over union of two rectangles (0 when either is empty).
pub fn intersection_over_union(a: Rect, b: Rect) -> f32 {
    let left = a.x.max(b.x);
    let right = (a.x + a.width).min(b.x + b.width);
    let top = a.y.max(b.y);
    let bottom = (a.y + a.height).min(b.y + b.height);
    if !(left < right && top < bottom) {
        return 0.0;
    }
    let intersection = (right - left) * (bottom - top);
    let union = a.width * a.height + b.width * b.height - intersection;
    if union > 0.0 {
        intersection / union
    } else {
        0.0
    }
}

/// The OpenSeeFace detector and landmark network on one backend.
pub struct OpenSeeFace {
    detector: Box<dyn InferenceBackend>,
    landmark_network: Box<dyn InferenceBackend>,
    detector_name: String,
    landmark_name: String,
    kind: BackendKind,
    detection_threshold: f32,
    overlap_threshold: f32,
}

impl OpenSeeFace {
    /// Loads both networks from `dir` (see [`model_files`]) and runs each once on a blank
    /// input, so a file that parses but cannot run (or returns unexpected shapes) fails
    /// here and not on the first frame, and so tract's one-off graph optimisation is not
    /// counted in the first frame's timings.
    pub fn load(dir: &Path, kind: BackendKind, threads: usize) -> Result<Self> {
        let (detector_path, landmark_path) = model_files(dir, kind);
        for path in [&detector_path, &landmark_path] {
            if !path.is_file() {
                return Err(TrackingError::MissingModel {
                    path: path.clone(),
                    hint: missing_model_hint(dir, kind),
                });
            }
        }
        let detector = load_model(&detector_path, kind, threads)
            .map_err(|e| damaged_model(&detector_path, e))?;
        let landmark_network = load_model(&landmark_path, kind, threads)
            .map_err(|e| damaged_model(&landmark_path, e))?;
        Self::from_backends(
            (detector, &detector_path),
            (landmark_network, &landmark_path),
        )
    }

    /// Both networks already loaded (the browser reads them from fetched bytes), each with
    /// the path its messages name; checked by one run on a blank input as in
    /// [`OpenSeeFace::load`].
    pub fn from_backends(
        detector: (Box<dyn InferenceBackend>, &Path),
        landmark_network: (Box<dyn InferenceBackend>, &Path),
    ) -> Result<Self> {
        let (detector, detector_path) = detector;
        let (landmark_network, landmark_path) = landmark_network;
        let kind = detector.kind();
        let mut tracker = Self {
            detector,
            landmark_network,
            detector_name: display_name(detector_path),
            landmark_name: display_name(landmark_path),
            kind,
            detection_threshold: DEFAULT_DETECTION_THRESHOLD,
            overlap_threshold: DEFAULT_OVERLAP_THRESHOLD,
        };
        let blank = Tensor::zeros(vec![1, 3, INPUT_SIZE, INPUT_SIZE]);
        tracker
            .run_detector(&blank)
            .map_err(|e| damaged_model(detector_path, e))?;
        tracker
            .run_landmark_network(&blank)
            .map_err(|e| damaged_model(landmark_path, e))?;
        Ok(tracker)
    }

    pub fn kind(&self) -> BackendKind {
        self.kind
    }

    pub fn detection_threshold(&self) -> f32 {
        self.detection_threshold
    }

    /// Sets the confidence a face-centre peak needs to count as a face (default
    /// [`DEFAULT_DETECTION_THRESHOLD`]). Lower finds faces that fill the whole frame
    /// (the detector scores those lower) at the price of more false detections.
    pub fn set_detection_threshold(&mut self, threshold: f32) {
        self.detection_threshold = threshold;
    }

    pub fn with_detection_threshold(mut self, threshold: f32) -> Self {
        self.detection_threshold = threshold;
        self
    }

    pub fn overlap_threshold(&self) -> f32 {
        self.overlap_threshold
    }

    /// Sets the intersection over union from which two detections count as one face
    /// (default [`DEFAULT_OVERLAP_THRESHOLD`]).
    pub fn set_overlap_threshold(&mut self, threshold: f32) {
        self.overlap_threshold = threshold;
    }

    /// The faces in `image`, most confident first, overlapping detections of one face
    /// reduced to the most confident. The whole frame is resized to the detector's 224 x
    /// 224 input (not letterboxed, as upstream), so boxes are square in that view.
    pub fn detect(&mut self, image: &RgbImage) -> Result<Vec<FaceDetection>> {
        let frame = Rect {
            x: 0.0,
            y: 0.0,
            width: image.width() as f32,
            height: image.height() as f32,
        };
        let input = sample_rect(
            image,
            frame,
            INPUT_SIZE,
            INPUT_SIZE,
            Normalisation::IMAGENET,
        )?;
        let (centre_map, maxpool) = self.run_detector(&input)?;
        let to_frame = Vec2::new(frame.width, frame.height) / INPUT_SIZE as f32;
        let plane = DETECTOR_GRID * DETECTOR_GRID;
        let mut candidates = Vec::new();
        for cell in 0..plane {
            let confidence = centre_map[cell];
            // A peak is a cell the 3x3 max pool did not change; comparing the two outputs
            // exactly is upstream's rule, both come from the same values.
            if confidence < self.detection_threshold || confidence != maxpool[cell] {
                continue;
            }
            let radius = centre_map[plane + cell] * DETECTOR_RADIUS_SCALE;
            let centre = DETECTOR_CELL
                * Vec2::new((cell % DETECTOR_GRID) as f32, (cell / DETECTOR_GRID) as f32);
            let face_box = Rect {
                x: (centre.x - radius) * to_frame.x,
                y: (centre.y - radius) * to_frame.y,
                width: 2.0 * radius * to_frame.x,
                height: 2.0 * radius * to_frame.y,
            };
            if face_box.is_valid() {
                candidates.push(FaceDetection {
                    face_box,
                    confidence,
                });
            }
        }
        candidates.sort_by(|a, b| b.confidence.total_cmp(&a.confidence));
        let mut kept: Vec<FaceDetection> = Vec::with_capacity(candidates.len());
        for candidate in candidates {
            if kept.iter().all(|k| {
                intersection_over_union(k.face_box, candidate.face_box) < self.overlap_threshold
            }) {
                kept.push(candidate);
            }
        }
        Ok(kept)
    }

    /// The 66 landmarks of the face in `face_box` (frame pixels, usually a detection's box
    /// or the previous frame's landmark box).
    pub fn landmarks(&mut self, image: &RgbImage, face_box: Rect) -> Result<Landmarks66> {
        let crop = landmark_crop(face_box, image.width(), image.height()).ok_or_else(|| {
            TrackingError::InvalidInput(format!(
                "face box {face_box:?} lies (almost) outside the {}x{} frame",
                image.width(),
                image.height()
            ))
        })?;
        let input = sample_rect(image, crop, INPUT_SIZE, INPUT_SIZE, Normalisation::IMAGENET)?;
        let output = self.run_landmark_network(&input)?;
        Ok(decode_landmarks(&output, crop))
    }

    /// Runs the detector; returns its two outputs' first image (face-centre and radius
    /// maps; their 3x3 max pool), checked for shape and finiteness.
    fn run_detector(&mut self, input: &Tensor) -> Result<(Vec<f32>, Vec<f32>)> {
        let outputs = self.detector.run(input)?;
        let expected = [1, 2, DETECTOR_GRID, DETECTOR_GRID];
        let mut outputs = outputs.into_iter();
        let (Some(centre_map), Some(maxpool)) = (outputs.next(), outputs.next()) else {
            return Err(TrackingError::BadOutput {
                model: self.detector_name.clone(),
                reason: "count: expected `output` and `maxpool`".into(),
            });
        };
        for (tensor, name) in [(&centre_map, "output"), (&maxpool, "maxpool")] {
            check_output(tensor, &expected, &self.detector_name, name)?;
        }
        Ok((centre_map.data, maxpool.data))
    }

    /// Runs the landmark network; returns its output's first image, checked.
    fn run_landmark_network(&mut self, input: &Tensor) -> Result<Vec<f32>> {
        let output = self
            .landmark_network
            .run(input)?
            .into_iter()
            .next()
            .ok_or_else(|| TrackingError::BadOutput {
                model: self.landmark_name.clone(),
                reason: "count: expected `output`".into(),
            })?;
        let expected = [1, LANDMARK_CHANNELS, HEATMAP_SIZE, HEATMAP_SIZE];
        check_output(&output, &expected, &self.landmark_name, "output")?;
        Ok(output.data)
    }
}

pub(crate) fn display_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// An output of the expected shape and finite, or an error naming the model and output.
pub(crate) fn check_output(
    tensor: &Tensor,
    expected: &[usize],
    model: &str,
    output: &str,
) -> Result<()> {
    if tensor.shape != expected || tensor.data.len() != expected.iter().product::<usize>() {
        return Err(TrackingError::BadOutput {
            model: model.to_owned(),
            reason: format!(
                "`{output}` of shape {:?}, expected {expected:?}",
                tensor.shape
            ),
        });
    }
    if !tensor.is_finite() {
        return Err(TrackingError::NonFinite {
            model: model.to_owned(),
            output: output.to_owned(),
        });
    }
    Ok(())
}

/// `ln(p / (1 - p)) / 16` with p clipped as upstream does.
fn offset_logit(p: f32) -> f32 {
    let p = p.clamp(LOGIT_CLIP, 1.0 - LOGIT_CLIP);
    (p / (1.0 - p)).ln() / LOGIT_FACTOR
}

/// The index and value of the first largest element, as numpy's `argmax` picks it.
fn first_maximum(values: &[f32]) -> (usize, f32) {
    let mut best = (0, f32::NEG_INFINITY);
    for (i, &v) in values.iter().enumerate() {
        if v > best.1 {
            best = (i, v);
        }
    }
    best
}

/// Decodes the landmark network's [198, 28, 28] output (checked by the caller) for `crop`.
fn decode_landmarks(output: &[f32], crop: Rect) -> Landmarks66 {
    let mut points_in_frame = [Vec2::ZERO; LANDMARK_COUNT];
    let mut confidence = [0.0; LANDMARK_COUNT];
    let heatmap = |channel: usize| &output[channel * HEATMAP_CELLS..(channel + 1) * HEATMAP_CELLS];
    for (k, (point, point_confidence)) in points_in_frame
        .iter_mut()
        .zip(confidence.iter_mut())
        .enumerate()
    {
        let (cell, peak) = first_maximum(heatmap(k));
        let (row, col) = ((cell / HEATMAP_SIZE) as f32, (cell % HEATMAP_SIZE) as f32);
        // The first offset block is the row (y) direction, the second the column (x).
        let row_offset = offset_logit(heatmap(LANDMARK_COUNT + k)[cell]);
        let col_offset = offset_logit(heatmap(2 * LANDMARK_COUNT + k)[cell]);
        let y_index = LAST_PIXEL * (row / LAST_CELL + row_offset);
        let x_index = LAST_PIXEL * (col / LAST_CELL + col_offset);
        // The decoded values index the crop's pixels; + 0.5 moves to their centres.
        let in_crop = Vec2::new(x_index + 0.5, y_index + 0.5);
        *point = crop.to_frame(in_crop, INPUT_SIZE as f32, INPUT_SIZE as f32);
        *point_confidence = peak;
    }
    let mean_confidence = confidence.iter().sum::<f32>() / LANDMARK_COUNT as f32;
    Landmarks66 {
        points_in_frame,
        confidence,
        mean_confidence,
        crop,
    }
}

// --- following a face through a video ---------------------------------------------------

/// Time spent on one frame, for benchmark tables.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StepTimings {
    /// In the detector, including resampling the frame (zero when it did not run).
    pub detect_ms: f64,
    /// In the landmark network, including the crop (one or two runs).
    pub landmarks_ms: f64,
}

/// One frame's result of [`FaceFollower::step`].
#[derive(Clone, Debug, PartialEq)]
pub struct FollowResult {
    pub landmarks: Landmarks66,
    /// The box the landmarks were computed from: the previous frame's landmark box, or this
    /// frame's detection.
    pub face_box: Rect,
    /// Whether the detector ran on this frame.
    pub detected: bool,
    /// Milliseconds in the detector this frame (0 when it did not run).
    pub detect_ms: f64,
    /// Milliseconds in the landmark network this frame.
    pub landmarks_ms: f64,
}

/// Follows one face through a video as the paper does (section 4 and its appendix, after
/// its reference [MultiFaceRetarget19]): the detector finds the face in the first frame,
/// and every later frame takes its box from the bounding box of the previous frame's
/// landmarks (as upstream OpenSeeFace does, without growth), which avoids the jitter of a
/// fresh detection per frame and skips the detector. The detector runs again when the
/// face is lost: the landmarks' mean confidence falls below a threshold, or their box is
/// degenerate or leaves the frame. Of several detected faces it follows the largest
/// ([`largest_face`]).
///
/// With a fallback detector ([`FaceFollower::with_fallback`]), a frame OpenSeeFace's
/// detector finds no usable face in is searched by RetinaFace (close-ups that fill the
/// frame, small or grey faces); after a search that found nothing it waits
/// [`crate::retinaface::FALLBACK_SEARCH_INTERVAL`] frames before the next, so footage
/// without a face does not pay for it on every frame.
pub struct FaceFollower {
    tracker: OpenSeeFace,
    min_landmark_confidence: f32,
    previous_box: Option<Rect>,
    last_timings: StepTimings,
    fallback: Option<crate::retinaface::RetinaFace>,
    /// Frames before the fallback may search again.
    fallback_wait: usize,
}

impl FaceFollower {
    pub fn new(tracker: OpenSeeFace) -> Self {
        Self {
            tracker,
            min_landmark_confidence: DEFAULT_MIN_LANDMARK_CONFIDENCE,
            previous_box: None,
            last_timings: StepTimings::default(),
            fallback: None,
            fallback_wait: 0,
        }
    }

    /// Searches with `detector` when OpenSeeFace's detector finds no usable face.
    pub fn with_fallback(mut self, detector: crate::retinaface::RetinaFace) -> Self {
        self.fallback = Some(detector);
        self
    }

    /// Whether a fallback detector is set.
    pub fn has_fallback(&self) -> bool {
        self.fallback.is_some()
    }

    /// Sets the mean landmark confidence below which the face counts as lost (default
    /// [`DEFAULT_MIN_LANDMARK_CONFIDENCE`]).
    pub fn with_min_landmark_confidence(mut self, threshold: f32) -> Self {
        self.min_landmark_confidence = threshold;
        self
    }

    pub fn min_landmark_confidence(&self) -> f32 {
        self.min_landmark_confidence
    }

    pub fn tracker(&self) -> &OpenSeeFace {
        &self.tracker
    }

    pub fn tracker_mut(&mut self) -> &mut OpenSeeFace {
        &mut self.tracker
    }

    /// The box the next frame will start from, if a face is being followed.
    pub fn previous_box(&self) -> Option<Rect> {
        self.previous_box
    }

    /// Timings of the last [`step`](Self::step), also when it found no face.
    pub fn last_timings(&self) -> StepTimings {
        self.last_timings
    }

    /// Forgets the face: the next frame starts with a detection (a cut in the video, a new
    /// clip).
    pub fn reset(&mut self) {
        self.previous_box = None;
        self.last_timings = StepTimings::default();
        self.fallback_wait = 0;
    }

    /// The face in the next frame of the video, or `None` if the frame shows none.
    pub fn step(&mut self, image: &RgbImage) -> Result<Option<FollowResult>> {
        let mut timings = StepTimings::default();
        let result = self.follow(image, &mut timings);
        self.last_timings = timings;
        let result = result?;
        self.previous_box = result.as_ref().and_then(|r| {
            r.landmarks
                .bounding_box()
                .filter(|b| is_followable(*b, image.width(), image.height()))
        });
        Ok(result)
    }

    fn follow(
        &mut self,
        image: &RgbImage,
        timings: &mut StepTimings,
    ) -> Result<Option<FollowResult>> {
        let (width, height) = (image.width(), image.height());
        if let Some(face_box) = self
            .previous_box
            .filter(|b| is_followable(*b, width, height))
        {
            let started = Instant::now();
            let landmarks = self.tracker.landmarks(image, face_box)?;
            timings.landmarks_ms += elapsed_ms(started);
            if landmarks.mean_confidence >= self.min_landmark_confidence {
                return Ok(Some(FollowResult {
                    landmarks,
                    face_box,
                    detected: false,
                    detect_ms: timings.detect_ms,
                    landmarks_ms: timings.landmarks_ms,
                }));
            }
        }
        let started = Instant::now();
        let mut detections = self.tracker.detect(image)?;
        timings.detect_ms = elapsed_ms(started);
        detections.retain(|d| landmark_crop(d.face_box, width, height).is_some());
        if let Some(found) = self.landmarks_on(image, &detections, timings)? {
            return Ok(Some(found));
        }
        let Some(fallback) = self.fallback.as_mut() else {
            return Ok(None);
        };
        if self.fallback_wait > 0 {
            self.fallback_wait -= 1;
            return Ok(None);
        }
        let started = Instant::now();
        let mut detections: Vec<FaceDetection> = fallback
            .detect(image)?
            .iter()
            .map(crate::retinaface::RetinaDetection::to_openseeface)
            .collect();
        timings.detect_ms += elapsed_ms(started);
        detections.retain(|d| landmark_crop(d.face_box, width, height).is_some());
        let found = self.landmarks_on(image, &detections, timings)?;
        if found.is_none() {
            self.fallback_wait = crate::retinaface::FALLBACK_SEARCH_INTERVAL;
        }
        Ok(found)
    }

    /// The landmarks of the largest of `detections`, if they are confident enough.
    fn landmarks_on(
        &mut self,
        image: &RgbImage,
        detections: &[FaceDetection],
        timings: &mut StepTimings,
    ) -> Result<Option<FollowResult>> {
        let Some(detection) = largest_face(detections) else {
            return Ok(None);
        };
        let started = Instant::now();
        let landmarks = self.tracker.landmarks(image, detection.face_box)?;
        timings.landmarks_ms += elapsed_ms(started);
        if landmarks.mean_confidence < self.min_landmark_confidence {
            return Ok(None);
        }
        Ok(Some(FollowResult {
            landmarks,
            face_box: detection.face_box,
            detected: true,
            detect_ms: timings.detect_ms,
            landmarks_ms: timings.landmarks_ms,
        }))
    }
}

fn elapsed_ms(started: Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}

/// Whether a landmark box can seed the next frame: finite, not collapsed to a line or a
/// dot, and with its centre inside the frame (a face mostly outside it is lost).
fn is_followable(face_box: Rect, width: u32, height: u32) -> bool {
    let centre = face_box.centre();
    face_box.is_valid()
        && face_box.width >= MIN_CROP_SIDE
        && face_box.height >= MIN_CROP_SIDE
        && (0.0..width as f32).contains(&centre.x)
        && (0.0..height as f32).contains(&centre.y)
        && landmark_crop(face_box, width, height).is_some()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(x: f32, y: f32, side: f32) -> Rect {
        Rect {
            x,
            y,
            width: side,
            height: side,
        }
    }

    #[test]
    fn mapping_to_ibug68_is_one_to_one_and_leaves_inner_corners_out() {
        let mut seen = [false; IBUG_LANDMARK_COUNT];
        for &ibug in &OPENSEEFACE_TO_IBUG68 {
            assert!(!seen[ibug], "iBUG point {ibug} assigned twice");
            seen[ibug] = true;
        }
        let missing: Vec<usize> = (0..IBUG_LANDMARK_COUNT).filter(|&i| !seen[i]).collect();
        assert_eq!(missing, vec![60, 64]);
        assert_eq!(OPENSEEFACE_TO_IBUG68[58], 48);
        assert_eq!(OPENSEEFACE_TO_IBUG68[62], 54);
        assert_eq!(&OPENSEEFACE_TO_IBUG68[59..62], &[61, 62, 63]);
        assert_eq!(&OPENSEEFACE_TO_IBUG68[63..66], &[65, 66, 67]);
    }

    #[test]
    fn landmark_crop_grows_like_upstream_and_clips_to_the_frame() {
        let crop = landmark_crop(square(100.0, 100.0, 80.0), 640, 480);
        assert_eq!(
            crop,
            Some(Rect {
                x: 92.0,
                y: 90.0,
                width: 96.0,
                height: 100.0,
            })
        );
        let clipped = landmark_crop(square(-20.0, -20.0, 80.0), 640, 480);
        assert_eq!(
            clipped,
            Some(Rect {
                x: 0.0,
                y: 0.0,
                width: 68.0,
                height: 70.0
            })
        );
        assert_eq!(landmark_crop(square(700.0, 10.0, 80.0), 640, 480), None);
        assert_eq!(landmark_crop(square(10.0, 10.0, 0.0), 640, 480), None);
    }

    #[test]
    fn intersection_over_union_of_known_boxes() {
        let a = square(0.0, 0.0, 10.0);
        assert!((intersection_over_union(a, a) - 1.0).abs() < 1e-6);
        assert!((intersection_over_union(a, square(5.0, 0.0, 10.0)) - 50.0 / 150.0).abs() < 1e-6);
        assert_eq!(intersection_over_union(a, square(20.0, 0.0, 10.0)), 0.0);
    }

    #[test]
    fn largest_face_wins_over_most_confident() {
        let small = FaceDetection {
            face_box: square(0.0, 0.0, 40.0),
            confidence: 0.95,
        };
        let large = FaceDetection {
            face_box: square(100.0, 0.0, 120.0),
            confidence: 0.7,
        };
        assert_eq!(largest_face(&[small, large]), Some(large));
        assert_eq!(largest_face(&[]), None);
    }

    #[test]
    fn decoding_puts_a_peak_at_its_cell_with_a_neutral_offset() {
        // Offsets of 0.5 have logit 0: the point sits exactly on the cell's grid position.
        let mut output = vec![0.5; LANDMARK_CHANNELS * HEATMAP_CELLS];
        for k in 0..LANDMARK_COUNT {
            output[k * HEATMAP_CELLS..(k + 1) * HEATMAP_CELLS].fill(0.0);
            output[k * HEATMAP_CELLS + 27 * HEATMAP_SIZE] = 0.9; // row 27, column 0
        }
        let crop = Rect {
            x: 10.0,
            y: 20.0,
            width: 448.0,
            height: 224.0,
        };
        let landmarks = decode_landmarks(&output, crop);
        let expected = Vec2::new(10.0 + 0.5 * 2.0, 20.0 + 223.5);
        assert!((landmarks.points_in_frame[5] - expected).length() < 1e-4);
        assert!((landmarks.mean_confidence - 0.9).abs() < 1e-6);
    }

    #[test]
    fn offset_logit_stays_finite_at_the_ends() {
        assert!(offset_logit(0.0).is_finite() && offset_logit(0.0) < 0.0);
        assert!(offset_logit(1.0).is_finite() && offset_logit(1.0) > 0.0);
        assert_eq!(offset_logit(0.5), 0.0);
    }

    #[test]
    fn followable_boxes() {
        assert!(is_followable(square(100.0, 100.0, 80.0), 640, 480));
        assert!(!is_followable(square(600.0, 100.0, 80.0), 640, 480));
        assert!(!is_followable(square(100.0, 100.0, 1.0), 640, 480));
        assert!(!is_followable(
            Rect {
                x: f32::NAN,
                ..square(0.0, 0.0, 10.0)
            },
            640,
            480
        ));
    }
}
