//! RetinaFace (the MobileNet-0.25 variant OpenSeeFace ships, `retinaface_640x640_opt.onnx`):
//! the slower, stronger detector both locators fall back on when their fast one finds no
//! face: close-ups that fill the frame, small faces, grey photographs, faces turned or with
//! the mouth open (issue 32, item 7).
//!
//! Conventions, as OpenSeeFace's `retinaface.py` runs it: the frame is scaled so its longer
//! side is 640 px and padded right and bottom to 640 x 640 with black; the input is BGR,
//! 0..255 minus (104, 117, 123), NCHW. Outputs: box offsets [1, 16800, 4], class
//! probabilities [1, 16800, 2] (face is the second), five points [1, 16800, 10], each
//! relative to one of 16800 SSD priors ([`priors`]) with variances 0.1 (centres) and 0.2
//! (log sizes). Detections above [`DEFAULT_MIN_CONFIDENCE`] are suppressed at
//! [`DEFAULT_SUPPRESSION_OVERLAP`] intersection over union, the most confident first.
//!
//! Upstream ships the network only with ONNX Runtime's fused operators, so it runs on ONNX
//! Runtime; with tract there is no fallback detector (the loaders say so).

use std::path::{Path, PathBuf};

use glam::Vec2;
use image::RgbImage;

use crate::backend::{BackendKind, InferenceBackend, Tensor, load_model};
use crate::error::{Result, TrackingError};
use crate::mediapipe::{DETECTION_KEYPOINTS, MeshDetection};
use crate::openseeface::{FaceDetection, check_output, display_name, intersection_over_union};
use crate::preprocess::{Normalisation, Rect, sample_rect};

/// The network's file, beside OpenSeeFace's other models.
pub const MODEL_FILE: &str = "retinaface_640x640_opt.onnx";
/// Side of the network's square input.
pub const INPUT_SIZE: usize = 640;
/// Number of priors (anchors) at 640 x 640: (80^2 + 40^2 + 20^2) cells x 2 sizes.
pub const PRIOR_COUNT: usize = 16800;
/// Upstream's confidence threshold (`min_conf`).
pub const DEFAULT_MIN_CONFIDENCE: f32 = 0.4;
/// Upstream's suppression overlap (`nms_threshold`).
pub const DEFAULT_SUPPRESSION_OVERLAP: f32 = 0.4;
/// After a fallback search that found no face, the frames a follower waits before the next
/// (the same pause as the tiled BlazeFace search's): footage without a face then costs one
/// RetinaFace run every half second at 30 fps.
pub const FALLBACK_SEARCH_INTERVAL: usize = crate::mediapipe::TILED_SEARCH_INTERVAL;
/// Per-channel means subtracted from 0..255 values, in the network's (BGR) order.
const BGR_MEAN: [f32; 3] = [104.0, 117.0, 123.0];
/// The SSD variances of the centre and the log-size offsets.
const VARIANCES: [f32; 2] = [0.1, 0.2];
/// Feature strides and the two prior sizes at each (input pixels).
const LEVELS: [(usize, [f32; 2]); 3] =
    [(8, [16.0, 32.0]), (16, [64.0, 128.0]), (32, [256.0, 512.0])];

/// The priors `[cx, cy, w, h]` in [0, 1] of the input, in the network's order: per level,
/// cells row by row, two sizes per cell (what upstream's `priorbox_640x640.json` holds;
/// computed here rather than read, and checked against that file by a test).
pub fn priors() -> Vec<[f32; 4]> {
    let side = INPUT_SIZE as f32;
    let mut out = Vec::with_capacity(PRIOR_COUNT);
    for (step, sizes) in LEVELS {
        let cells = INPUT_SIZE / step;
        for row in 0..cells {
            for col in 0..cells {
                for size in sizes {
                    out.push([
                        (col as f32 + 0.5) * step as f32 / side,
                        (row as f32 + 0.5) * step as f32 / side,
                        size / side,
                        size / side,
                    ]);
                }
            }
        }
    }
    out
}

/// One face RetinaFace found, in frame pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetinaDetection {
    /// The face's box as the network draws it (brows to chin, tight at the cheeks).
    pub face_box: Rect,
    /// The eye, eye, nose tip, mouth corner, mouth corner, in the network's order: the
    /// subject's right eye (the image's left) first.
    pub points: [Vec2; 5],
    /// 0..1.
    pub score: f32,
}

