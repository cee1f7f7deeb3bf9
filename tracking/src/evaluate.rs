//! Accuracy on held-out synthetic clips (rendered by `python -m likeness_train.clips` with
//! a seed training never used): expression MAE against the true w, landmark NME against
//! the true projected landmarks, head-pose error, for TrackNet alone, with refinement,
//! with the personalized model and with smoothing.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use face::camera::{HeadPose, Intrinsics};
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{
    BlendshapeWeights, FaceModel, ICT_NAMES, NUM_BLENDSHAPES, NUM_LANDMARKS, PersonalCorrections,
    PersonalizedBlendshapes, Template,
};
use glam::{Vec2, Vec3};
use serde::Deserialize;

use crate::error::{Result, TrackingError, io_error};
use crate::identity::IdentityConfig;
use crate::networks::ModelNet;
use crate::pipeline::{FrameOutput, LocatorChoice, Tracker, TrackerConfig};
use crate::record::FrameRecord;
use crate::refine::RefineConfig;
use crate::smooth::SmoothingConfig;
use crate::source::{FrameSource, ImageFiles, Next, natural_cmp};

/// One frame's truth.
#[derive(Clone, Debug, Deserialize)]
pub struct TruthFrame {
    pub index: usize,
    pub time_s: f64,
    pub weights: Vec<f32>,
    pub rotation_deg: [f32; 3],
    pub translation: [f32; 3],
    pub landmarks_68: Vec<[f32; 2]>,
    pub face_box: [f32; 4],
}

/// A clip's truth file.
#[derive(Clone, Debug, Deserialize)]
pub struct ClipTruth {
    /// The seed the clip was rendered with (absent in clips from before it was written).
    #[serde(default)]
    pub seed: Option<u64>,
    pub width: u32,
    pub height: u32,
    pub focal_px: f32,
    pub fps: f64,
    pub frames: Vec<TruthFrame>,
}

/// A held-out clip on disk.
#[derive(Clone, Debug)]
pub struct Clip {
    pub dir: PathBuf,
    pub truth: ClipTruth,
    pub frames: Vec<PathBuf>,
}

/// Where `training/setup.sh` renders the held-out clips.
pub fn default_clips_dir() -> PathBuf {
    match std::env::var_os("LIKENESS_CLIPS").filter(|v| !v.is_empty()) {
        Some(d) => PathBuf::from(d),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../training/.cache/clips-s9001"),
    }
}

impl Clip {
    pub fn load(dir: &Path) -> Result<Self> {
        let truth_path = dir.join("truth.json");
        let text = std::fs::read_to_string(&truth_path).map_err(io_error(&truth_path))?;
        let truth: ClipTruth = serde_json::from_str(&text).map_err(|e| TrackingError::Decode {
            path: truth_path.clone(),
            reason: e.to_string(),
        })?;
        let mut frames: Vec<PathBuf> = std::fs::read_dir(dir)
            .map_err(io_error(dir))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "png"))
            .collect();
        frames.sort_by(|a, b| natural_cmp(&a.to_string_lossy(), &b.to_string_lossy()));
        let bad = truth.frames.len() != frames.len()
            || truth.frames.iter().any(|f| {
                f.weights.len() != NUM_BLENDSHAPES || f.landmarks_68.len() != NUM_LANDMARKS
            });
        if bad || frames.is_empty() {
            return Err(TrackingError::Decode {
                path: truth_path,
                reason: format!(
                    "{} truth frames for {} images, or arrays of the wrong length",
                    truth.frames.len(),
                    frames.len()
                ),
            });
        }
        Ok(Self {
            dir: dir.to_owned(),
            truth,
            frames,
        })
    }

    /// Every clip folder (`clip_*`) under `root`, in order.
    pub fn load_all(root: &Path) -> Result<Vec<Self>> {
        let mut dirs: Vec<PathBuf> = std::fs::read_dir(root)
            .map_err(io_error(root))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.join("truth.json").is_file())
            .collect();
        dirs.sort();
        if dirs.is_empty() {
            return Err(TrackingError::MissingModel {
                path: root.to_owned(),
                hint: "no clips: render them with `python -m likeness_train.clips` (training/setup.sh does)".into(),
            });
        }
        dirs.iter().map(|d| Self::load(d)).collect()
    }

    /// Horizontal field of view of the clip's camera.
    pub fn fov_deg(&self) -> f32 {
        2.0 * (0.5 * self.truth.width as f32 / self.truth.focal_px)
            .atan()
            .to_degrees()
    }

    pub fn source(&self) -> ImageFiles {
        ImageFiles::new(
            self.frames.clone(),
            self.truth.fps,
            self.dir.display().to_string(),
        )
    }

    /// The clip's true person as blendshapes: their `person.safetensors` (`dS0` [3, 128,
    /// 128] and `dS` [53, 3, 128, 128], cm, channels first) through equation (2). The
    /// frames were rendered with the exact identity offset; dS_0 is its UV projection,
    /// what ModelNet could output at best (its landmarks reproduce the clip's within
    /// 0.05 px, the `refinement_bounds` example checks).
    pub fn true_person(&self, face: &FaceModel) -> Result<PersonalizedBlendshapes> {
        let path = self.dir.join("person.safetensors");
        let bytes = std::fs::read(&path).map_err(io_error(&path))?;
        let bad = |reason: String| TrackingError::Decode {
            path: path.clone(),
            reason,
        };
        let tensors =
            safetensors::SafeTensors::deserialize(&bytes).map_err(|e| bad(e.to_string()))?;
        let size = CORRECTION_SIZE;
        let read = |name: &str, maps: usize| -> Result<Vec<UvMap>> {
            let t = tensors.tensor(name).map_err(|e| bad(e.to_string()))?;
            let plane = 3 * size * size;
            if t.dtype() != safetensors::Dtype::F32 || t.data().len() != maps * plane * 4 {
                return Err(bad(format!(
                    "`{name}` is not {maps} x 3 x {size} x {size} f32"
                )));
            }
            let values: Vec<f32> = t
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            Ok(values
                .chunks_exact(plane)
                .map(|chw| crate::networks::chw_to_uv(chw, size, size))
                .collect())
        };
        let mut corrections = PersonalCorrections::zeros();
        corrections.identity_shape = read("dS0", 1)?.remove(0);
        corrections.expression_shapes = read("dS", NUM_BLENDSHAPES)?;
        Ok(face.personalize(&corrections)?)
    }
}

