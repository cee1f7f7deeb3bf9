//! Face detection (BlazeFace, short range) and 468 dense landmarks (Face Mesh) with
//! MediaPipe's models, placed as MediaPipe's own face-mesh graph places them (issue 32).
//!
//! OpenSeeFace's 66 points give an eye 6 points and the lips 18, so blinks, squints,
//! brows and lip shapes are barely constrained on real footage; Face Mesh's 468 points
//! cover lids, lips and brows with contours of their own. `shared/models/README.md`
//! describes the two ONNX files (converted from the `.tflite` files of the PyPI wheel
//! `mediapipe==0.10.14`, Apache-2.0). What this module reproduces of MediaPipe's graphs
//! (`face_detection_short_range_common`, `face_detection_front_detection_to_roi`,
//! `face_landmark_landmarks_to_roi`), with the calculators' options written out below:
//!
//! - **Detection.** The whole frame letterboxed (centred, black borders) to 128 x 128 RGB
//!   in [-1, 1]; 896 SSD anchors (strides 8 and 16, fixed size); each anchor regresses a
//!   box (centre offset and size, in input pixels) and six keypoints (right eye, left eye,
//!   nose tip, mouth centre, right and left ear tragion: the subject's right is the image
//!   left); score = sigmoid(clip(logit, +-100)) >= 0.5; weighted non-maximum suppression
//!   at an intersection over union of 0.3 (overlapping detections are averaged, weighted
//!   by score, and keep the best score).
//! - **Crop from a detection.** The detection's box, turned so the eye keypoints are level,
//!   made square on its longer side and scaled by 1.5.
//! - **Face Mesh.** That crop sampled to 192 x 192 RGB in [0, 1] (NHWC); the network returns
//!   468 points (x, y in crop pixels, z relative at x's scale) and a face-presence logit.
//! - **Crop from the previous frame's points** (following a face): the points' bounding
//!   box, turned so points 33 and 263 (the outer eye corners) are level, square on the
//!   longer side, scaled by 1.5. When the presence falls below 0.5 the face is lost and
//!   the detector runs again.
//!
//! Coordinates: every point and box is in frame pixels of the image passed in, continuous,
//! pixel (row i, column j) covering [j, j+1) x [i, i+1), as in [`crate::preprocess`].
//! MediaPipe's own coordinates put pixel centres at integers: its points are ours minus
//! half a pixel.

use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use image::RgbImage;

use crate::backend::{BackendKind, InferenceBackend, Tensor, load_model};
use crate::error::{Result, TrackingError};
use crate::openseeface::{check_output, display_name, intersection_over_union};
use crate::preprocess::Rect;

/// The detector's file in the models folder (both engines run it as it is).
pub const DETECTOR_FILE: &str = "face_detection_short_range.onnx";
/// Face Mesh's file in the models folder.
pub const MESH_FILE: &str = "face_landmark.onnx";
/// Side of the detector's square input, in pixels.
pub const DETECTOR_INPUT: usize = 128;
/// Side of Face Mesh's square input, in pixels.
pub const MESH_INPUT: usize = 192;
/// Face Mesh's points per face.
pub const MESH_POINTS: usize = 468;
/// The detector's anchors (16 x 16 cells x 2 at stride 8, 8 x 8 cells x 6 at stride 16).
pub const ANCHOR_COUNT: usize = 896;
/// Values the detector regresses per anchor: box (4) and six keypoints (x, y).
const REGRESSOR_VALUES: usize = 16;
/// Keypoints per detection (right eye, left eye, nose tip, mouth, right ear, left ear).
pub const DETECTION_KEYPOINTS: usize = 6;
/// MediaPipe's `min_score_thresh` for the short-range detector.
pub const DEFAULT_MIN_DETECTION_SCORE: f32 = 0.5;
/// MediaPipe's `min_suppression_threshold` (intersection over union).
pub const DEFAULT_SUPPRESSION_OVERLAP: f32 = 0.3;
/// MediaPipe's `min_tracking_confidence` default: below this presence the face is lost.
pub const DEFAULT_MIN_PRESENCE: f32 = 0.5;
/// `score_clipping_thresh` of the detector's logits.
const SCORE_CLIP: f32 = 100.0;
/// The crop around a detection's box or the previous points' box, relative to its longer
/// side (`RectTransformationCalculator` scale 1.5 with `square_long`).
pub const CROP_SCALE: f32 = 1.5;
/// Face Mesh points at the outer corners of the right eye (image left on a frontal face)
/// and the left eye: the line that is made level when following a face.
pub const RIGHT_EYE_OUTER: usize = 33;
pub const LEFT_EYE_OUTER: usize = 263;

/// Where the files come from, for error messages.
const UPSTREAM: &str = "the PyPI wheel mediapipe==0.10.14 (mediapipe/modules/face_detection/\
face_detection_short_range.tflite and mediapipe/modules/face_landmark/face_landmark.tflite), \
converted to ONNX with tf2onnx as shared/models/README.md describes";

/// The model directory used when none is given: `$LIKENESS_MODELS/mediapipe` when
/// `LIKENESS_MODELS` is set, else `shared/models/mediapipe` beside the repository.
pub fn default_models_dir() -> PathBuf {
    match std::env::var_os("LIKENESS_MODELS").filter(|v| !v.is_empty()) {
        Some(root) => PathBuf::from(root).join("mediapipe"),
        None => {
            Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).join("../shared/models/mediapipe")
        }
    }
}

fn missing_model_hint(dir: &Path) -> String {
    let place = if dir.is_dir() {
        format!("the directory {} lacks it", dir.display())
    } else {
        format!("the directory {} does not exist", dir.display())
    };
    format!(
        "{place}. {DETECTOR_FILE} and {MESH_FILE} are MediaPipe's models from {UPSTREAM}. Point \
         Likeness at the folder holding them with `--models DIR` (its subfolder `mediapipe`), \
         or set LIKENESS_MODELS to a directory that holds them in a subfolder `mediapipe`"
    )
}