impl RetinaDetection {
    /// As OpenSeeFace's detector would give it: upstream grows RetinaFace's box by 15 % of
    /// its width on each side and 20 % of its height above and below before cropping for
    /// the landmark network.
    pub fn to_openseeface(&self) -> FaceDetection {
        let b = self.face_box;
        let (dx, dy) = (0.15 * b.width, 0.2 * b.height);
        FaceDetection {
            face_box: Rect {
                x: b.x - dx,
                y: b.y - dy,
                width: b.width + 2.0 * dx,
                height: b.height + 2.0 * dy,
            },
            confidence: self.score,
        }
    }

    /// As BlazeFace would give it, for Face Mesh's crop (which takes its size from the box
    /// and its rotation from the eyes): the eyes, the nose, the mouth centre between the
    /// corners; the ears, which RetinaFace does not give, at the box's sides level with the
    /// eyes (nothing downstream reads them).
    pub fn to_mesh(&self) -> MeshDetection {
        let [right_eye, left_eye, nose, mouth_right, mouth_left] = self.points;
        let b = self.face_box;
        let eye_y = 0.5 * (right_eye.y + left_eye.y);
        let keypoints: [Vec2; DETECTION_KEYPOINTS] = [
            right_eye,
            left_eye,
            nose,
            0.5 * (mouth_right + mouth_left),
            Vec2::new(b.x, eye_y),
            Vec2::new(b.x + b.width, eye_y),
        ];
        MeshDetection {
            face_box: b,
            keypoints,
            score: self.score,
        }
    }
}

/// The detections in the network's outputs (`offsets` 16800 x 4, `classes` 16800 x 2,
/// `points` 16800 x 10) scoring above `min_confidence`, in input pixels (0..640), before
/// suppression.
pub fn decode(
    offsets: &[f32],
    classes: &[f32],
    points: &[f32],
    priors: &[[f32; 4]],
    min_confidence: f32,
) -> Vec<RetinaDetection> {
    let side = INPUT_SIZE as f32;
    let mut out = Vec::new();
    for (i, prior) in priors.iter().enumerate() {
        let Some(&score) = classes.get(2 * i + 1) else {
            break;
        };
        // NaN is no detection.
        if score.is_nan() || score <= min_confidence {
            continue;
        }
        let (Some(o), Some(p)) = (
            offsets.get(4 * i..4 * i + 4),
            points.get(10 * i..10 * i + 10),
        ) else {
            break;
        };
        let [cx, cy, pw, ph] = *prior;
        let centre = Vec2::new(cx + o[0] * VARIANCES[0] * pw, cy + o[1] * VARIANCES[0] * ph);
        let size = Vec2::new(
            pw * (o[2] * VARIANCES[1]).exp(),
            ph * (o[3] * VARIANCES[1]).exp(),
        );
        let corner = (centre - 0.5 * size) * side;
        let face_box = Rect {
            x: corner.x,
            y: corner.y,
            width: size.x * side,
            height: size.y * side,
        };
        let points = std::array::from_fn(|k| {
            Vec2::new(
                cx + p[2 * k] * VARIANCES[0] * pw,
                cy + p[2 * k + 1] * VARIANCES[0] * ph,
            ) * side
        });
        if face_box.is_valid() {
            out.push(RetinaDetection {
                face_box,
                points,
                score,
            });
        }
    }
    out
}

/// The most confident of each group of overlapping detections (intersection over union at
/// or above `overlap`), most confident first.
pub fn suppress(mut detections: Vec<RetinaDetection>, overlap: f32) -> Vec<RetinaDetection> {
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<RetinaDetection> = Vec::with_capacity(detections.len());
    for d in detections {
        if kept
            .iter()
            .all(|k| intersection_over_union(k.face_box, d.face_box) < overlap)
        {
            kept.push(d);
        }
    }
    kept
}

/// The file in `dir`, or an error saying where it comes from.
pub fn model_path(dir: &Path) -> Result<PathBuf> {
    let path = dir.join(MODEL_FILE);
    if path.is_file() {
        Ok(path)
    } else {
        Err(TrackingError::MissingModel {
            path,
            hint: format!(
                "RetinaFace ({MODEL_FILE}) comes with OpenSeeFace's models, from the public \
                 GitHub repository emilianavt/OpenSeeFace, folder models/; put it beside \
                 mnv3_detection_opt.onnx in {}",
                dir.display()
            ),
        })
    }
}

/// RetinaFace on ONNX Runtime.
pub struct RetinaFace {
    network: Box<dyn InferenceBackend>,
    name: String,
    priors: Vec<[f32; 4]>,
    min_confidence: f32,
    overlap: f32,
}