impl TruthFrame {
    /// The true weights (a loaded clip has 53 per frame).
    pub fn blendshape_weights(&self) -> BlendshapeWeights {
        BlendshapeWeights(std::array::from_fn(|i| {
            self.weights.get(i).copied().unwrap_or(0.0)
        }))
    }

    /// The true head pose in the clip's camera.
    pub fn pose(&self) -> HeadPose {
        let [yaw, pitch, roll] = self.rotation_deg;
        HeadPose::from_degrees(yaw, pitch, roll, Vec3::from(self.translation))
    }

    /// Where `person`'s `vertices` appear in this frame (true weights and pose, the clip's
    /// camera `intrinsics`).
    pub fn project_vertices(
        &self,
        person: &PersonalizedBlendshapes,
        intrinsics: &Intrinsics,
        vertices: &[u32],
    ) -> Result<Vec<Vec2>> {
        let (pose, weights) = (self.pose(), self.blendshape_weights());
        vertices
            .iter()
            .map(|&v| {
                if v as usize >= person.vertex_count {
                    return Err(TrackingError::InvalidInput(format!(
                        "vertex {v} is outside the person's {} vertices",
                        person.vertex_count
                    )));
                }
                intrinsics
                    .project(pose.transform(person.vertex(v as usize, &weights)))
                    .ok_or_else(|| {
                        TrackingError::InvalidInput(format!(
                            "frame {}: vertex {v} is behind the camera",
                            self.index
                        ))
                    })
            })
            .collect()
    }
}

/// Tracks `clip` with `locator` (its camera, no refinement, no smoothing; dense points kept
/// for a dense locator): each frame's output and the camera, for studies of what the
/// detectors and TrackNet give.
pub fn track_clip_unrefined(
    face: Arc<FaceModel>,
    clip: &Clip,
    locator: LocatorChoice,
) -> Result<(Vec<FrameOutput>, Intrinsics)> {
    let config = TrackerConfig {
        locator,
        dense_fit: true,
        refine: None,
        ..TrackerConfig::default()
    };
    let TrackedClip {
        tracker, outputs, ..
    } = track_clip(face, clip, &config)?;
    let intrinsics = tracker.intrinsics(clip.truth.width, clip.truth.height);
    Ok((outputs, intrinsics))
}

/// Errors of one variant over one or more clips.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Metrics {
    /// Mean |w - w_true| over channels and frames with a face.
    pub expression_mae: f64,
    /// Mean |w - w_true| over the visible channels ([`visible_channels`]).
    pub expression_mae_visible: f64,
    /// Mean landmark distance / sqrt(true box area), over frames with a face.
    pub landmark_nme: f64,
    /// Mean landmark distance / the true outer inter-ocular distance (points 36 and 45).
    pub landmark_nme_iod: f64,
    /// Mean |yaw|, |pitch|, |roll| error in degrees.
    pub pose_error_deg: [f64; 3],
    /// Frames with a face found / all frames.
    pub detected: f64,
    /// Jitter: mean over consecutive frames of |(w_t - w_t-1) - (true change)|, per
    /// channel: the frame-to-frame noise smoothing is meant to remove.
    pub weight_jitter: f64,
    /// The same for the landmarks, in NME units.
    pub landmark_jitter: f64,
    /// How the weights follow the true head yaw ([`yaw_following`]): the predicted weights
    /// (what a real-footage check can measure), their errors (pred - truth, what should
    /// not follow the yaw) and the true weights themselves (a few clips' slow random walks
    /// correlate by chance: the baseline).
    pub yaw_following: YawFollowing,
    pub yaw_following_error: YawFollowing,
    pub yaw_following_truth: YawFollowing,
    pub frames: usize,
}

#[derive(Default)]
struct Accumulator {
    mae: f64,
    nme: f64,
    nme_iod: f64,
    /// Every frame's predicted and true weights (frames with a face), for the per-channel
    /// report.
    predicted: Vec<[f32; NUM_BLENDSHAPES]>,
    truth: Vec<[f32; NUM_BLENDSHAPES]>,
    /// The true yaw (degrees) of each of those frames.
    yaw: Vec<f64>,
    pose: [f64; 3],
    with_face: usize,
    all: usize,
    jitter_w: f64,
    jitter_lm: f64,
    pairs: usize,
    /// The previous frame's prediction and truth (cleared between clips).
    previous: Option<(FrameRecord, TruthFrame)>,
}