/// A file that exists but does not load or run as the expected network.
fn damaged_model(path: &Path, error: TrackingError) -> TrackingError {
    match error {
        TrackingError::Inference { .. } | TrackingError::BadOutput { .. } => {
            TrackingError::Decode {
                path: path.to_owned(),
                reason: format!(
                    "{error} (the file is damaged or not this model; fetch it again from {UPSTREAM})"
                ),
            }
        }
        other => other,
    }
}

/// A square region of a frame turned by `angle`: its x axis runs along (cos, sin) of the
/// angle in frame pixels (y down), so a positive angle turns it clockwise on screen.
/// MediaPipe's normalised rotated rectangle, in pixels and square.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RotatedSquare {
    pub centre: Vec2,
    pub side: f32,
    /// Radians.
    pub angle: f32,
}

impl RotatedSquare {
    /// The frame point at (u, v) of the square, both in [0, 1] from its top-left corner.
    pub fn to_frame(&self, uv: Vec2) -> Vec2 {
        let (sin, cos) = self.angle.sin_cos();
        let d = (uv - Vec2::splat(0.5)) * self.side;
        self.centre + Vec2::new(cos * d.x - sin * d.y, sin * d.x + cos * d.y)
    }

    /// The inverse of [`RotatedSquare::to_frame`].
    pub fn to_square(&self, p: Vec2) -> Vec2 {
        let (sin, cos) = self.angle.sin_cos();
        let d = p - self.centre;
        Vec2::new(cos * d.x + sin * d.y, -sin * d.x + cos * d.y) / self.side + Vec2::splat(0.5)
    }

    pub fn is_valid(&self) -> bool {
        self.centre.is_finite()
            && self.side.is_finite()
            && self.side > 0.0
            && self.angle.is_finite()
    }

    /// MediaPipe's crop around `bounds` (frame pixels): square on the longer side, scaled
    /// by [`CROP_SCALE`], turned so that the line from `from` to `to` is level.
    pub fn around(bounds: Rect, from: Vec2, to: Vec2) -> Self {
        let d = to - from;
        Self {
            centre: bounds.centre(),
            side: bounds.width.max(bounds.height) * CROP_SCALE,
            angle: d.y.atan2(d.x),
        }
    }
}

/// What the sampler reads outside the frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Border {
    /// Black (MediaPipe's `BORDER_ZERO`, the detector's letterbox).
    Black,
    /// The nearest edge pixel (MediaPipe's default `BORDER_REPLICATE`, Face Mesh's crop).
    Replicate,
}

/// The square `square` of `image` sampled to `out` x `out` RGB values, NHWC, each
/// `v / 255 * scale + offset`, as MediaPipe's CPU `ImageToTensorCalculator` samples it:
/// OpenCV's bilinear warp, which puts pixel centres at integer coordinates and maps output
/// pixel (r, c) to the square's point (c / out, r / out), with no prefilter when it
/// shrinks. Matching it is what makes our points MediaPipe's: on the real crop framed in
/// a 640 x 480 frame, sampling pixel centres with a box prefilter (as
/// [`crate::preprocess`] does) moved the points 2.0 px (median) from MediaPipe's own, this
/// sampling 0.02 px (tests/mediapipe.rs). In this module's continuous coordinates
/// (centres at +0.5) that point is `square.to_frame(..) - 0.5` in OpenCV's.
///
/// Written here rather than with `image::imageops`: the crop is turned and reaches outside
/// the frame, which no resizing crate samples.
pub fn sample_square_nhwc(
    image: &RgbImage,
    square: RotatedSquare,
    out: usize,
    scale: f32,
    offset: f32,
    border: Border,
) -> Result<Tensor> {
    let (iw, ih) = (image.width() as isize, image.height() as isize);
    if iw == 0 || ih == 0 {
        return Err(TrackingError::InvalidInput("the image is empty".into()));
    }
    if !square.is_valid() || out == 0 {
        return Err(TrackingError::InvalidInput(format!(
            "crop {square:?} is empty or not finite"
        )));
    }
    let raw = image.as_raw();
    let texel = |x: isize, y: isize| -> [f32; 3] {
        let (x, y) = match border {
            Border::Replicate => (x.clamp(0, iw - 1), y.clamp(0, ih - 1)),
            Border::Black if x < 0 || y < 0 || x >= iw || y >= ih => return [0.0; 3],
            Border::Black => (x, y),
        };
        let i = (y * iw + x) as usize * 3;
        [
            f32::from(raw[i]),
            f32::from(raw[i + 1]),
            f32::from(raw[i + 2]),
        ]
    };
    let mut data = vec![0.0f32; out * out * 3];
    let to_unit = scale / 255.0;
    for r in 0..out {
        for c in 0..out {
            let uv = Vec2::new(c as f32, r as f32) / out as f32;
            let p = square.to_frame(uv) - Vec2::splat(0.5);
            let (x0, y0) = (p.x.floor(), p.y.floor());
            let (fx, fy) = (p.x - x0, p.y - y0);
            let (x0, y0) = (x0 as isize, y0 as isize);
            let (t00, t10) = (texel(x0, y0), texel(x0 + 1, y0));
            let (t01, t11) = (texel(x0, y0 + 1), texel(x0 + 1, y0 + 1));
            let o = (r * out + c) * 3;
            for ch in 0..3 {
                let top = t00[ch] + (t10[ch] - t00[ch]) * fx;
                let bottom = t01[ch] + (t11[ch] - t01[ch]) * fx;
                data[o + ch] = (top + (bottom - top) * fy) * to_unit + offset;
            }
        }
    }
    Tensor::new(vec![1, out, out, 3], data)
}

