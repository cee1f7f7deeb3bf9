//! The per-frame tracker: locate the face, crop as in training, TrackNet, refine on the
//! landmarks, smooth; and personalization over a whole clip (section 3 and 4 of the paper).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use face::camera::{Intrinsics, focal_length_px};
use face::{FaceModel, NUM_LANDMARKS, PersonalizedBlendshapes};
use glam::Vec2;
use image::RgbImage;

use crate::backend::{BackendChoice, BackendKind, Tensor};
use crate::error::{Result, TrackingError};
use crate::networks::{Manifest, TrackNet, TrackNetOutput, default_networks_dir};
use crate::openseeface::{FaceFollower, OpenSeeFace, default_models_dir};
use crate::params::FaceParams;
use crate::preprocess::{Rect, sample_rect};
use crate::record::{CameraRecord, FrameRecord};
use crate::refine::{LandmarkObservations, RefineConfig, Refiner};
use crate::smooth::{FaceParamsSmoother, SmoothingConfig};
use crate::source::Frame;

/// How faces are found in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LocatorChoice {
    /// OpenSeeFace detection and landmarks when the models are there; otherwise every
    /// image is taken as a face crop (with a warning).
    #[default]
    Auto,
    /// OpenSeeFace detection and landmarks; an error without the models.
    Landmarks,
    /// Every image is already a face crop framed like the training images (synthetic
    /// renders, pre-cropped stills).
    PreCropped,
}

impl std::str::FromStr for LocatorChoice {
    type Err = TrackingError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Self::Auto),
            "landmarks" | "detect" => Ok(Self::Landmarks),
            "precropped" | "pre-cropped" | "crop" => Ok(Self::PreCropped),
            other => Err(TrackingError::InvalidInput(format!(
                "unknown face locator `{other}` (auto, landmarks or precropped)"
            ))),
        }
    }
}

/// Everything a tracker needs to know.
#[derive(Clone, Debug)]
pub struct TrackerConfig {
    pub backend: BackendChoice,
    /// Intra-op threads for ONNX Runtime.
    pub threads: usize,
    /// Folder of `manifest.json`, `track_net.onnx`, `model_net.onnx`.
    pub networks_dir: PathBuf,
    /// Folder of the OpenSeeFace models.
    pub models_dir: PathBuf,
    pub locator: LocatorChoice,
    /// Horizontal field of view of the footage camera in degrees. Default: 50 for
    /// footage; for pre-cropped input the training cameras' nominal value.
    pub fov_deg: Option<f32>,
    /// `None`: TrackNet's output as is.
    pub refine: Option<RefineConfig>,
    pub smoothing: SmoothingConfig,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            backend: BackendChoice::Auto,
            threads: 2,
            networks_dir: default_networks_dir(),
            models_dir: default_models_dir(),
            locator: LocatorChoice::Auto,
            fov_deg: None,
            refine: Some(RefineConfig::default()),
            smoothing: SmoothingConfig::default(),
        }
    }
}

/// Default horizontal field of view assumed for footage (a typical webcam or phone).
pub const DEFAULT_FOOTAGE_FOV_DEG: f32 = 50.0;

/// Milliseconds spent in each stage of one frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    pub detect_ms: f64,
    pub landmarks_ms: f64,
    pub crop_ms: f64,
    pub tracknet_ms: f64,
    pub refine_ms: f64,
    pub smooth_ms: f64,
}

/// Everything one frame produced.
#[derive(Clone, Debug)]
pub struct FrameOutput {
    pub record: FrameRecord,
    /// The network input (kept for personalization).
    pub input: Option<Tensor>,
    pub crop: Option<Rect>,
    /// TrackNet's parameters in the frame camera, before refinement and smoothing.
    pub tracknet: Option<FaceParams>,
    /// After refinement, before smoothing.
    pub refined: Option<FaceParams>,
    /// The landmark observations refinement used.
    pub observations: Option<LandmarkObservations>,
    pub confidence: f32,
    pub times: StageTimes,
}

enum Locator {
    Landmarks(Box<FaceFollower>),
    PreCropped,
}