impl Accumulator {
    fn add(&mut self, record: &FrameRecord, truth: &TruthFrame) {
        self.all += 1;
        let previous = self.previous.replace((record.clone(), truth.clone()));
        let Some(t) = &record.track else { return };
        if let Some((p, pt)) = previous
            .as_ref()
            .and_then(|(r, pt)| Some((r.track.as_ref()?, pt)))
        {
            self.pairs += 1;
            self.jitter_w += (0..NUM_BLENDSHAPES)
                .map(|i| {
                    f64::from(
                        ((t.weights[i] - p.weights[i]) - (truth.weights[i] - pt.weights[i])).abs(),
                    )
                })
                .sum::<f64>()
                / NUM_BLENDSHAPES as f64;
            let norm = f64::from(truth.face_box[2] * truth.face_box[3])
                .sqrt()
                .max(1e-6);
            self.jitter_lm += (0..NUM_LANDMARKS)
                .map(|k| {
                    let d =
                        glam::Vec2::from(t.landmarks_68[k]) - glam::Vec2::from(p.landmarks_68[k]);
                    let e = glam::Vec2::from(truth.landmarks_68[k])
                        - glam::Vec2::from(pt.landmarks_68[k]);
                    f64::from((d - e).length())
                })
                .sum::<f64>()
                / (NUM_LANDMARKS as f64 * norm);
        }
        self.with_face += 1;
        let weights = |w: &[f32]| std::array::from_fn(|i| w.get(i).copied().unwrap_or(0.0));
        self.predicted.push(weights(&t.weights));
        self.truth.push(weights(&truth.weights));
        self.yaw.push(f64::from(truth.rotation_deg[0]));
        let iod = glam::Vec2::from(truth.landmarks_68[OUTER_EYE_CORNERS.0])
            .distance(glam::Vec2::from(truth.landmarks_68[OUTER_EYE_CORNERS.1]));
        self.nme_iod += t
            .landmarks_68
            .iter()
            .zip(&truth.landmarks_68)
            .map(|(a, b)| f64::from(glam::Vec2::from(*a).distance(glam::Vec2::from(*b))))
            .sum::<f64>()
            / (NUM_LANDMARKS as f64 * f64::from(iod).max(1e-6));
        self.mae += t
            .weights
            .iter()
            .zip(&truth.weights)
            .map(|(a, b)| f64::from((a - b).abs()))
            .sum::<f64>()
            / NUM_BLENDSHAPES as f64;
        let norm = f64::from(truth.face_box[2] * truth.face_box[3])
            .sqrt()
            .max(1e-6);
        self.nme += t
            .landmarks_68
            .iter()
            .zip(&truth.landmarks_68)
            .map(|(a, b)| f64::from(glam::Vec2::from(*a).distance(glam::Vec2::from(*b))))
            .sum::<f64>()
            / (NUM_LANDMARKS as f64 * norm);
        for k in 0..3 {
            let mut d = t.rotation_deg[k] - truth.rotation_deg[k];
            d = (d + 180.0).rem_euclid(360.0) - 180.0;
            self.pose[k] += f64::from(d.abs());
        }
    }

    fn new_clip(&mut self) {
        self.previous = None;
    }

    /// `clip`'s frames refined again by `tracker` from a reset, as a new clip.
    fn add_retracked(&mut self, tracker: &mut Tracker, outputs: &[FrameOutput], clip: &Clip) {
        self.new_clip();
        tracker.reset();
        let (w, h) = (clip.truth.width, clip.truth.height);
        for (o, t) in outputs.iter().zip(&clip.truth.frames) {
            self.add(&tracker.retrack(o, w, h), t);
        }
    }

    fn finish(&self, visible: &[bool; NUM_BLENDSHAPES]) -> (Metrics, ExpressionReport) {
        let n = self.with_face.max(1) as f64;
        let report = expression_report(&self.predicted, &self.truth, visible);
        let error: Vec<[f32; NUM_BLENDSHAPES]> = self
            .predicted
            .iter()
            .zip(&self.truth)
            .map(|(p, t)| std::array::from_fn(|i| p[i] - t[i]))
            .collect();
        let metrics = Metrics {
            yaw_following: yaw_following(&self.predicted, &self.yaw),
            yaw_following_error: yaw_following(&error, &self.yaw),
            yaw_following_truth: yaw_following(&self.truth, &self.yaw),
            expression_mae: self.mae / n,
            expression_mae_visible: report.mae_visible[0],
            landmark_nme: self.nme / n,
            landmark_nme_iod: self.nme_iod / n,
            pose_error_deg: self.pose.map(|p| p / n),
            detected: self.with_face as f64 / self.all.max(1) as f64,
            frames: self.all,
            weight_jitter: self.jitter_w / self.pairs.max(1) as f64,
            landmark_jitter: self.jitter_lm / self.pairs.max(1) as f64,
        };
        (metrics, report)
    }
}

/// Pearson correlation of two equally long series (0 where either is constant).
fn pearson(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().min(b.len());
    if n == 0 {
        return 0.0;
    }
    let mean = |x: &[f64]| x[..n].iter().sum::<f64>() / n as f64;
    let (ma, mb) = (mean(a), mean(b));
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for k in 0..n {
        let (x, y) = (a[k] - ma, b[k] - mb);
        sab += x * y;
        saa += x * x;
        sbb += y * y;
    }
    let denominator = (saa * sbb).sqrt();
    if denominator > 0.0 {
        sab / denominator
    } else {
        0.0
    }
}

/// How much a series of weights follows the head yaw (issue 32 asks |r| <= 0.3 for every
/// channel of the tracked weights on real footage).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct YawFollowing {
    /// The channel with the largest |r| with the yaw, and that r.
    pub channel: usize,
    pub r: f64,
    /// r of eyeBlink_L - eyeBlink_R with the yaw (a tracker that reads a turned head as a
    /// wink).
    pub blink_asymmetry_r: f64,
}

/// [`YawFollowing`] of `predicted` (one row per frame) against `yaw`.
fn yaw_following(predicted: &[[f32; NUM_BLENDSHAPES]], yaw: &[f64]) -> YawFollowing {
    let column = |f: &dyn Fn(&[f32; NUM_BLENDSHAPES]) -> f32| -> Vec<f64> {
        predicted.iter().map(|w| f64::from(f(w))).collect()
    };
    let (channel, r) = (0..NUM_BLENDSHAPES)
        .map(|i| (i, pearson(&column(&|w| w[i]), yaw)))
        .fold((0, 0.0f64), |best, (i, r)| {
            if r.abs() > best.1.abs() { (i, r) } else { best }
        });
    let blink = |name: &str| ICT_NAMES.iter().position(|n| *n == name);
    let asymmetry = match (blink("eyeBlink_L"), blink("eyeBlink_R")) {
        (Some(l), Some(rr)) => pearson(&column(&|w| w[l] - w[rr]), yaw),
        _ => 0.0,
    };
    YawFollowing {
        channel,
        r,
        blink_asymmetry_r: asymmetry,
    }
}