/// The centres of the detector's anchors in [0, 1] of its input, in the order of its
/// outputs. MediaPipe's `SsdAnchorsCalculator` with the short-range options (4 layers,
/// strides 8, 16, 16, 16, aspect ratio 1 plus the interpolated scale, `fixed_anchor_size`):
/// layers of equal stride share one grid, so stride 8 gives 2 anchors per cell of 16 x 16
/// and stride 16 gives 6 per cell of 8 x 8; with a fixed size only the centres matter.
pub fn detector_anchors() -> Vec<Vec2> {
    let mut anchors = Vec::with_capacity(ANCHOR_COUNT);
    for (stride, per_cell) in [(8usize, 2usize), (16, 6)] {
        let grid = DETECTOR_INPUT.div_ceil(stride);
        for y in 0..grid {
            for x in 0..grid {
                let centre = Vec2::new(
                    (x as f32 + 0.5) / grid as f32,
                    (y as f32 + 0.5) / grid as f32,
                );
                anchors.extend(std::iter::repeat_n(centre, per_cell));
            }
        }
    }
    anchors
}

/// A face the detector found.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeshDetection {
    /// Frame pixels.
    pub face_box: Rect,
    /// Right eye, left eye, nose tip, mouth centre, right ear, left ear; frame pixels.
    pub keypoints: [Vec2; DETECTION_KEYPOINTS],
    /// 0..1.
    pub score: f32,
}

impl MeshDetection {
    /// Where Face Mesh looks for this face (MediaPipe's `face_detection_front_detection_to_roi`).
    pub fn crop(&self) -> RotatedSquare {
        RotatedSquare::around(self.face_box, self.keypoints[0], self.keypoints[1])
    }
}

fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// The detections in the detector's raw outputs (`regressors`, 896 x 16, and `logits`, 896)
/// scoring at least `min_score`, in [0, 1] of its input, before suppression; MediaPipe's
/// `TensorsToDetectionsCalculator` (x first, every value in input pixels relative to its
/// anchor's centre).
pub fn decode_detections(
    regressors: &[f32],
    logits: &[f32],
    anchors: &[Vec2],
    min_score: f32,
) -> Vec<MeshDetection> {
    let scale = DETECTOR_INPUT as f32;
    let mut found = Vec::new();
    for (i, anchor) in anchors.iter().enumerate() {
        let (Some(raw), Some(&logit)) = (
            regressors.get(i * REGRESSOR_VALUES..(i + 1) * REGRESSOR_VALUES),
            logits.get(i),
        ) else {
            break;
        };
        let score = sigmoid(logit.clamp(-SCORE_CLIP, SCORE_CLIP));
        if score.is_nan() || score < min_score {
            continue;
        }
        let centre = *anchor + Vec2::new(raw[0], raw[1]) / scale;
        let size = Vec2::new(raw[2], raw[3]) / scale;
        let keypoints =
            std::array::from_fn(|k| *anchor + Vec2::new(raw[4 + 2 * k], raw[5 + 2 * k]) / scale);
        let face_box = Rect {
            x: centre.x - 0.5 * size.x,
            y: centre.y - 0.5 * size.y,
            width: size.x,
            height: size.y,
        };
        if face_box.is_valid() && keypoints.iter().all(|k: &Vec2| k.is_finite()) {
            found.push(MeshDetection {
                face_box,
                keypoints,
                score,
            });
        }
    }
    found
}

/// MediaPipe's weighted non-maximum suppression: the best remaining detection takes every
/// remaining one overlapping it by more than `overlap` (intersection over union) and
/// becomes their score-weighted average (box corners and keypoints), keeping its own
/// score. Best first.
pub fn weighted_suppression(
    mut detections: Vec<MeshDetection>,
    overlap: f32,
) -> Vec<MeshDetection> {
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept = Vec::new();
    while let Some(best) = detections.first().copied() {
        let (cluster, rest): (Vec<_>, Vec<_>) = detections
            .into_iter()
            .partition(|d| intersection_over_union(best.face_box, d.face_box) > overlap);
        detections = rest;
        // `best` overlaps itself fully, so a cluster is never empty; a box of zero area
        // (IoU 0 with itself) is its own cluster.
        let cluster = if cluster.is_empty() {
            vec![best]
        } else {
            cluster
        };
        let total: f32 = cluster.iter().map(|d| d.score).sum();
        let mut lo = Vec2::ZERO;
        let mut hi = Vec2::ZERO;
        let mut keypoints = [Vec2::ZERO; DETECTION_KEYPOINTS];
        for d in &cluster {
            let w = d.score / total;
            lo += w * Vec2::new(d.face_box.x, d.face_box.y);
            hi += w * Vec2::new(
                d.face_box.x + d.face_box.width,
                d.face_box.y + d.face_box.height,
            );
            for (k, p) in keypoints.iter_mut().zip(d.keypoints) {
                *k += w * p;
            }
        }
        kept.push(MeshDetection {
            face_box: Rect {
                x: lo.x,
                y: lo.y,
                width: hi.x - lo.x,
                height: hi.y - lo.y,
            },
            keypoints,
            score: best.score,
        });
    }
    kept
}

/// Face Mesh's output for one face.
#[derive(Clone, Debug, PartialEq)]
pub struct FaceMesh {
    /// 468 points, x and y in frame pixels, z at the same scale (relative depth, larger is
    /// farther from the camera, as MediaPipe's).
    pub points: Vec<Vec3>,
    /// The face-presence probability, 0..1.
    pub presence: f32,
    /// The crop the points were found in.
    pub crop: RotatedSquare,
}

impl FaceMesh {
    /// The points' image positions.
    pub fn points_2d(&self) -> impl Iterator<Item = Vec2> + '_ {
        self.points.iter().map(|p| p.truncate())
    }

    /// Where to look for this face in the next frame (MediaPipe's
    /// `face_landmark_landmarks_to_roi`); `None` when the points do not span a box.
    pub fn next_crop(&self) -> Option<RotatedSquare> {
        let bounds = Rect::bounding(self.points_2d())?;
        let crop = RotatedSquare::around(
            bounds,
            self.points[RIGHT_EYE_OUTER].truncate(),
            self.points[LEFT_EYE_OUTER].truncate(),
        );
        crop.is_valid().then_some(crop)
    }
}

/// BlazeFace and Face Mesh on one backend.
pub struct MediaPipe {
    detector: Box<dyn InferenceBackend>,
    mesh: Box<dyn InferenceBackend>,
    detector_name: String,
    mesh_name: String,
    kind: BackendKind,
    anchors: Vec<Vec2>,
    min_detection_score: f32,
    suppression_overlap: f32,
}