impl RetinaFace {
    /// Loads [`MODEL_FILE`] from `dir` (OpenSeeFace's model folder) on ONNX Runtime with
    /// `threads` threads, checked by one run on a blank input.
    pub fn load(dir: &Path, threads: usize) -> Result<Self> {
        let path = model_path(dir)?;
        let network = load_model(&path, BackendKind::OnnxRuntime, threads)?;
        Self::from_backend(network, &path)
    }

    /// The network already loaded; `path` names it in messages. Refused on tract, which
    /// lacks the fused operators upstream's file uses.
    pub fn from_backend(network: Box<dyn InferenceBackend>, path: &Path) -> Result<Self> {
        if network.kind() != BackendKind::OnnxRuntime {
            return Err(TrackingError::InvalidInput(format!(
                "{}: RetinaFace runs on ONNX Runtime only (upstream's file uses its fused \
                 operators)",
                path.display()
            )));
        }
        let mut detector = Self {
            network,
            name: display_name(path),
            priors: priors(),
            min_confidence: DEFAULT_MIN_CONFIDENCE,
            overlap: DEFAULT_SUPPRESSION_OVERLAP,
        };
        detector.run(&Tensor::zeros(vec![1, 3, INPUT_SIZE, INPUT_SIZE]))?;
        Ok(detector)
    }

    pub fn min_confidence(&self) -> f32 {
        self.min_confidence
    }

    /// Sets the probability a detection needs (default [`DEFAULT_MIN_CONFIDENCE`]); an
    /// error outside (0, 1).
    pub fn set_min_confidence(&mut self, confidence: f32) -> Result<()> {
        if !(confidence > 0.0 && confidence < 1.0) {
            return Err(TrackingError::InvalidInput(format!(
                "RetinaFace's confidence threshold is in (0, 1), not {confidence}"
            )));
        }
        self.min_confidence = confidence;
        Ok(())
    }

    /// The faces in `image`, most confident first, in frame pixels.
    pub fn detect(&mut self, image: &RgbImage) -> Result<Vec<RetinaDetection>> {
        let (width, height) = (image.width() as f32, image.height() as f32);
        if width == 0.0 || height == 0.0 {
            return Err(TrackingError::InvalidInput("the image is empty".into()));
        }
        // The longer side to 640, as upstream's resize (which truncates the other side).
        let scale = INPUT_SIZE as f32 / width.max(height);
        let out_w = ((width * scale) as usize).clamp(1, INPUT_SIZE);
        let out_h = ((height * scale) as usize).clamp(1, INPUT_SIZE);
        // 0..255 minus the mean: a "normalisation" of mean m / 255 and std 1 / 255, in RGB
        // order here, swapped to BGR below.
        let rgb_mean = [BGR_MEAN[2], BGR_MEAN[1], BGR_MEAN[0]];
        let norm = Normalisation {
            mean: rgb_mean.map(|m| m / 255.0),
            std: [1.0 / 255.0; 3],
        };
        let frame = Rect {
            x: 0.0,
            y: 0.0,
            width,
            height,
        };
        let scaled = sample_rect(image, frame, out_w, out_h, norm)?;
        let plane = INPUT_SIZE * INPUT_SIZE;
        let mut input = Tensor::zeros(vec![1, 3, INPUT_SIZE, INPUT_SIZE]);
        for (bgr, mean) in BGR_MEAN.iter().enumerate() {
            let rgb = 2 - bgr;
            let target = &mut input.data[bgr * plane..(bgr + 1) * plane];
            // The padding is black before the mean is taken off.
            target.fill(-mean);
            let source = &scaled.data[rgb * out_w * out_h..(rgb + 1) * out_w * out_h];
            for (row, values) in source.chunks_exact(out_w).enumerate() {
                target[row * INPUT_SIZE..row * INPUT_SIZE + out_w].copy_from_slice(values);
            }
        }
        let (offsets, classes, points) = self.run(&input)?;
        // Frame pixels per input pixel, per axis (the truncated side is a little short).
        let to_frame = Vec2::new(width / out_w as f32, height / out_h as f32);
        let found = decode(
            &offsets,
            &classes,
            &points,
            &self.priors,
            self.min_confidence,
        )
        .into_iter()
        .map(|d| RetinaDetection {
            face_box: Rect {
                x: d.face_box.x * to_frame.x,
                y: d.face_box.y * to_frame.y,
                width: d.face_box.width * to_frame.x,
                height: d.face_box.height * to_frame.y,
            },
            points: d.points.map(|p| p * to_frame),
            score: d.score,
        })
        .collect();
        Ok(suppress(found, self.overlap))
    }