/// The outer eye corners of the 68-point layout, the usual inter-ocular normaliser.
pub const OUTER_EYE_CORNERS: (usize, usize) = (36, 45);
/// A channel counts as visible when, at w = 1 on the template, some face or eyeball vertex
/// moves at least this many pixels at the synthetic people's nominal framing (the face
/// `NOMINAL_FACE_FILL` of a 128 px image): the training evaluation's rule
/// (`training/likeness_train/metrics.py`).
pub const VISIBLE_MIN_PX: f32 = 1.0;
pub const NOMINAL_FACE_FILL: f32 = 0.85;
pub const NOMINAL_IMAGE_PX: f32 = 128.0;
/// w above this counts as "the shape is shown" (activation F1).
pub const ACTIVE_THRESHOLD: f32 = 0.3;

/// The largest image motion in pixels of each blendshape at w = 1 on the template (face
/// and eyeballs, the eyes turned by [`face::gaze`]) at the nominal framing.
pub fn channel_motion_px(template: &Template) -> [f32; NUM_BLENDSHAPES] {
    let face_end = template
        .parts
        .iter()
        .find(|p| p.name == "face")
        .map_or(template.vertex_count(), |p| p.vertices.end as usize);
    let (low, high) = template.neutral[..face_end]
        .iter()
        .fold((f32::MAX, f32::MIN), |(lo, hi), v| {
            (lo.min(v.y), hi.max(v.y))
        });
    let pixels_per_cm = NOMINAL_FACE_FILL * NOMINAL_IMAGE_PX / (high - low).max(1e-6);
    let eyes = face::gaze::Eyes::new(template, &template.neutral);
    let shown = |v: usize| {
        v < face_end
            || eyes
                .as_ref()
                .is_some_and(|e| e.ranges.iter().any(|r| r.contains(&v)))
    };
    std::array::from_fn(|i| {
        let mut moved: Vec<glam::Vec3> = template
            .neutral
            .iter()
            .zip(template.expression_delta(i))
            .map(|(p, d)| *p + *d)
            .collect();
        if let Some(eyes) = &eyes {
            let mut one_hot = [0.0; NUM_BLENDSHAPES];
            one_hot[i] = 1.0;
            eyes.turn(&one_hot, &mut moved, None);
        }
        moved
            .iter()
            .zip(&template.neutral)
            .enumerate()
            .filter(|(v, _)| shown(*v))
            .map(|(_, (a, b))| a.distance(*b))
            .fold(0.0, f32::max)
            * pixels_per_cm
    })
}

/// The channels an image can show ([`VISIBLE_MIN_PX`]).
pub fn visible_channels(template: &Template) -> [bool; NUM_BLENDSHAPES] {
    channel_motion_px(template).map(|px| px >= VISIBLE_MIN_PX)
}

/// One channel's accuracy beside the trivial predictors on the same frames.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ChannelReport {
    pub name: &'static str,
    pub mae: f64,
    pub mae_zero: f64,
    pub mae_constant_mean: f64,
    /// Pearson correlation with the truth (0 where either side is constant).
    pub correlation: f64,
    /// F1 of "w > ACTIVE_THRESHOLD"; `None` where neither side is ever active.
    pub f1: Option<f64>,
    pub visible: bool,
}

/// Expression accuracy: MAE over all channels and over the visible ones for the prediction,
/// w = 0 and w = each channel's mean over these frames (in that order), and per channel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ExpressionReport {
    pub mae_all: [f64; 3],
    pub mae_visible: [f64; 3],
    pub channels: Vec<ChannelReport>,
}

/// The report of `predicted` against `truth` (the same frames).
pub fn expression_report(
    predicted: &[[f32; NUM_BLENDSHAPES]],
    truth: &[[f32; NUM_BLENDSHAPES]],
    visible: &[bool; NUM_BLENDSHAPES],
) -> ExpressionReport {
    let n = predicted.len().min(truth.len());
    let frames = n.max(1) as f64;
    let channels: Vec<ChannelReport> = (0..NUM_BLENDSHAPES)
        .map(|i| {
            let p: Vec<f64> = predicted[..n].iter().map(|w| f64::from(w[i])).collect();
            let t: Vec<f64> = truth[..n].iter().map(|w| f64::from(w[i])).collect();
            let mt = t.iter().sum::<f64>() / frames;
            let mae = |c: &dyn Fn(usize) -> f64| {
                (0..n).map(|k| (c(k) - t[k]).abs()).sum::<f64>() / frames
            };
            let threshold = f64::from(ACTIVE_THRESHOLD);
            let (found, real) = (
                p.iter().filter(|&&x| x > threshold).count(),
                t.iter().filter(|&&x| x > threshold).count(),
            );
            let both = (0..n)
                .filter(|&k| p[k] > threshold && t[k] > threshold)
                .count();
            ChannelReport {
                name: ICT_NAMES[i],
                mae: mae(&|k| p[k]),
                mae_zero: mae(&|_| 0.0),
                mae_constant_mean: mae(&|_| mt),
                correlation: pearson(&p, &t),
                f1: (found + real > 0).then(|| 2.0 * both as f64 / (found + real) as f64),
                visible: visible[i],
            }
        })
        .collect();
    let average = |pick: &dyn Fn(&ChannelReport) -> f64, only_visible: bool| {
        let chosen: Vec<f64> = channels
            .iter()
            .filter(|c| c.visible || !only_visible)
            .map(pick)
            .collect();
        chosen.iter().sum::<f64>() / chosen.len().max(1) as f64
    };
    let three = |only_visible: bool| {
        [
            average(&|c| c.mae, only_visible),
            average(&|c| c.mae_zero, only_visible),
            average(&|c| c.mae_constant_mean, only_visible),
        ]
    };
    ExpressionReport {
        mae_all: three(false),
        mae_visible: three(true),
        channels,
    }
}