impl MediaPipe {
    /// Loads both networks from `dir` and runs each once on a blank input, so that a file
    /// which parses but cannot run (or answers in other shapes) fails here, not on the
    /// first frame.
    pub fn load(dir: &Path, kind: BackendKind, threads: usize) -> Result<Self> {
        let (detector_path, mesh_path) = (dir.join(DETECTOR_FILE), dir.join(MESH_FILE));
        for path in [&detector_path, &mesh_path] {
            if !path.is_file() {
                return Err(TrackingError::MissingModel {
                    path: path.clone(),
                    hint: missing_model_hint(dir),
                });
            }
        }
        let detector = load_model(&detector_path, kind, threads)
            .map_err(|e| damaged_model(&detector_path, e))?;
        let mesh =
            load_model(&mesh_path, kind, threads).map_err(|e| damaged_model(&mesh_path, e))?;
        Self::from_backends((detector, &detector_path), (mesh, &mesh_path))
    }

    /// Both networks already loaded (the browser reads them from fetched bytes), each with
    /// the path its messages name; checked as in [`MediaPipe::load`].
    pub fn from_backends(
        detector: (Box<dyn InferenceBackend>, &Path),
        mesh: (Box<dyn InferenceBackend>, &Path),
    ) -> Result<Self> {
        let (detector, detector_path) = detector;
        let (mesh, mesh_path) = mesh;
        let kind = detector.kind();
        let mut located = Self {
            detector,
            mesh,
            detector_name: display_name(detector_path),
            mesh_name: display_name(mesh_path),
            kind,
            anchors: detector_anchors(),
            min_detection_score: DEFAULT_MIN_DETECTION_SCORE,
            suppression_overlap: DEFAULT_SUPPRESSION_OVERLAP,
        };
        located
            .run_detector(&Tensor::zeros(vec![1, DETECTOR_INPUT, DETECTOR_INPUT, 3]))
            .map_err(|e| damaged_model(detector_path, e))?;
        located
            .run_mesh(&Tensor::zeros(vec![1, MESH_INPUT, MESH_INPUT, 3]))
            .map_err(|e| damaged_model(mesh_path, e))?;
        Ok(located)
    }

    pub fn kind(&self) -> BackendKind {
        self.kind
    }

    pub fn min_detection_score(&self) -> f32 {
        self.min_detection_score
    }

    /// The score a detection needs (default [`DEFAULT_MIN_DETECTION_SCORE`]).
    pub fn set_min_detection_score(&mut self, score: f32) {
        self.min_detection_score = score;
    }

    /// The faces in `image`, best first. The frame is letterboxed to the detector's square
    /// input (centred, black borders), so boxes keep the frame's proportions.
    pub fn detect(&mut self, image: &RgbImage) -> Result<Vec<MeshDetection>> {
        let (w, h) = (image.width() as f32, image.height() as f32);
        // MediaPipe centres its letterbox at (w/2, h/2) of its coordinates, where pixel
        // centres are integers: half a pixel right of and below the frame's centre in ours.
        let letterbox = RotatedSquare {
            centre: Vec2::new(0.5 * w + 0.5, 0.5 * h + 0.5),
            side: w.max(h),
            angle: 0.0,
        };
        let found = self.detect_in_square(image, letterbox)?;
        Ok(weighted_suppression(found, self.suppression_overlap))
    }

    /// The faces in the axis-aligned square `region` of `image` (frame pixels; the frame's
    /// outside reads black), best first: where the previous frame's face was, or one tile
    /// of [`MediaPipe::detect_tiled`].
    pub fn detect_in(&mut self, image: &RgbImage, region: Rect) -> Result<Vec<MeshDetection>> {
        let square = RotatedSquare {
            centre: region.centre(),
            side: region.width.max(region.height),
            angle: 0.0,
        };
        let found = self.detect_in_square(image, square)?;
        Ok(weighted_suppression(found, self.suppression_overlap))
    }

    /// Faces too small for the whole-frame pass: BlazeFace's short-range model sees the
    /// frame at 128 px, where a face a tenth of the frame's height is ~10 px and is missed.
    /// This runs it on square tiles of a third of the frame's shorter side, overlapping by
    /// half, and merges what they find (weighted suppression across tiles). Measured on the
    /// real crop pasted into a 1280 x 720 frame: the whole frame finds it down to 224 px
    /// (0.31 of the height), these tiles down to 48 px (1/15) at scores 0.82-0.93. It costs
    /// one detector run per tile (45 for 1280 x 720), so it is for the first frame and for
    /// a face that was lost, not for every frame.
    pub fn detect_tiled(&mut self, image: &RgbImage) -> Result<Vec<MeshDetection>> {
        let (w, h) = (image.width() as f32, image.height() as f32);
        let tile = (w.min(h) / 3.0).max(DETECTOR_INPUT as f32);
        let step = 0.5 * tile;
        let positions = |extent: f32| -> Vec<f32> {
            let n = ((extent - tile) / step).ceil().max(0.0) as usize;
            (0..=n)
                .map(|i| (i as f32 * step).min((extent - tile).max(0.0)))
                .collect()
        };
        let mut found = Vec::new();
        for y in positions(h) {
            for x in positions(w) {
                let region = RotatedSquare {
                    centre: Vec2::new(x + 0.5 * tile, y + 0.5 * tile),
                    side: tile,
                    angle: 0.0,
                };
                found.extend(self.detect_in_square(image, region)?);
            }
        }
        Ok(weighted_suppression(found, self.suppression_overlap))
    }