/// Tracks frames one after another.
pub struct Tracker {
    pub manifest: Manifest,
    track_net: TrackNet,
    locator: Locator,
    face: Arc<FaceModel>,
    blendshapes: Arc<PersonalizedBlendshapes>,
    /// The landmark rows of `blendshapes`, gathered once per person.
    refiner: Refiner,
    config: TrackerConfig,
    smoother: FaceParamsSmoother,
    last_time_s: Option<f64>,
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

impl Tracker {
    /// Loads the networks and, as the locator asks, the OpenSeeFace models. `footage`
    /// says whether the input is real footage (video, camera), which cannot be tracked
    /// without face detection.
    pub fn new(face: Arc<FaceModel>, config: TrackerConfig, footage: bool) -> Result<Self> {
        let kind = config.backend.resolve()?;
        let manifest = Manifest::load(&config.networks_dir)?;
        let track_net = TrackNet::load(&manifest, kind, config.threads)?;
        let locator = match config.locator {
            LocatorChoice::PreCropped => Locator::PreCropped,
            LocatorChoice::Landmarks => Locator::Landmarks(Box::new(FaceFollower::new(
                OpenSeeFace::load(&config.models_dir, kind, config.threads)?,
            ))),
            LocatorChoice::Auto => {
                match OpenSeeFace::load(&config.models_dir, kind, config.threads) {
                    Ok(models) => Locator::Landmarks(Box::new(FaceFollower::new(models))),
                    Err(e @ TrackingError::MissingModel { .. }) if !footage => {
                        tracing::warn!(
                            "{e}; treating every image as a face crop framed like the training images"
                        );
                        Locator::PreCropped
                    }
                    Err(e) => {
                        return Err(TrackingError::InvalidInput(format!(
                            "real footage needs face detection: {e}. Pass --locator precropped if every frame is already a face crop."
                        )));
                    }
                }
            }
        };
        let blendshapes = Arc::new(face.template_blendshapes());
        let refiner = Refiner::new(&blendshapes, &face.template)?;
        let smoother = FaceParamsSmoother::new(config.smoothing.clone());
        Ok(Self {
            manifest,
            track_net,
            locator,
            face,
            blendshapes,
            refiner,
            config,
            smoother,
            last_time_s: None,
        })
    }

    pub fn backend(&self) -> BackendKind {
        self.track_net.kind()
    }

    pub fn uses_landmarks(&self) -> bool {
        matches!(self.locator, Locator::Landmarks(_))
    }

    /// Refinement uses this person's blendshapes from now on (a personalized model).
    pub fn set_blendshapes(&mut self, blendshapes: Arc<PersonalizedBlendshapes>) -> Result<()> {
        self.refiner = Refiner::new(&blendshapes, &self.face.template)?;
        self.blendshapes = blendshapes;
        Ok(())
    }

    pub fn set_refine(&mut self, refine: Option<RefineConfig>) {
        self.config.refine = refine;
    }

    pub fn set_smoothing(&mut self, smoothing: SmoothingConfig) {
        self.config.smoothing = smoothing.clone();
        self.smoother = FaceParamsSmoother::new(smoothing);
    }

    /// The frame camera for an image of this size.
    pub fn intrinsics(&self, width: u32, height: u32) -> Intrinsics {
        match self.locator {
            Locator::PreCropped => {
                // The image is the crop: the training camera, whatever the user said.
                let fov = self.config.fov_deg.unwrap_or(self.manifest.nominal_fov_deg);
                Intrinsics::centered(width, height, focal_length_px(width.min(height), fov))
            }
            Locator::Landmarks(_) => Intrinsics::from_fov(
                width,
                height,
                self.config.fov_deg.unwrap_or(DEFAULT_FOOTAGE_FOV_DEG),
            ),
        }
    }

    pub fn camera_record(&self, width: u32, height: u32) -> CameraRecord {
        let k = self.intrinsics(width, height);
        CameraRecord {
            width,
            height,
            focal_px: k.focal_px,
            cx: k.cx,
            cy: k.cy,
        }
    }

    /// Forgets the face (a new clip starts; nothing carries over).
    pub fn reset(&mut self) {
        if let Locator::Landmarks(f) = &mut self.locator {
            f.reset();
        }
        self.smoother.reset();
        self.last_time_s = None;
    }

    /// Tracks one frame. Never fails: a frame without a face, or whose networks produce
    /// NaN, is a "no face" record saying why.
    pub fn process(&mut self, frame: &Frame) -> FrameOutput {
        match self.process_inner(&frame.image, frame.index, frame.time_s) {
            Ok(out) => out,
            Err(e) => {
                self.smoother.reset();
                FrameOutput::none(FrameRecord::no_face(
                    frame.index,
                    frame.time_s,
                    Some(e.to_string()),
                ))
            }
        }
    }