impl ExpressionReport {
    /// A Markdown table, one row per channel.
    pub fn table(&self) -> String {
        let mut out = String::from(
            "| channel | MAE | w = 0 | constant mean | correlation | F1 (w > 0.3) |\n|---|---|---|---|---|---|\n",
        );
        for c in &self.channels {
            let f1 = c.f1.map_or("-".to_string(), |f| format!("{f:.2}"));
            let name = if c.visible {
                c.name.to_string()
            } else {
                format!("{} (not visible)", c.name)
            };
            out.push_str(&format!(
                "| {name} | {:.3} | {:.3} | {:.3} | {:.2} | {f1} |\n",
                c.mae, c.mae_zero, c.mae_constant_mean, c.correlation
            ));
        }
        out
    }
}

/// One clip tracked by TrackNet alone (no refinement, no smoothing, the clip's camera):
/// what every refined variant starts from, so TrackNet runs once per clip.
struct TrackedClip {
    tracker: Tracker,
    outputs: Vec<FrameOutput>,
    /// `config`'s refinement settings (the default when it has none).
    refine_config: RefineConfig,
}

fn track_clip(face: Arc<FaceModel>, clip: &Clip, config: &TrackerConfig) -> Result<TrackedClip> {
    let mut cfg = config.clone();
    cfg.fov_deg = Some(clip.fov_deg());
    cfg.smoothing = SmoothingConfig::off();
    let refine_config = cfg.refine.clone().unwrap_or_default();
    cfg.refine = None;
    let mut tracker = Tracker::new(face, cfg, true)?;
    let mut outputs: Vec<FrameOutput> = Vec::new();
    let mut source = clip.source();
    loop {
        match source.next_frame()? {
            Next::Frame(f) => outputs.push(tracker.process(&f)),
            Next::Skipped(s) => return Err(s.error),
            Next::End => break,
        }
    }
    Ok(TrackedClip {
        tracker,
        outputs,
        refine_config,
    })
}

/// The refinement settings compared by [`tune_refinement`] and what each gave.
#[derive(Clone, Debug, Default)]
pub struct Tuning {
    /// TrackNet alone on the tuning clips: the row every candidate must beat.
    pub tracknet: Metrics,
    /// Each candidate and its metrics with refinement on the template, in the given order.
    pub rows: Vec<(RefineConfig, Metrics)>,
    /// Index into `rows` of the candidate with the lowest expression MAE over all 53
    /// channels (the first of equals, so list the candidates from the weakest prior up).
    pub chosen: usize,
    pub clips: usize,
}

/// Refinement on the template with each of `candidates` over `clips`, TrackNet run once
/// per clip. Meant for clips of a seed that neither training nor the held-out evaluation
/// uses (`likeness_train.clips --seed 9002`): settings chosen here and then reported on
/// the held-out clips (seed 9001) are not tuned on what they are reported on.
pub fn tune_refinement(
    face: Arc<FaceModel>,
    clips: &[Clip],
    config: &TrackerConfig,
    candidates: &[RefineConfig],
) -> Result<Tuning> {
    if candidates.is_empty() {
        return Err(TrackingError::InvalidInput(
            "no refinement settings to compare".into(),
        ));
    }
    for c in candidates {
        c.validate()?;
    }
    let mut tracknet = Accumulator::default();
    let mut acc: Vec<Accumulator> = candidates.iter().map(|_| Accumulator::default()).collect();
    for clip in clips {
        let TrackedClip {
            mut tracker,
            outputs,
            ..
        } = track_clip(face.clone(), clip, config)?;
        tracknet.new_clip();
        for (o, t) in outputs.iter().zip(&clip.truth.frames) {
            tracknet.add(&o.record, t);
        }
        for (candidate, a) in candidates.iter().zip(&mut acc) {
            tracker.set_refine(Some(candidate.clone()));
            a.add_retracked(&mut tracker, &outputs, clip);
        }
    }
    let visible = visible_channels(&face.template);
    let rows: Vec<(RefineConfig, Metrics)> = candidates
        .iter()
        .cloned()
        .zip(acc.iter().map(|a| a.finish(&visible).0))
        .collect();
    let chosen = rows.iter().enumerate().fold(0, |best, (i, (_, m))| {
        if m.expression_mae < rows[best].1.expression_mae {
            i
        } else {
            best
        }
    });
    Ok(Tuning {
        tracknet: tracknet.finish(&visible).0,
        rows,
        chosen,
        clips: clips.len(),
    })
}

/// Refuses tuning clips that share a seed with the held-out clips (or name no seed, so
/// that cannot be checked): settings chosen on the clips they are reported on would
/// flatter themselves.
pub fn check_tuning_clips(tuning: &[Clip], held_out: &[Clip]) -> Result<()> {
    let held_out_seeds: Vec<u64> = held_out.iter().filter_map(|c| c.truth.seed).collect();
    match tuning
        .iter()
        .find(|c| c.truth.seed.is_none_or(|s| held_out_seeds.contains(&s)))
    {
        Some(c) => Err(TrackingError::InvalidInput(format!(
            "tuning clip {} is {}; render tuning clips with a seed of their own (python -m likeness_train.clips --seed 9002)",
            c.dir.display(),
            match c.truth.seed {
                Some(s) => format!("of seed {s}, a held-out clips' seed"),
                None => "of no recorded seed".to_string(),
            }
        ))),
        None => Ok(()),
    }
}