    /// The detector on `square` (axis-aligned), its detections in frame pixels, before
    /// suppression.
    fn detect_in_square(
        &mut self,
        image: &RgbImage,
        square: RotatedSquare,
    ) -> Result<Vec<MeshDetection>> {
        let input = sample_square_nhwc(image, square, DETECTOR_INPUT, 2.0, -1.0, Border::Black)?;
        let (regressors, logits) = self.run_detector(&input)?;
        let found = decode_detections(
            &regressors,
            &logits,
            &self.anchors,
            self.min_detection_score,
        );
        let to_frame = |p: Vec2| square.to_frame(p);
        Ok(found
            .into_iter()
            .map(|d| {
                let lo = to_frame(Vec2::new(d.face_box.x, d.face_box.y));
                let hi = to_frame(Vec2::new(
                    d.face_box.x + d.face_box.width,
                    d.face_box.y + d.face_box.height,
                ));
                MeshDetection {
                    face_box: Rect {
                        x: lo.x,
                        y: lo.y,
                        width: hi.x - lo.x,
                        height: hi.y - lo.y,
                    },
                    keypoints: d.keypoints.map(to_frame),
                    score: d.score,
                }
            })
            .collect())
    }

    /// Face Mesh on the square `crop` of `image` (a detection's [`MeshDetection::crop`] or
    /// the previous frame's [`FaceMesh::next_crop`]).
    pub fn mesh(&mut self, image: &RgbImage, crop: RotatedSquare) -> Result<FaceMesh> {
        let input = sample_square_nhwc(image, crop, MESH_INPUT, 1.0, 0.0, Border::Replicate)?;
        let (raw, logit) = self.run_mesh(&input)?;
        let size = MESH_INPUT as f32;
        let points = raw
            .chunks_exact(3)
            .map(|p| {
                let xy = crop.to_frame(Vec2::new(p[0], p[1]) / size);
                xy.extend(p[2] / size * crop.side)
            })
            .collect();
        Ok(FaceMesh {
            points,
            presence: sigmoid(logit),
            crop,
        })
    }

    /// The detector's `regressors` (896 x 16) and `classificators` (896), checked.
    fn run_detector(&mut self, input: &Tensor) -> Result<(Vec<f32>, Vec<f32>)> {
        let mut outputs = self.detector.run(input)?.into_iter();
        let (Some(regressors), Some(logits)) = (outputs.next(), outputs.next()) else {
            return Err(TrackingError::BadOutput {
                model: self.detector_name.clone(),
                reason: "count: expected `regressors` and `classificators`".into(),
            });
        };
        check_output(
            &regressors,
            &[1, ANCHOR_COUNT, REGRESSOR_VALUES],
            &self.detector_name,
            "regressors",
        )?;
        check_output(
            &logits,
            &[1, ANCHOR_COUNT, 1],
            &self.detector_name,
            "classificators",
        )?;
        Ok((regressors.data, logits.data))
    }

    /// Face Mesh's 468 x 3 values and its presence logit, checked.
    fn run_mesh(&mut self, input: &Tensor) -> Result<(Vec<f32>, f32)> {
        let mut outputs = self.mesh.run(input)?.into_iter();
        let (Some(points), Some(presence)) = (outputs.next(), outputs.next()) else {
            return Err(TrackingError::BadOutput {
                model: self.mesh_name.clone(),
                reason: "count: expected `conv2d_21` and `conv2d_31`".into(),
            });
        };
        check_output(
            &points,
            &[1, 1, 1, MESH_POINTS * 3],
            &self.mesh_name,
            "conv2d_21",
        )?;
        check_output(&presence, &[1, 1, 1, 1], &self.mesh_name, "conv2d_31")?;
        Ok((points.data, presence.data[0]))
    }
}

/// The Face Mesh point standing for each iBUG 68 landmark (jaw 0-16, brows 17-26, nose
/// 27-35, eyes 36-47, lips 48-67; the subject's right first, as iBUG's). The subset widely
/// used with MediaPipe's canonical face mesh: jaw points on the mesh's silhouette ring,
/// eye and lip corners and contour points where iBUG has them.
pub const MESH_TO_IBUG68: [usize; crate::openseeface::IBUG_LANDMARK_COUNT] = [
    // jaw, from the right temple to the left
    162, 234, 93, 58, 172, 136, 149, 148, 152, 377, 378, 365, 397, 288, 323, 454, 389,
    // right brow, left brow
    71, 63, 105, 66, 107, 336, 296, 334, 293, 301, // nose bridge, nose bottom
    168, 197, 5, 4, 75, 97, 2, 326, 305,
    // right eye, left eye (outer corner first, clockwise on the image)
    33, 160, 158, 133, 153, 144, 362, 385, 387, 263, 373, 380,
    // outer lip (corners 48 and 54), inner lip (corners 60 and 64)
    61, 39, 37, 0, 267, 269, 291, 405, 314, 17, 84, 181, 78, 82, 13, 312, 308, 317, 14, 87,
];

/// Which Face Mesh points stand for each iBUG 68 landmark: three (index, weight) pairs
/// whose weighted sum, the weights summing to 1, is the landmark.
pub type Ibug68Points = [[(usize, f32); 3]; crate::openseeface::IBUG_LANDMARK_COUNT];

/// One Face Mesh point per landmark (as [`MESH_TO_IBUG68`] lists them).
pub fn single_points(points: &[usize; crate::openseeface::IBUG_LANDMARK_COUNT]) -> Ibug68Points {
    points.map(|i| [(i, 1.0), (i, 0.0), (i, 0.0)])
}

/// Length of [`ibug68_points_to_f32s`]: (index, weight) of three points per landmark.
pub const IBUG68_POINTS_F32S: usize = crate::openseeface::IBUG_LANDMARK_COUNT * 3 * 2;

/// [`Ibug68Points`] as numbers, for a Web Worker's message (the worker has no template to
/// work them out from): per landmark, three (index, weight) pairs. An index is exact in an
/// f32 (it is below 2^24).
pub fn ibug68_points_to_f32s(points: &Ibug68Points) -> Vec<f32> {
    points
        .iter()
        .flatten()
        .flat_map(|&(i, w)| [i as f32, w])
        .collect()
}