    fn process_inner(
        &mut self,
        image: &RgbImage,
        index: usize,
        time_s: f64,
    ) -> Result<FrameOutput> {
        let mut times = StageTimes::default();
        crate::source::check_frame_size(image.width(), image.height())?;
        let intrinsics = self.intrinsics(image.width(), image.height());
        // 1. Where is the face?
        let (crop, observations, confidence) = match &mut self.locator {
            Locator::PreCropped => {
                let side = image.width().min(image.height()) as f32;
                let centre = Vec2::new(image.width() as f32, image.height() as f32) * 0.5;
                (Rect::square(centre, side), None, 1.0)
            }
            Locator::Landmarks(follower) => {
                let Some(found) = follower.step(image)? else {
                    self.smoother.reset();
                    return Ok(FrameOutput::none(FrameRecord::no_face(index, time_s, None)));
                };
                times.detect_ms = found.detect_ms;
                times.landmarks_ms = found.landmarks_ms;
                let ibug = found.landmarks.to_ibug68();
                let points: Vec<Vec2> = ibug
                    .iter()
                    .take(crate::preprocess::CROP_LANDMARKS)
                    .filter_map(|p| p.map(|(p, _)| p))
                    .collect();
                let crop = self.manifest.crop.crop_for_landmarks(&points)?;
                let observations = LandmarkObservations::from_ibug68(&ibug);
                (crop, Some(observations), found.landmarks.mean_confidence)
            }
        };
        // 2. The crop, as in training.
        let t = Instant::now();
        let s = self.manifest.input_size;
        let input = sample_rect(image, crop, s, s, self.manifest.normalisation)?;
        times.crop_ms = ms(t);
        // 3. TrackNet.
        let t = Instant::now();
        let output: TrackNetOutput =
            self.track_net
                .run(&input)?
                .into_iter()
                .next()
                .ok_or_else(|| TrackingError::BadOutput {
                    model: "track_net".into(),
                    reason: "no output for the image".into(),
                })??;
        times.tracknet_ms = ms(t);
        let tracknet = output.to_frame(&self.manifest, &crop, &intrinsics);
        let (refined, record) = self.refine_and_smooth(
            index,
            time_s,
            &tracknet,
            observations.as_ref(),
            &intrinsics,
            confidence,
            &mut times,
        )?;
        Ok(FrameOutput {
            record,
            input: Some(input),
            crop: Some(crop),
            tracknet: Some(tracknet),
            refined: Some(refined),
            observations,
            confidence,
            times,
        })
    }

    /// Refines and smooths a frame again from its TrackNet output and landmarks, with the
    /// current blendshapes (after personalization); frames must come in time order after a
    /// [`Tracker::reset`].
    pub fn retrack(&mut self, out: &FrameOutput, width: u32, height: u32) -> FrameRecord {
        let (index, time_s) = (out.record.index, out.record.time_s);
        let Some(tracknet) = out.tracknet else {
            self.smoother.reset();
            return out.record.clone();
        };
        let intrinsics = self.intrinsics(width, height);
        let mut times = StageTimes::default();
        match self.refine_and_smooth(
            index,
            time_s,
            &tracknet,
            out.observations.as_ref(),
            &intrinsics,
            out.confidence,
            &mut times,
        ) {
            Ok((_, record)) => record,
            Err(e) => {
                self.smoother.reset();
                FrameRecord::no_face(index, time_s, Some(e.to_string()))
            }
        }
    }

    /// Steps 4 and 5 of a frame: refinement on the detected landmarks (when configured and
    /// observed), then smoothing (a jump back in time starts a new sequence), then the
    /// record. Returns the refined (unsmoothed) parameters too.
    #[allow(clippy::too_many_arguments)]
    fn refine_and_smooth(
        &mut self,
        index: usize,
        time_s: f64,
        tracknet: &FaceParams,
        observations: Option<&LandmarkObservations>,
        intrinsics: &Intrinsics,
        confidence: f32,
        times: &mut StageTimes,
    ) -> Result<(FaceParams, FrameRecord)> {
        let t = Instant::now();
        let refined = match (&self.config.refine, observations) {
            (Some(config), Some(obs)) => {
                self.refiner
                    .refine(intrinsics, tracknet, obs, config)?
                    .params
            }
            _ => *tracknet,
        };
        times.refine_ms = ms(t);
        if !refined.is_finite() {
            return Err(TrackingError::NonFinite {
                model: "refinement".into(),
                output: "parameters".into(),
            });
        }
        let t = Instant::now();
        if self.last_time_s.is_some_and(|last| time_s <= last) {
            self.smoother.reset();
        }
        self.last_time_s = Some(time_s);
        let smoothed = self.smoother.filter(time_s, &refined);
        times.smooth_ms = ms(t);
        let landmarks = self.project_landmarks(&smoothed, intrinsics);
        if landmarks.iter().any(|p| !p.is_finite()) {
            return Err(TrackingError::NonFinite {
                model: "tracking".into(),
                output: "landmarks (the face is behind the camera)".into(),
            });
        }
        let record = FrameRecord::with_face(index, time_s, &smoothed, &landmarks, confidence);
        Ok((refined, record))
    }

    /// The model's 68 landmarks under `params`, in frame pixels.
    pub fn project_landmarks(
        &self,
        params: &FaceParams,
        intrinsics: &Intrinsics,
    ) -> [Vec2; NUM_LANDMARKS] {
        let points = self
            .blendshapes
            .landmarks(&self.face.template, &params.blendshape_weights());
        points.map(|p| {
            intrinsics
                .project(params.pose.transform(p))
                .unwrap_or(Vec2::NAN)
        })
    }
}

impl FrameOutput {
    pub fn none(record: FrameRecord) -> Self {
        Self {
            record,
            input: None,
            crop: None,
            tracknet: None,
            refined: None,
            observations: None,
            confidence: 0.0,
            times: StageTimes::default(),
        }
    }
}