/// Refinement on the template with an identity fitted to each clip by each of
/// `candidates`, over tuning clips (as [`tune_refinement`], never the held-out ones): the
/// metrics with refinement on the template alone first, then one row per candidate.
pub fn tune_identity(
    face: Arc<FaceModel>,
    clips: &[Clip],
    config: &TrackerConfig,
    candidates: &[IdentityConfig],
) -> Result<(Metrics, Vec<(IdentityConfig, Metrics)>)> {
    if candidates.is_empty() {
        return Err(TrackingError::InvalidInput(
            "no identity settings to compare".into(),
        ));
    }
    for c in candidates {
        c.validate(face.template.identity_count)?;
    }
    let mut template = Accumulator::default();
    let mut acc: Vec<Accumulator> = candidates.iter().map(|_| Accumulator::default()).collect();
    for clip in clips {
        let TrackedClip {
            mut tracker,
            outputs,
            refine_config,
        } = track_clip(face.clone(), clip, config)?;
        let (w, h) = (clip.truth.width, clip.truth.height);
        tracker.set_refine(Some(refine_config));
        let template_model = Arc::new(face.template_blendshapes());
        template.add_retracked(&mut tracker, &outputs, clip);
        for (candidate, a) in candidates.iter().zip(&mut acc) {
            tracker.set_blendshapes(template_model.clone())?;
            tracker.fit_identity(&outputs, w, h, candidate)?;
            a.add_retracked(&mut tracker, &outputs, clip);
        }
    }
    let visible = visible_channels(&face.template);
    Ok((
        template.finish(&visible).0,
        candidates
            .iter()
            .cloned()
            .zip(acc.iter().map(|a| a.finish(&visible).0))
            .collect(),
    ))
}

impl Tuning {
    /// A Markdown table: TrackNet alone, then each candidate's weight prior and sparsity
    /// with its errors, the chosen one marked.
    pub fn table(&self) -> String {
        let mut out = format!(
            "{} clips, {} frames\n\n| refinement | expression MAE (all 53) | MAE (visible) | landmark NME (box) | chosen |\n|---|---|---|---|---|\n| none (TrackNet only) | {:.4} | {:.4} | {:.2} % | |\n",
            self.clips,
            self.tracknet.frames,
            self.tracknet.expression_mae,
            self.tracknet.expression_mae_visible,
            100.0 * self.tracknet.landmark_nme
        );
        for (i, (c, m)) in self.rows.iter().enumerate() {
            out.push_str(&format!(
                "| weight prior {}, sparsity {}, rotation prior {}, translation prior {} | {:.4} | {:.4} | {:.2} % | {} |\n",
                c.weight_prior,
                c.weight_sparsity,
                c.rotation_prior,
                c.translation_prior,
                m.expression_mae,
                m.expression_mae_visible,
                100.0 * m.landmark_nme,
                if i == self.chosen { "yes" } else { "" }
            ));
        }
        out
    }
}

/// The variants compared, in table order.
pub const VARIANTS: [&str; 5] = [
    "TrackNet only",
    "+ refinement (template)",
    "+ refinement (identity fitted to the clip)",
    "+ refinement (personalized)",
    "+ refinement (personalized) + smoothing",
];

/// One row per variant, plus the w = 0 reference MAE.
#[derive(Clone, Debug, Default)]
pub struct Evaluation {
    pub rows: Vec<(String, Metrics)>,
    /// Per variant (the order of `rows`), the expression report.
    pub reports: Vec<ExpressionReport>,
    pub zero_weights_mae: f64,
    pub clips: usize,
    pub backend: String,
}

/// Runs every variant over `clips`. `config` supplies backend and models; its refinement
/// settings are used for the refined variants, and the camera comes from each clip.
pub fn evaluate(
    face: Arc<FaceModel>,
    clips: &[Clip],
    config: &TrackerConfig,
    personalize_frames: usize,
    identity: &IdentityConfig,
) -> Result<Evaluation> {
    let mut acc: Vec<Accumulator> = (0..VARIANTS.len())
        .map(|_| Accumulator::default())
        .collect();
    let mut zero = 0.0;
    let mut zero_n = 0usize;
    let mut backend = String::new();
    for clip in clips {
        let TrackedClip {
            mut tracker,
            outputs,
            refine_config,
        } = track_clip(face.clone(), clip, config)?;
        backend = tracker.backend().to_string();
        for a in &mut acc {
            a.new_clip();
        }
        for (o, t) in outputs.iter().zip(&clip.truth.frames) {
            acc[0].add(&o.record, t);
            zero +=
                t.weights.iter().map(|w| f64::from(w.abs())).sum::<f64>() / NUM_BLENDSHAPES as f64;
            zero_n += 1;
        }
        let (w, h) = (clip.truth.width, clip.truth.height);
        // Refinement on the template.
        tracker.set_refine(Some(refine_config.clone()));
        acc[1].add_retracked(&mut tracker, &outputs, clip);
        // The template with the identity fitted to the whole clip (a clip with no face to
        // fit keeps the template, and this row then equals the one above).
        if let Err(e) = tracker.fit_identity(&outputs, w, h, identity) {
            tracing::warn!("{}: no identity fitted: {e}", clip.dir.display());
        }
        acc[2].add_retracked(&mut tracker, &outputs, clip);
        // Personalized: ModelNet on diverse frames of this clip.
        let mut model_net = ModelNet::load(&tracker.manifest, tracker.backend(), config.threads)?;
        let (corrections, _) =
            crate::personalize::personalize(&mut model_net, &outputs, personalize_frames)?;
        tracker.set_blendshapes(Arc::new(face.personalize(&corrections)?))?;
        acc[3].add_retracked(&mut tracker, &outputs, clip);
        tracker.set_smoothing(config.smoothing.clone());
        acc[4].add_retracked(&mut tracker, &outputs, clip);
    }
    let visible = visible_channels(&face.template);
    let (metrics, reports): (Vec<Metrics>, Vec<ExpressionReport>) =
        acc.iter().map(|a| a.finish(&visible)).unzip();
    Ok(Evaluation {
        rows: VARIANTS
            .iter()
            .map(|name| name.to_string())
            .zip(metrics)
            .collect(),
        reports,
        zero_weights_mae: zero / zero_n.max(1) as f64,
        clips: clips.len(),
        backend,
    })
}