/// The inverse of [`ibug68_points_to_f32s`]; an error for numbers that are not such points
/// (wrong length, an index that is not a Face Mesh point, a weight that is not finite).
pub fn ibug68_points_from_f32s(numbers: &[f32]) -> Result<Ibug68Points> {
    if numbers.len() != IBUG68_POINTS_F32S {
        return Err(TrackingError::InvalidInput(format!(
            "the landmark points are {IBUG68_POINTS_F32S} numbers, not {}",
            numbers.len()
        )));
    }
    let mut out = [[(0usize, 0.0f32); 3]; crate::openseeface::IBUG_LANDMARK_COUNT];
    for (k, pair) in numbers.chunks_exact(2).enumerate() {
        let (index, weight) = (pair[0], pair[1]);
        if !(index >= 0.0 && index < MESH_POINTS as f32 && index.fract() == 0.0) {
            return Err(TrackingError::InvalidInput(format!(
                "landmark {} names Face Mesh point {index}, there are {MESH_POINTS}",
                k / 3
            )));
        }
        if !weight.is_finite() {
            return Err(TrackingError::InvalidInput(format!(
                "landmark {} has the weight {weight}",
                k / 3
            )));
        }
        out[k / 3][k % 3] = (index as usize, weight);
    }
    Ok(out)
}

impl FaceMesh {
    /// The iBUG 68 landmarks as `points` picks them ([`MESH_TO_IBUG68`] or
    /// [`IctCorrespondence::ibug68_points`]), each with the face's presence as its
    /// confidence (Face Mesh scores the face, not its points).
    pub fn to_ibug68(
        &self,
        points: &Ibug68Points,
    ) -> [Option<(Vec2, f32)>; crate::openseeface::IBUG_LANDMARK_COUNT] {
        points.map(|weighted| {
            let mut sum = Vec2::ZERO;
            for &(i, w) in &weighted {
                sum += self.points.get(i)?.truncate() * w;
            }
            Some((sum, self.presence))
        })
    }
}

/// Face Mesh's face oval, in order around the face: the points on the silhouette, which
/// slide over the surface as the head turns (a contour chain for refinement).
pub const FACE_OVAL: [usize; 36] = [
    10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377, 152,
    148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109,
];

/// Face Mesh's eyelid, lip and brow lines, each an open chain in order along the line, the
/// corners left out (they are fixed features): upper and lower lid of each eye, upper and
/// lower outer and inner lip, upper and lower edge of each brow. A point on such a line is
/// placed well across it and poorly along it, and where it lands along the line depends on
/// the detector more than on the mesh vertex the correspondence gives it; refinement keeps
/// the across-line part of its residual and little of the along-line part, as for the oval.
pub const FEATURE_LINES: [&[usize]; 12] = [
    // right eye (the subject's): upper lid, lower lid
    &[246, 161, 160, 159, 158, 157, 173],
    &[7, 163, 144, 145, 153, 154, 155],
    // left eye: upper lid, lower lid
    &[466, 388, 387, 386, 385, 384, 398],
    &[249, 390, 373, 374, 380, 381, 382],
    // outer lip: upper, lower
    &[185, 40, 39, 37, 0, 267, 269, 270, 409],
    &[146, 91, 181, 84, 17, 314, 405, 321, 375],
    // inner lip: upper, lower
    &[191, 80, 81, 82, 13, 312, 311, 310, 415],
    &[95, 88, 178, 87, 14, 317, 402, 318, 324],
    // right brow: upper, lower edge; left brow: upper, lower edge
    &[70, 63, 105, 66, 107],
    &[46, 53, 52, 65, 55],
    &[300, 293, 334, 296, 336],
    &[276, 283, 282, 295, 285],
];

/// The file beside the models that says which ICT vertex lies under each Face Mesh point.
pub const CORRESPONDENCE_FILE: &str = "ict_correspondence.json";

/// The ICT FaceKit vertex under each of Face Mesh's 468 points (`ict_correspondence.json`,
/// `mediapipe_to_ict_vertex`; shared/models/README.md says how it was fitted).
#[derive(Clone, Debug, PartialEq)]
pub struct IctCorrespondence {
    pub vertices: Vec<u32>,
}