    fn run(&mut self, input: &Tensor) -> Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
        let mut outputs = self.network.run(input)?.into_iter();
        let (Some(offsets), Some(classes), Some(points)) =
            (outputs.next(), outputs.next(), outputs.next())
        else {
            return Err(TrackingError::BadOutput {
                model: self.name.clone(),
                reason: "count: expected box offsets, class probabilities and points".into(),
            });
        };
        check_output(&offsets, &[1, PRIOR_COUNT, 4], &self.name, "offsets")?;
        check_output(&classes, &[1, PRIOR_COUNT, 2], &self.name, "classes")?;
        check_output(&points, &[1, PRIOR_COUNT, 10], &self.name, "points")?;
        Ok((offsets.data, classes.data, points.data))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn priors_are_the_ssd_grid() {
        let p = priors();
        assert_eq!(p.len(), PRIOR_COUNT);
        assert_eq!(p[0], [4.0 / 640.0, 4.0 / 640.0, 16.0 / 640.0, 16.0 / 640.0]);
        assert_eq!(p[1], [4.0 / 640.0, 4.0 / 640.0, 32.0 / 640.0, 32.0 / 640.0]);
        assert_eq!(p[2][0], 12.0 / 640.0);
        // The last: stride 32, cell (19, 19), size 512.
        assert_eq!(p[PRIOR_COUNT - 1], [624.0 / 640.0, 624.0 / 640.0, 0.8, 0.8]);
    }

    #[test]
    fn decoding_by_hand() {
        let priors = [[0.5, 0.25, 0.1, 0.2], [0.1, 0.1, 0.05, 0.05]];
        // Prior 0: centre moved by (1, -1) variance units, width x e^(0.2), height kept.
        let offsets = [1.0, -1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        let classes = [0.1, 0.9, 0.8, 0.2];
        let mut points = [0.0f32; 20];
        points[0] = 2.0; // point 0 of prior 0: x moved by 2 x 0.1 x 0.1
        let found = decode(&offsets, &classes, &points, &priors, 0.4);
        assert_eq!(found.len(), 1, "prior 1 scores 0.2");
        let d = found[0];
        let (cx, cy) = (0.5 + 0.1 * 0.1, 0.25 - 0.1 * 0.2);
        let (w, h) = (0.1 * 0.2f32.exp(), 0.2);
        let close = |a: f32, b: f32| (a - b).abs() < 1e-3;
        assert!(close(d.face_box.x, (cx - w / 2.0) * 640.0), "{d:?}");
        assert!(close(d.face_box.y, (cy - h / 2.0) * 640.0), "{d:?}");
        assert!(close(d.face_box.width, w * 640.0) && close(d.face_box.height, h * 640.0));
        assert!(close(d.points[0].x, (0.5 + 2.0 * 0.1 * 0.1) * 640.0));
        assert!(close(d.points[1].y, 0.25 * 640.0));
        assert_eq!(d.score, 0.9);
        // NaN scores are no detection.
        assert!(decode(&offsets, &[0.0, f32::NAN, 0.0, 0.0], &points, &priors, 0.4).is_empty());
    }

    #[test]
    fn suppression_keeps_the_most_confident_of_overlapping_boxes() {
        let at = |x: f32, score: f32| RetinaDetection {
            face_box: Rect {
                x,
                y: 0.0,
                width: 10.0,
                height: 10.0,
            },
            points: [Vec2::ZERO; 5],
            score,
        };
        // IoU of boxes 2 px apart: 80 / 120 = 0.67; 9 px apart: 10 / 190 = 0.05.
        let kept = suppress(vec![at(0.0, 0.5), at(2.0, 0.9), at(11.0, 0.6)], 0.4);
        let xs: Vec<f32> = kept.iter().map(|d| d.face_box.x).collect();
        assert_eq!(xs, vec![2.0, 11.0]);
    }

    #[test]
    fn the_openseeface_box_is_upstreams_growth() {
        let d = RetinaDetection {
            face_box: Rect {
                x: 100.0,
                y: 50.0,
                width: 40.0,
                height: 60.0,
            },
            points: [Vec2::ZERO; 5],
            score: 0.8,
        };
        let b = d.to_openseeface().face_box;
        assert_eq!((b.x, b.y, b.width, b.height), (94.0, 38.0, 52.0, 84.0));
    }
}