impl Evaluation {
    /// A Markdown table.
    pub fn table(&self) -> String {
        let visible = self
            .reports
            .first()
            .map_or(0, |r| r.channels.iter().filter(|c| c.visible).count());
        let mut out = format!(
            "{} held-out clips, {} frames, backend {}\n\n| variant | expression MAE (all 53) | MAE ({visible} visible) | landmark NME (box) | NME (inter-ocular) | yaw / pitch / roll error (deg) | w jitter | landmark jitter | face found | weights following the yaw: channel (r); blink L - R r | errors following the yaw: channel (r); blink L - R r |\n|---|---|---|---|---|---|---|---|---|---|---|\n",
            self.clips,
            self.rows.first().map_or(0, |r| r.1.frames),
            self.backend
        );
        for (name, m) in &self.rows {
            out.push_str(&format!(
                "| {name} | {:.4} | {:.4} | {:.2} % | {:.2} % | {:.2} / {:.2} / {:.2} | {:.4} | {:.2} % | {:.0} % | {} ({:.2}); {:.2} | {} ({:.2}); {:.2} |\n",
                m.expression_mae,
                m.expression_mae_visible,
                100.0 * m.landmark_nme,
                100.0 * m.landmark_nme_iod,
                m.pose_error_deg[0],
                m.pose_error_deg[1],
                m.pose_error_deg[2],
                m.weight_jitter,
                100.0 * m.landmark_jitter,
                100.0 * m.detected,
                ICT_NAMES[m.yaw_following.channel],
                m.yaw_following.r,
                m.yaw_following.blink_asymmetry_r,
                ICT_NAMES[m.yaw_following_error.channel],
                m.yaw_following_error.r,
                m.yaw_following_error.blink_asymmetry_r
            ));
        }
        if let Some(r) = self.reports.first() {
            let truth = self.rows.first().map(|(_, m)| m.yaw_following_truth);
            out.push_str(&format!(
                "| w = 0 (same frames) | {:.4} | {:.4} | | | | | | | | |\n| w = each channel's mean (same frames) | {:.4} | {:.4} | | | | | | | | |\n| the true weights (same frames) | | | | | | | | | {} ({:.2}); {:.2} | |\n",
                r.mae_all[1], r.mae_visible[1], r.mae_all[2], r.mae_visible[2],
                truth.map_or("-", |t| ICT_NAMES[t.channel]),
                truth.map_or(0.0, |t| t.r),
                truth.map_or(0.0, |t| t.blink_asymmetry_r)
            ));
        }
        out
    }
}

/// How well the model's landmarks agree with OpenSeeFace's on a real image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RealCropAgreement {
    /// Mean distance over the iBUG points both have / sqrt(landmark box area).
    pub tracknet_nme: f64,
    pub refined_nme: f64,
}