impl IctCorrespondence {
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join(CORRESPONDENCE_FILE);
        let bytes = std::fs::read(&path).map_err(|source| match source.kind() {
            std::io::ErrorKind::NotFound => TrackingError::MissingModel {
                path: path.clone(),
                hint: missing_model_hint(dir),
            },
            _ => TrackingError::Io {
                path: path.clone(),
                source,
            },
        })?;
        Self::from_json(&bytes, &path)
    }

    /// Parses the file's bytes; `path` names it in errors.
    pub fn from_json(bytes: &[u8], path: &Path) -> Result<Self> {
        #[derive(serde::Deserialize)]
        struct File {
            mediapipe_to_ict_vertex: Vec<u32>,
        }
        let bad = |reason: String| TrackingError::Decode {
            path: path.to_owned(),
            reason,
        };
        let file: File = serde_json::from_slice(bytes)
            .map_err(|e| bad(format!("not the correspondence file ({e})")))?;
        if file.mediapipe_to_ict_vertex.len() != MESH_POINTS {
            return Err(bad(format!(
                "`mediapipe_to_ict_vertex` has {} entries, Face Mesh has {MESH_POINTS} points",
                file.mediapipe_to_ict_vertex.len()
            )));
        }
        Ok(Self {
            vertices: file.mediapipe_to_ict_vertex,
        })
    }

    /// All 468 points for refinement: their ICT vertices, the face oval and the
    /// [`FEATURE_LINES`] as contour chains.
    pub fn fit_points(&self) -> crate::refine::FitPoints {
        crate::refine::FitPoints {
            vertices: self.vertices.clone(),
            contours: std::iter::once(&FACE_OVAL[..])
                .chain(FEATURE_LINES)
                .map(<[usize]>::to_vec)
                .collect(),
        }
    }

    /// For each of the template's 68 landmark vertices, the three Face Mesh points whose
    /// ICT vertices lie nearest to it on the neutral face, weighted so that their affine
    /// combination is the landmark vertex's projection onto their plane (the nearest alone
    /// where that would extrapolate far): the points that stand where the model's
    /// own landmarks are, so refinement compares like with like. The single nearest point
    /// lies 5-9 mm from the brow and jaw landmarks; on the held-out clips the weighted
    /// three bring the 68 points' NME from 3.76 to 3.59 % (the widely used subset
    /// [`MESH_TO_IBUG68`], which puts the jaw on the silhouette: 4.13 %). An error when a
    /// vertex index is outside the template.
    pub fn ibug68_points(&self, template: &face::Template) -> Result<Ibug68Points> {
        let position = |v: u32| {
            template.neutral.get(v as usize).copied().ok_or_else(|| {
                TrackingError::InvalidInput(format!(
                    "the correspondence names ICT vertex {v}, the template has {} vertices",
                    template.neutral.len()
                ))
            })
        };
        let mesh_positions = self
            .vertices
            .iter()
            .map(|&v| position(v))
            .collect::<Result<Vec<_>>>()?;
        let mut out = [[(0usize, 0.0f32); 3]; crate::openseeface::IBUG_LANDMARK_COUNT];
        for (slot, &landmark) in out.iter_mut().zip(&template.landmarks_68) {
            let target = position(landmark)?;
            let mut near: Vec<(usize, f32)> = mesh_positions
                .iter()
                .enumerate()
                .map(|(i, q)| (i, q.distance(target)))
                .collect();
            near.sort_by(|a, b| a.1.total_cmp(&b.1));
            let [(i0, _), (i1, _), (i2, _)] = [near[0], near[1], near[2]];
            let q = [mesh_positions[i0], mesh_positions[i1], mesh_positions[i2]];
            // Least squares for w1, w2 in q2 + w1 (q0 - q2) + w2 (q1 - q2) = target.
            let (a, b, d) = (q[0] - q[2], q[1] - q[2], target - q[2]);
            let (aa, ab, bb) = (a.dot(a), a.dot(b), b.dot(b));
            let det = aa * bb - ab * ab;
            let affine = (det.abs() > 1e-9 * aa.max(bb).powi(2)).then(|| {
                let w0 = (a.dot(d) * bb - b.dot(d) * ab) / det;
                let w1 = (b.dot(d) * aa - a.dot(d) * ab) / det;
                [w0, w1, 1.0 - w0 - w1]
            });
            // Where the landmark lies far outside the three (an affine weight below -0.25),
            // the nearest point alone.
            let weights = match affine {
                Some(w) if w.iter().all(|&x| x >= -0.25) => w,
                _ => [1.0, 0.0, 0.0],
            };
            *slot = [(i0, weights[0]), (i1, weights[1]), (i2, weights[2])];
        }
        Ok(out)
    }
}

/// One frame's result of [`MeshFollower::step`].
#[derive(Clone, Debug)]
pub struct MeshFollowResult {
    pub mesh: FaceMesh,
    /// Whether the detector ran (first frame, or the face had been lost).
    pub detected: bool,
    pub detect_ms: f64,
    pub mesh_ms: f64,
}

/// Follows one face through a video: BlazeFace on every frame, Face Mesh on the crop of
/// the largest detection. A face the whole-frame pass misses (too small) is looked for
/// around where it was (a square of twice the previous crop, one more run) or, with none
/// to follow, on tiles ([`MediaPipe::detect_tiled`], at most every
/// [`TILED_SEARCH_INTERVAL`] frames while nothing is found). When no detector pass finds
/// it (a head turned past what BlazeFace knows), Face Mesh runs on the crop the previous
/// frame's points give ([`FaceMesh::next_crop`]),
/// for as long as its presence stays at or above the threshold (default
/// [`DEFAULT_MIN_PRESENCE`]) and the crop's centre inside the frame. Of several detected
/// faces it follows the largest, as [`crate::openseeface::largest_face`] argues.
///
/// MediaPipe's video graph runs the detector only when the face is lost and otherwise
/// follows the previous points. On the held-out synthetic clips that lagged a fast head
/// turn by several frames while the presence stayed above 0.9 (clip 1, frames 26-31: the
/// points slid onto the forehead, NME up to 60 %); detecting on every frame, the 68 points'
/// NME over the clips is 3.76 % against 3.89 % (3.97 % for OpenSeeFace's) and the refined
/// landmark NME 2.71 % against 2.94 % (tracking/README.md), for one BlazeFace run a frame.
///
/// Unlike MediaPipe's graph, points found on a detection while a face is being followed
/// are kept whatever their presence: the detector has already said there is a face (a
/// score of at least 0.5), and on those clips Face Mesh's presence fell to 0.001-0.03 on seven frames of a
/// strong funnel and squint (clip 1, frames 9-15) whose detections scored 0.85: dropping
/// them found 94 % of the frames, keeping them 100 %, at the same expression error. A new
/// face (first frame, after a loss) is kept on Face Mesh's presence unless RetinaFace found
/// it: BlazeFace gives a false face on 7 % of background crops (11 % with the tiles),
/// RetinaFace on 1 %; one Face Mesh does not confirm sends the search on.
///
/// With a fallback detector ([`MeshFollower::with_fallback`]), RetinaFace searches the
/// whole frame before the tiles do (one run of ~30 ms against 45 BlazeFace runs; it finds
/// faces down to a box of ~1/12 of the frame height, the tiles smaller ones).
pub struct MeshFollower {
    located: MediaPipe,
    min_presence: f32,
    previous: Option<RotatedSquare>,
    /// Frames to wait before the next tiled search, after one found nothing.
    tiled_wait: usize,
    ibug68: Ibug68Points,
    fallback: Option<crate::retinaface::RetinaFace>,
}

impl MeshFollower {
    /// `ibug68`: which points hand on the iBUG 68 landmarks ([`MeshFollower::ibug68`]).
    pub fn new(located: MediaPipe, ibug68: Ibug68Points) -> Self {
        Self {
            located,
            min_presence: DEFAULT_MIN_PRESENCE,
            previous: None,
            tiled_wait: 0,
            ibug68,
            fallback: None,
        }
    }