/// Tracks the real face crop at `path` pasted into a grey 640x480 frame (the detector,
/// like upstream's, needs context around a face) and compares the model's projected
/// landmarks with OpenSeeFace's, before and after refinement.
pub fn real_crop_agreement(
    face: Arc<FaceModel>,
    path: &Path,
    config: &TrackerConfig,
) -> Result<RealCropAgreement> {
    let crop = crate::source::read_image(path)?;
    let mut frame = image::RgbImage::from_pixel(640, 480, image::Rgb([128, 128, 128]));
    let (x0, y0) = (
        (640u32.saturating_sub(crop.width())) / 2,
        (480u32.saturating_sub(crop.height())) / 2,
    );
    image::imageops::replace(&mut frame, &crop, i64::from(x0), i64::from(y0));
    let mut cfg = config.clone();
    cfg.locator = crate::pipeline::LocatorChoice::Landmarks;
    cfg.smoothing = SmoothingConfig::off();
    let refine_config = cfg.refine.clone().unwrap_or_default();
    cfg.refine = None;
    let mut tracker = Tracker::new(face, cfg, true)?;
    let out = tracker.process(&crate::source::Frame {
        index: 0,
        time_s: 0.0,
        image: frame,
        path: None,
    });
    let observations = out.observations.clone().ok_or_else(|| {
        TrackingError::InvalidInput(format!(
            "no face found in {} ({})",
            path.display(),
            out.record.note.clone().unwrap_or_default()
        ))
    })?;
    tracker.set_refine(Some(refine_config));
    tracker.reset();
    let refined = tracker.retrack(&out, 640, 480);
    let nme = |record: &FrameRecord| -> Result<f64> {
        let t = record.track.as_ref().ok_or_else(|| {
            TrackingError::InvalidInput(record.note.clone().unwrap_or_else(|| "no face".into()))
        })?;
        let pairs: Vec<(glam::Vec2, glam::Vec2)> = observations
            .points
            .iter()
            .filter(|o| o.index < 60)
            .map(|o| (glam::Vec2::from(t.landmarks_68[o.index]), o.pixel))
            .collect();
        let bbox = crate::preprocess::Rect::bounding(pairs.iter().map(|p| p.1))
            .ok_or_else(|| TrackingError::InvalidInput("no landmarks".into()))?;
        let norm = f64::from(bbox.width * bbox.height).sqrt().max(1e-6);
        Ok(pairs
            .iter()
            .map(|(a, b)| f64::from(a.distance(*b)))
            .sum::<f64>()
            / (pairs.len().max(1) as f64 * norm))
    };
    Ok(RealCropAgreement {
        tracknet_nme: nme(&out.record)?,
        refined_nme: nme(&refined)?,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_following_finds_the_channel_and_the_blink_asymmetry_that_follow_yaw() {
        let index = |name: &str| ICT_NAMES.iter().position(|n| *n == name).unwrap_or(0);
        let (l, r, jaw) = (index("eyeBlink_L"), index("eyeBlink_R"), index("jawOpen"));
        let yaw: Vec<f64> = (0..40).map(|k| f64::from(k) - 20.0).collect();
        let predicted: Vec<[f32; NUM_BLENDSHAPES]> = yaw
            .iter()
            .enumerate()
            .map(|(k, &y)| {
                let mut w = [0.0; NUM_BLENDSHAPES];
                // Left blink rises with the yaw, right falls: their difference is yaw itself.
                w[l] = 0.5 + 0.01 * y as f32;
                w[r] = 0.5 - 0.01 * y as f32;
                // jawOpen alternates, unrelated to yaw.
                w[jaw] = (k % 2) as f32;
                w
            })
            .collect();
        let found = yaw_following(&predicted, &yaw);
        assert!(
            found.channel == l || found.channel == r,
            "{}",
            ICT_NAMES[found.channel]
        );
        assert!((found.r.abs() - 1.0).abs() < 1e-9, "{found:?}");
        assert!((found.blink_asymmetry_r - 1.0).abs() < 1e-9, "{found:?}");
        // Constant series correlate with nothing.
        assert_eq!(pearson(&[1.0, 1.0, 1.0], &[1.0, 2.0, 3.0]), 0.0);
        assert_eq!(pearson(&[], &[]), 0.0);
        assert!((pearson(&[1.0, 2.0, 3.0], &[6.0, 4.0, 2.0]) + 1.0).abs() < 1e-12);
    }

    fn frames(rows: &[[f32; 2]]) -> Vec<[f32; NUM_BLENDSHAPES]> {
        rows.iter()
            .map(|r| {
                let mut w = [0.0; NUM_BLENDSHAPES];
                w[0] = r[0];
                w[1] = r[1];
                w
            })
            .collect()
    }

    #[test]
    fn the_expression_report_by_hand() {
        // Channels 0 and 1 as in training/tests/test_metrics.py; the other 51 all zero.
        let truth = frames(&[[1.0, 0.0], [0.0, 0.0], [0.0, 0.5], [0.0, 0.0]]);
        let predicted = frames(&[[0.8, 0.2], [0.0, 0.2], [0.2, 0.3], [0.0, 0.2]]);
        let mut visible = [false; NUM_BLENDSHAPES];
        visible[0] = true;
        let r = expression_report(&predicted, &truth, &visible);
        let close = |a: f64, b: f64| (a - b).abs() < 1e-6;
        assert!(close(r.channels[0].mae, 0.1) && close(r.channels[1].mae, 0.2));
        assert!(close(r.channels[0].mae_zero, 0.25) && close(r.channels[1].mae_zero, 0.125));
        assert!(close(r.channels[0].mae_constant_mean, 0.375));
        assert!(close(r.mae_visible[0], 0.1) && close(r.mae_visible[1], 0.25));
        assert!(close(r.mae_all[0], 0.3 / NUM_BLENDSHAPES as f64));
        // Channel 0: active (> 0.3) in frame 0 on both sides: F1 1. Channel 2: never.
        assert_eq!(r.channels[0].f1, Some(1.0));
        assert_eq!(r.channels[2].f1, None);
        assert!(r.channels[0].correlation > 0.9);
        assert_eq!(r.channels[2].correlation, 0.0);
        assert!(r.table().contains("(not visible)"));
    }

    fn clip_of_seed(seed: Option<u64>, dir: &str) -> Clip {
        Clip {
            dir: PathBuf::from(dir),
            truth: ClipTruth {
                seed,
                width: 64,
                height: 64,
                focal_px: 64.0,
                fps: 30.0,
                frames: Vec::new(),
            },
            frames: Vec::new(),
        }
    }

    #[test]
    fn tuning_clips_of_the_held_out_seed_or_of_none_are_refused() {
        let held_out = [
            clip_of_seed(Some(9001), "h0"),
            clip_of_seed(Some(9001), "h1"),
        ];
        let own = [
            clip_of_seed(Some(9002), "t0"),
            clip_of_seed(Some(9002), "t1"),
        ];
        assert!(check_tuning_clips(&own, &held_out).is_ok());
        let mixed = [
            clip_of_seed(Some(9002), "t0"),
            clip_of_seed(Some(9001), "t1"),
        ];
        let e = check_tuning_clips(&mixed, &held_out).expect_err("a held-out clip among them");
        assert!(
            e.to_string().contains("t1") && e.to_string().contains("9001"),
            "{e}"
        );
        let unknown = [clip_of_seed(None, "old")];
        let e = check_tuning_clips(&unknown, &held_out).expect_err("no seed to check");
        assert!(e.to_string().contains("no recorded seed"), "{e}");
    }

    #[test]
    fn tuning_without_candidates_is_an_error_not_a_choice() {
        let template = face::template::Template::one_quad("test");
        let e = tune_refinement(
            Arc::new(FaceModel::new(template)),
            &[],
            &TrackerConfig::default(),
            &[],
        )
        .expect_err("nothing to compare");
        assert!(e.to_string().contains("no refinement settings"), "{e}");
    }

    #[test]
    fn every_ict_channel_is_visible_once_the_eyes_turn() {
        let template = face::template::Template::load_default(None).expect("the ICT template");
        let motion = channel_motion_px(&template);
        let look = face::names::ict_index("eyeLookOut_L").expect("name");
        assert!(motion.iter().all(|&px| px >= VISIBLE_MIN_PX), "{motion:?}");
        assert!(motion[look] > 2.0, "the eyeball turns: {}", motion[look]);
    }
}