    /// Searches with `detector` when BlazeFace finds no face and none is being followed.
    pub fn with_fallback(mut self, detector: crate::retinaface::RetinaFace) -> Self {
        self.fallback = Some(detector);
        self
    }

    /// Whether a fallback detector is set.
    pub fn has_fallback(&self) -> bool {
        self.fallback.is_some()
    }

    /// Which Face Mesh point stands for each iBUG 68 landmark.
    pub fn ibug68(&self) -> &Ibug68Points {
        &self.ibug68
    }

    pub fn with_min_presence(mut self, presence: f32) -> Self {
        self.min_presence = presence;
        self
    }

    /// The presence below which a followed face counts as lost.
    pub fn min_presence(&self) -> f32 {
        self.min_presence
    }

    pub fn located(&self) -> &MediaPipe {
        &self.located
    }

    pub fn kind(&self) -> BackendKind {
        self.located.kind()
    }

    /// Forgets the face: the next frame starts with a detection.
    pub fn reset(&mut self) {
        self.previous = None;
        self.tiled_wait = 0;
    }

    /// The face in the next frame, or `None` if the frame shows none.
    pub fn step(&mut self, image: &RgbImage) -> Result<Option<MeshFollowResult>> {
        let result = self.follow(image);
        self.previous = match &result {
            Ok(Some(found)) => found
                .mesh
                .next_crop()
                .filter(|c| inside(c.centre, image.width(), image.height())),
            _ => None,
        };
        result
    }

    fn follow(&mut self, image: &RgbImage) -> Result<Option<MeshFollowResult>> {
        let started = web_time::Instant::now();
        let whole_frame = self.located.detect(image)?;
        let mut detect_ms = elapsed_ms(started);
        if !whole_frame.is_empty() {
            let found =
                self.mesh_on(image, &whole_frame, DetectionSource::WholeFrame, detect_ms)?;
            // A new face Face Mesh does not confirm is as good as none: search on.
            if found.is_some() || self.previous.is_some() {
                return Ok(found);
            }
        }
        // A face too small for the whole-frame pass: where it was (one run), else, with
        // no face to follow, everywhere (RetinaFace, then tiles; the first frame or after
        // a loss).
        let started = web_time::Instant::now();
        let (detections, source) = match self.previous {
            Some(previous) => {
                let region = Rect::square(previous.centre, 2.0 * previous.side);
                (
                    self.located.detect_in(image, region)?,
                    DetectionSource::NearPrevious,
                )
            }
            None if self.tiled_wait == 0 => {
                let mut found: Vec<MeshDetection> = match self.fallback.as_mut() {
                    Some(fallback) => fallback
                        .detect(image)?
                        .iter()
                        .map(crate::retinaface::RetinaDetection::to_mesh)
                        .collect(),
                    None => Vec::new(),
                };
                let mut source = DetectionSource::RetinaFace;
                if found.is_empty() {
                    found = self.located.detect_tiled(image)?;
                    source = DetectionSource::Tiles;
                }
                if found.is_empty() {
                    self.tiled_wait = TILED_SEARCH_INTERVAL;
                }
                (found, source)
            }
            None => {
                self.tiled_wait -= 1;
                return Ok(None);
            }
        };
        detect_ms += elapsed_ms(started);
        let found = self.mesh_on(image, &detections, source, detect_ms)?;
        if found.is_none() && source == DetectionSource::Tiles {
            // A false face in the background: wait before searching again, as after a
            // search that found nothing.
            self.tiled_wait = TILED_SEARCH_INTERVAL;
        }
        Ok(found)
    }

    /// Face Mesh on the largest of `detections` (on the previous frame's crop when there is
    /// none and a face is being followed), if the face is kept.
    ///
    /// Kept whatever Face Mesh's presence: a face BlazeFace detected while one is being
    /// followed (see the type's comment) and a face RetinaFace found (1-3 % false faces on
    /// background crops). A new face from BlazeFace's whole-frame pass (7 % false faces on
    /// background crops in 640 x 480 frames) or from the tiles (11 %), and a face only
    /// followed: while Face Mesh sees a face (tracking/README.md).
    fn mesh_on(
        &mut self,
        image: &RgbImage,
        detections: &[MeshDetection],
        source: DetectionSource,
        detect_ms: f64,
    ) -> Result<Option<MeshFollowResult>> {
        let largest = detections
            .iter()
            .filter(|d| inside(d.face_box.centre(), image.width(), image.height()))
            .max_by(|a, b| {
                let area = |d: &MeshDetection| d.face_box.width * d.face_box.height;
                area(a).total_cmp(&area(b))
            });
        let (crop, detected) = match (largest, self.previous) {
            (Some(detection), _) => (detection.crop(), true),
            (None, Some(previous)) => (previous, false),
            (None, None) => return Ok(None),
        };
        let started = web_time::Instant::now();
        let mesh = self.located.mesh(image, crop)?;
        let mesh_ms = elapsed_ms(started);
        let trusted = detected
            && match source {
                DetectionSource::WholeFrame => self.previous.is_some(),
                DetectionSource::NearPrevious | DetectionSource::RetinaFace => true,
                DetectionSource::Tiles => false,
            };
        Ok(
            (trusted || mesh.presence >= self.min_presence).then_some(MeshFollowResult {
                mesh,
                detected,
                detect_ms,
                mesh_ms,
            }),
        )
    }
}

/// Which search found a frame's detections ([`MeshFollower::step`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum DetectionSource {
    WholeFrame,
    NearPrevious,
    RetinaFace,
    Tiles,
}

/// After a tiled search ([`MediaPipe::detect_tiled`]) found no face, the frames that
/// search nothing but the whole frame before tiles are tried again: footage without a face
/// then costs one tiled search every half second at 30 fps, not one a frame.
pub const TILED_SEARCH_INTERVAL: usize = 15;

fn inside(p: Vec2, width: u32, height: u32) -> bool {
    (0.0..width as f32).contains(&p.x) && (0.0..height as f32).contains(&p.y)
}

fn elapsed_ms(started: web_time::Instant) -> f64 {
    started.elapsed().as_secs_f64() * 1e3
}
