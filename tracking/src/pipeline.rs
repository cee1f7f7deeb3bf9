//! The per-frame tracker: locate the face, crop as in training, TrackNet, refine on the
//! landmarks, smooth; and personalization over a whole clip (section 3 and 4 of the paper).

use std::ops::ControlFlow;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc;
use web_time::Instant;

use face::camera::{Intrinsics, focal_length_px};
use face::{FaceModel, NUM_LANDMARKS, PersonalizedBlendshapes};
use glam::Vec2;
use image::RgbImage;

use crate::backend::{BackendChoice, BackendKind, Tensor};
use crate::error::{Result, TrackingError};
use crate::mediapipe::{IctCorrespondence, MediaPipe, MeshFollower};
use crate::networks::{Manifest, TrackNet, TrackNetOutput, default_networks_dir};
use crate::openseeface::{FaceFollower, OpenSeeFace, default_models_dir};
use crate::params::FaceParams;
use crate::preprocess::{Rect, sample_rect};
use crate::record::{CameraRecord, FrameRecord};
use crate::refine::{FitPoints, LandmarkObservations, RefineConfig, Refiner};
use crate::smooth::{FaceParamsSmoother, SmoothingConfig};
use crate::source::{Frame, FrameError, FrameSource, Next};

/// How faces are found in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LocatorChoice {
    /// OpenSeeFace detection and landmarks. Without the models (a missing, mistyped or
    /// broken `models_dir`) an error, unless the caller says the input is not footage
    /// ([`Tracker::new`]'s `footage`), when every image is taken as a face crop with a
    /// warning. The CLI always treats its input as footage.
    #[default]
    Auto,
    /// OpenSeeFace detection and landmarks; an error without the models.
    Landmarks,
    /// MediaPipe's BlazeFace and 468-point Face Mesh ([`crate::mediapipe`]), handing on
    /// the iBUG 68 subset of its points; an error without the models.
    MediaPipe,
    /// Every image is already a face crop framed like the training images (synthetic
    /// renders, pre-cropped stills).
    PreCropped,
}

impl std::str::FromStr for LocatorChoice {
    type Err = TrackingError;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "auto" => Ok(Self::Auto),
            "landmarks" | "detect" | "openseeface" => Ok(Self::Landmarks),
            "mediapipe" | "mesh" => Ok(Self::MediaPipe),
            "precropped" | "pre-cropped" | "crop" => Ok(Self::PreCropped),
            other => Err(TrackingError::InvalidInput(format!(
                "unknown face locator `{other}` (auto, openseeface, mediapipe or precropped)"
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
    /// Folder of MediaPipe's models ([`LocatorChoice::MediaPipe`]).
    pub mediapipe_dir: PathBuf,
    /// With [`LocatorChoice::MediaPipe`]: refinement fits all 468 Face Mesh points through
    /// their ICT correspondence (`true`) or the 68 handed on as iBUG landmarks (`false`).
    pub dense_fit: bool,
    pub locator: LocatorChoice,
    /// Horizontal field of view of the footage camera in degrees. Default: 50 for
    /// footage; for pre-cropped input the training cameras' nominal value.
    pub fov_deg: Option<f32>,
    /// `None`: TrackNet's output as is.
    pub refine: Option<RefineConfig>,
    pub smoothing: SmoothingConfig,
    /// Whether the footage locators search with RetinaFace when their fast detector finds
    /// no face (ONNX Runtime only; its file missing is a warning, not an error).
    pub fallback_detector: bool,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            backend: BackendChoice::Auto,
            threads: 2,
            networks_dir: default_networks_dir(),
            models_dir: default_models_dir(),
            mediapipe_dir: crate::mediapipe::default_models_dir(),
            dense_fit: true,
            locator: LocatorChoice::Auto,
            fov_deg: None,
            refine: Some(RefineConfig::default()),
            smoothing: SmoothingConfig::default(),
            fallback_detector: true,
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
    /// ModelNet's input for this frame (`Manifest::input_size`), kept for personalization.
    pub input: Option<Tensor>,
    pub crop: Option<Rect>,
    /// TrackNet's parameters in the frame camera, before refinement and smoothing.
    pub tracknet: Option<FaceParams>,
    /// After refinement, before smoothing.
    pub refined: Option<FaceParams>,
    /// The landmark observations refinement used (the 68 iBUG points).
    pub observations: Option<LandmarkObservations>,
    /// A dense detector's points (indices into Face Mesh's 468), which refinement fits
    /// instead of `observations` when the tracker has their correspondence.
    pub dense_observations: Option<LandmarkObservations>,
    pub confidence: f32,
    pub times: StageTimes,
}

/// A face locator for footage, its networks already loaded ([`Tracker::from_parts`]).
pub enum FootageLocator {
    /// OpenSeeFace's detector and 66 landmarks.
    OpenSeeFace(Box<FaceFollower>),
    /// MediaPipe's BlazeFace and Face Mesh; `dense`: the points refinement fits instead of
    /// the 68 (all 468 through the ICT correspondence), or `None` to fit the 68.
    MediaPipe {
        follower: Box<MeshFollower>,
        dense: Option<FitPoints>,
    },
}

enum Locator {
    Landmarks(Box<FaceFollower>),
    Mesh(Box<MeshFollower>),
    PreCropped,
}

/// Where the face is in one frame, as the locating stage hands it on to the rest of the
/// tracker ([`Tracker::process_located`]). It crosses threads, and in the browser a Web
/// Worker's message, so it has a flat form ([`LocatedFace::to_f32s`]).
#[derive(Clone, Debug, PartialEq)]
pub struct LocatedFace {
    /// The detected landmarks in iBUG order; `None` for a pre-cropped image.
    ibug68: Option<Box<Ibug68>>,
    /// A dense detector's points (Face Mesh's 468) with their confidence, which
    /// refinement fits through the template correspondence when the tracker has it.
    dense: Option<Vec<(Vec2, f32)>>,
    confidence: f32,
    detect_ms: f64,
    landmarks_ms: f64,
}

/// The iBUG landmarks with their confidence, `None` where one was not found.
type Ibug68 = [Option<(Vec2, f32)>; crate::openseeface::IBUG_LANDMARK_COUNT];

/// Length of [`LocatedFace::to_f32s`]: a header of four numbers, then x, y and confidence
/// of each iBUG landmark, then of each dense point (NaN when there are none).
pub const LOCATED_FACE_F32S: usize =
    4 + 3 * crate::openseeface::IBUG_LANDMARK_COUNT + 3 * crate::mediapipe::MESH_POINTS;

/// Where the dense points start in [`LocatedFace::to_f32s`].
const DENSE_START: usize = 4 + 3 * crate::openseeface::IBUG_LANDMARK_COUNT;

impl LocatedFace {
    /// The face [`FaceFollower::step`] found in the next frame of a video, or `None`.
    pub fn follow(follower: &mut FaceFollower, image: &RgbImage) -> Result<Option<Self>> {
        Ok(follower.step(image)?.map(|found| Self {
            ibug68: Some(Box::new(found.landmarks.to_ibug68())),
            dense: None,
            confidence: found.landmarks.mean_confidence,
            detect_ms: found.detect_ms,
            landmarks_ms: found.landmarks_ms,
        }))
    }

    /// The face [`MeshFollower::step`] found in the next frame of a video, or `None`.
    pub fn follow_mesh(follower: &mut MeshFollower, image: &RgbImage) -> Result<Option<Self>> {
        Ok(follower.step(image)?.map(|found| Self {
            ibug68: Some(Box::new(found.mesh.to_ibug68(follower.ibug68()))),
            dense: Some(
                found
                    .mesh
                    .points_2d()
                    .map(|p| (p, found.mesh.presence))
                    .collect(),
            ),
            confidence: found.mesh.presence,
            detect_ms: found.detect_ms,
            landmarks_ms: found.mesh_ms,
        }))
    }

    fn pre_cropped() -> Self {
        Self {
            ibug68: None,
            dense: None,
            confidence: 1.0,
            detect_ms: 0.0,
            landmarks_ms: 0.0,
        }
    }

    /// The flat form: `[has landmarks (0 or 1), confidence, detect ms, landmark ms]`, then
    /// `x, y, confidence` per iBUG landmark, NaN for a landmark that was not found.
    pub fn to_f32s(&self) -> Vec<f32> {
        let mut out = Vec::with_capacity(LOCATED_FACE_F32S);
        out.extend([
            if self.ibug68.is_some() { 1.0 } else { 0.0 },
            self.confidence,
            self.detect_ms as f32,
            self.landmarks_ms as f32,
        ]);
        for point in self.ibug68.iter().flat_map(|points| points.iter()) {
            match point {
                Some((p, c)) => out.extend([p.x, p.y, *c]),
                None => out.extend([f32::NAN; 3]),
            }
        }
        out.resize(DENSE_START, f32::NAN);
        for (p, c) in self.dense.iter().flat_map(|points| points.iter()) {
            out.extend([p.x, p.y, *c]);
        }
        out.resize(LOCATED_FACE_F32S, f32::NAN);
        out
    }

    /// Reads [`LocatedFace::to_f32s`]'s form back; an error for any other length, or for
    /// values no locator produces (a header that is not finite, a half-missing landmark).
    pub fn from_f32s(values: &[f32]) -> Result<Self> {
        let bad = |reason: String| TrackingError::InvalidInput(format!("located face: {reason}"));
        if values.len() != LOCATED_FACE_F32S {
            return Err(bad(format!(
                "{} numbers, expected {LOCATED_FACE_F32S}",
                values.len()
            )));
        }
        let (header, rest) = values.split_at(4);
        let (points, dense_values) = rest.split_at(DENSE_START - 4);
        if header.iter().any(|v| !v.is_finite()) || !(header[0] == 0.0 || header[0] == 1.0) {
            return Err(bad(format!("header {header:?}")));
        }
        let ibug68 = if header[0] == 1.0 {
            let mut ibug = Box::new([None; crate::openseeface::IBUG_LANDMARK_COUNT]);
            for (k, (slot, xyc)) in ibug.iter_mut().zip(points.chunks_exact(3)).enumerate() {
                *slot = match xyc.iter().filter(|v| v.is_finite()).count() {
                    3 => Some((Vec2::new(xyc[0], xyc[1]), xyc[2])),
                    0 => None,
                    _ => return Err(bad(format!("landmark {k} is {xyc:?}"))),
                };
            }
            Some(ibug)
        } else {
            None
        };
        let found = dense_values
            .chunks_exact(3)
            .filter(|xyc| xyc.iter().all(|v| v.is_finite()))
            .count();
        let dense = match found {
            0 if dense_values.iter().all(|v| v.is_nan()) => None,
            crate::mediapipe::MESH_POINTS => Some(
                dense_values
                    .chunks_exact(3)
                    .map(|xyc| (Vec2::new(xyc[0], xyc[1]), xyc[2]))
                    .collect(),
            ),
            _ => {
                return Err(bad(format!(
                    "{found} of the {} dense points are finite",
                    crate::mediapipe::MESH_POINTS
                )));
            }
        };
        Ok(Self {
            ibug68,
            dense,
            confidence: header[1],
            detect_ms: f64::from(header[2]),
            landmarks_ms: f64::from(header[3]),
        })
    }
}

impl Locator {
    /// `None`: the frame shows no face.
    fn locate(&mut self, image: &RgbImage) -> Result<Option<LocatedFace>> {
        match self {
            Locator::PreCropped => Ok(Some(LocatedFace::pre_cropped())),
            Locator::Landmarks(follower) => LocatedFace::follow(follower, image),
            Locator::Mesh(follower) => LocatedFace::follow_mesh(follower, image),
        }
    }

    /// What "no face" means for this locator, with its thresholds.
    fn no_face_note(&self) -> String {
        match self {
            Locator::Landmarks(f) => format!(
                "no face found: OpenSeeFace's detector found none at confidence >= {} (and a \
                 face followed from the previous frame, if any, was lost: its landmarks' mean \
                 confidence fell below {}); {}",
                f.tracker().detection_threshold(),
                f.min_landmark_confidence(),
                if f.has_fallback() {
                    "RetinaFace, searching when it finds none (at most every 15 frames \
                     after a miss), found none either; a face smaller than about a twelfth of \
                     the frame's height or turned past profile can be missed (--locator \
                     mediapipe also searches tiles of the frame for small faces)"
                } else {
                    "without the fallback detector (RetinaFace: ONNX Runtime and \
                     retinaface_640x640_opt.onnx beside the OpenSeeFace models), a face much \
                     smaller than a tenth of the frame, turned past profile or filling the \
                     whole frame can be missed (--locator mediapipe finds close-ups)"
                }
            ),
            Locator::Mesh(f) => format!(
                "no face found: MediaPipe's BlazeFace found none scoring >= {} (and a face \
                 followed from the previous frame, if any, was lost: Face Mesh's presence fell \
                 below {}); {}BlazeFace on tiles of the frame found none either (at most every \
                 15 frames after a miss), so the face, if any, is smaller than about a \
                 fifteenth of the frame's short side or turned past profile",
                f.located().min_detection_score(),
                f.min_presence(),
                if f.has_fallback() {
                    "RetinaFace and "
                } else {
                    ""
                }
            ),
            Locator::PreCropped => "no face: the image is taken as a face crop".into(),
        }
    }

    fn reset(&mut self) {
        match self {
            Locator::Landmarks(f) => f.reset(),
            Locator::Mesh(f) => f.reset(),
            Locator::PreCropped => {}
        }
    }
}

/// What the locating stage of [`Tracker::track_source`] sends on.
enum Staged {
    Frame(Frame, Result<Option<LocatedFace>>),
    Skipped(FrameError),
    Broken(TrackingError),
}

/// Frames decoded and located ahead of the frame being finished: one keeps both stages
/// busy; more would only add latency.
const PIPELINE_DEPTH: usize = 1;

/// One step of [`Tracker::track_source`].
pub enum TrackEvent {
    /// A decoded frame and what tracking made of it.
    Frame(Frame, Box<FrameOutput>),
    /// A frame that could not be decoded (the footage goes on).
    Skipped(FrameError),
}

/// Tracks frames one after another.
pub struct Tracker {
    pub manifest: Manifest,
    track_net: TrackNet,
    locator: Locator,
    /// Whether faces are found by landmarks in footage (so the frame camera is the
    /// footage's), kept apart from `locator` because that is lent to a worker thread in
    /// [`Tracker::track_source`].
    footage_camera: bool,
    /// Why a frame has no face, for its record (issue 32: every `"face": false` says why);
    /// worded for the locator this tracker was built with.
    no_face_note: String,
    face: Arc<FaceModel>,
    blendshapes: Arc<PersonalizedBlendshapes>,
    /// The landmark rows of `blendshapes`, gathered once per person.
    refiner: Refiner,
    /// The rows of a dense detector's points (Face Mesh's through the ICT correspondence),
    /// with the points they were gathered for.
    dense: Option<(FitPoints, Refiner)>,
    config: TrackerConfig,
    smoother: FaceParamsSmoother,
    last_time_s: Option<f64>,
}

/// `follower` with RetinaFace as its fallback detector when the config asks for one and it
/// can run: on ONNX Runtime, from the OpenSeeFace model folder. Without it the follower
/// still works (its fast detector alone), so a missing or damaged file is a warning.
fn with_fallback<F>(
    follower: F,
    config: &TrackerConfig,
    kind: BackendKind,
    attach: impl FnOnce(F, crate::retinaface::RetinaFace) -> F,
) -> F {
    if !config.fallback_detector {
        return follower;
    }
    if kind != BackendKind::OnnxRuntime {
        tracing::info!(
            "no fallback face detector on {kind:?}: RetinaFace runs on ONNX Runtime only"
        );
        return follower;
    }
    match crate::retinaface::RetinaFace::load(&config.models_dir, config.threads) {
        Ok(detector) => attach(follower, detector),
        Err(e) => {
            tracing::warn!("no fallback face detector: {e}");
            follower
        }
    }
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

impl Tracker {
    /// Loads the networks and, as the locator asks, the OpenSeeFace models. `footage`
    /// says whether the input may be real footage (any image of a person, a video, a
    /// camera), which cannot be tracked without face detection: `Auto` then refuses to
    /// fall back to pre-cropped input when the models cannot be loaded. Only input known
    /// to be face crops (synthetic renders) should pass `false`.
    pub fn new(face: Arc<FaceModel>, config: TrackerConfig, footage: bool) -> Result<Self> {
        let kind = config.backend.resolve()?;
        let manifest = Manifest::load(&config.networks_dir)?;
        let track_net = TrackNet::load(&manifest, kind, config.threads)?;
        let mut dense_points = None;
        let locator = match config.locator {
            LocatorChoice::PreCropped => Locator::PreCropped,
            LocatorChoice::Landmarks => Locator::Landmarks(Box::new(with_fallback(
                FaceFollower::new(OpenSeeFace::load(&config.models_dir, kind, config.threads)?),
                &config,
                kind,
                FaceFollower::with_fallback,
            ))),
            LocatorChoice::MediaPipe => {
                // The points over the template's own landmark vertices, not the common
                // subset: 3.59 against 4.13 % NME on the held-out clips (tracking/README.md).
                let correspondence = IctCorrespondence::load(&config.mediapipe_dir)?;
                let points = correspondence.ibug68_points(&face.template)?;
                if config.dense_fit {
                    dense_points = Some(correspondence.fit_points());
                }
                Locator::Mesh(Box::new(with_fallback(
                    MeshFollower::new(
                        MediaPipe::load(&config.mediapipe_dir, kind, config.threads)?,
                        points,
                    ),
                    &config,
                    kind,
                    MeshFollower::with_fallback,
                )))
            }
            LocatorChoice::Auto => {
                match OpenSeeFace::load(&config.models_dir, kind, config.threads) {
                    Ok(models) => Locator::Landmarks(Box::new(with_fallback(
                        FaceFollower::new(models),
                        &config,
                        kind,
                        FaceFollower::with_fallback,
                    ))),
                    Err(e @ TrackingError::MissingModel { .. }) if !footage => {
                        tracing::warn!(
                            "{e}; treating every image as a face crop framed like the training images"
                        );
                        Locator::PreCropped
                    }
                    Err(e) => {
                        return Err(TrackingError::InvalidInput(format!(
                            "real footage needs face detection, and the OpenSeeFace models \
                             were looked for in {}: {e}. Without them no face is found, so \
                             nothing is tracked rather than taking the whole frame as the \
                             face; if every frame is already a face crop framed like the \
                             training images, say so with --locator precropped.",
                            config.models_dir.display()
                        )));
                    }
                }
            }
        };
        Self::assemble(face, config, manifest, track_net, locator, dense_points)
    }

    /// A tracker from networks already loaded (the browser reads them from fetched bytes):
    /// `locator` finds the face in footage; without it every image is taken as a face
    /// crop framed like the training images.
    pub fn from_parts(
        face: Arc<FaceModel>,
        config: TrackerConfig,
        manifest: Manifest,
        track_net: TrackNet,
        locator: Option<FootageLocator>,
    ) -> Result<Self> {
        let (locator, dense_points) = match locator {
            Some(FootageLocator::OpenSeeFace(follower)) => (Locator::Landmarks(follower), None),
            Some(FootageLocator::MediaPipe { follower, dense }) => (Locator::Mesh(follower), dense),
            None => (Locator::PreCropped, None),
        };
        Self::assemble(face, config, manifest, track_net, locator, dense_points)
    }

    fn assemble(
        face: Arc<FaceModel>,
        config: TrackerConfig,
        manifest: Manifest,
        track_net: TrackNet,
        locator: Locator,
        dense_points: Option<FitPoints>,
    ) -> Result<Self> {
        let blendshapes = Arc::new(face.template_blendshapes());
        let refiner = Refiner::new(&blendshapes, &face.template)?;
        let dense = match dense_points {
            Some(points) => {
                let refiner = Refiner::with_points(&blendshapes, &points)?;
                Some((points, refiner))
            }
            None => None,
        };
        let smoother = FaceParamsSmoother::new(config.smoothing.clone());
        Ok(Self {
            manifest,
            track_net,
            footage_camera: !matches!(locator, Locator::PreCropped),
            no_face_note: locator.no_face_note(),
            locator,
            face,
            blendshapes,
            refiner,
            dense,
            config,
            smoother,
            last_time_s: None,
        })
    }

    pub fn backend(&self) -> BackendKind {
        self.track_net.kind()
    }

    pub fn uses_landmarks(&self) -> bool {
        self.footage_camera
    }

    /// What finds the face: "openseeface", "mediapipe" or "precropped" (the tracking
    /// JSON's settings). Asked while [`Tracker::track_source`] runs, it names the locator
    /// lent to its worker as "precropped"; ask before or after.
    pub fn locator_name(&self) -> &'static str {
        match self.locator {
            Locator::Landmarks(_) => "openseeface",
            Locator::Mesh(_) => "mediapipe",
            Locator::PreCropped => "precropped",
        }
    }

    /// Refinement uses this person's blendshapes from now on (a personalized model).
    pub fn set_blendshapes(&mut self, blendshapes: Arc<PersonalizedBlendshapes>) -> Result<()> {
        self.refiner = Refiner::new(&blendshapes, &self.face.template)?;
        if let Some((points, refiner)) = &mut self.dense {
            *refiner = Refiner::with_points(&blendshapes, points)?;
        }
        self.blendshapes = blendshapes;
        Ok(())
    }

    /// Fits the person's identity to a whole tracked clip (`outputs` of this tracker, frames
    /// of `width` x `height`) and uses it from now on ([`crate::identity`]): each round
    /// refines every frame on the current model (the configured refinement, or the
    /// default), then fits the identity to all of them with those poses and weights held.
    /// The identity goes on top of the blendshapes in use when called (the template, or
    /// ModelNet's person). Fits Face Mesh's points where the tracker fits them, else the 68.
    pub fn fit_identity(
        &mut self,
        outputs: &[FrameOutput],
        width: u32,
        height: u32,
        config: &crate::identity::IdentityConfig,
    ) -> Result<crate::identity::IdentityFit> {
        config.validate(self.face.template.identity_count)?;
        let refine = self.config.refine.clone().unwrap_or_default();
        let intrinsics = self.intrinsics(width, height);
        let start = self.blendshapes.clone();
        let points = match &self.dense {
            Some((points, _)) => points.clone(),
            None => FitPoints::ibug68(&self.face.template),
        };
        let start_refiner = Refiner::with_points(&start, &points)?;
        let mut coefficients: Vec<f32> = Vec::new();
        let mut fit = None;
        for _ in 0..config.rounds {
            let mut frames = Vec::new();
            for out in outputs {
                let Some(tracknet) = out.tracknet.as_ref() else {
                    continue;
                };
                let (refiner, observations) = match (&self.dense, &out.dense_observations) {
                    (Some((_, dense)), Some(obs)) => (dense, obs),
                    (Some(_), None) => continue,
                    (None, _) => match &out.observations {
                        Some(obs) => (&self.refiner, obs),
                        None => continue,
                    },
                };
                // A frame refinement refuses (a point behind the camera) is left out of the
                // fit, as it is out of the tracking.
                let params = match refiner.refine(&intrinsics, tracknet, observations, &refine) {
                    Ok(refined) => refined.params,
                    Err(e) => {
                        tracing::debug!(
                            "frame {} left out of the identity fit: {e}",
                            out.record.index
                        );
                        continue;
                    }
                };
                frames.push(crate::identity::ClipFrame {
                    params,
                    observations,
                });
            }
            let this = crate::identity::fit_identity(
                &self.face.template,
                &start_refiner,
                &intrinsics,
                &frames,
                &refine,
                config,
                &coefficients,
            )?;
            coefficients = this.coefficients.clone();
            let person =
                crate::identity::with_identity(&self.face.template, &start, &coefficients)?;
            self.set_blendshapes(Arc::new(person))?;
            fit = Some(this);
        }
        fit.ok_or_else(|| TrackingError::InvalidInput("no identity fit round ran".into()))
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
        if self.footage_camera {
            Intrinsics::from_fov(
                width,
                height,
                self.config.fov_deg.unwrap_or(DEFAULT_FOOTAGE_FOV_DEG),
            )
        } else {
            // The image is the crop: the training camera, whatever the user said.
            let fov = self.config.fov_deg.unwrap_or(self.manifest.nominal_fov_deg);
            Intrinsics::centered(width, height, focal_length_px(width.min(height), fov))
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
        self.locator.reset();
        self.smoother.reset();
        self.last_time_s = None;
    }

    /// Tracks one frame. Never fails: a frame without a face, or whose networks produce
    /// NaN, is a "no face" record saying why.
    pub fn process(&mut self, frame: &Frame) -> FrameOutput {
        let (width, height) = frame.image.dimensions();
        let located = crate::source::check_frame_size(width, height)
            .and_then(|()| self.locator.locate(&frame.image));
        self.process_located(frame, located)
    }

    /// Tracks one frame whose face was located elsewhere (another thread, the browser's
    /// Web Worker) by [`LocatedFace::follow`] with this tracker's OpenSeeFace models: the
    /// same output as [`Tracker::process`] given the same locating, so that stage can run
    /// beside this one. Frames must come in order; `located` is that stage's result for
    /// `frame`. Never fails, as [`Tracker::process`].
    pub fn process_located(
        &mut self,
        frame: &Frame,
        located: Result<Option<LocatedFace>>,
    ) -> FrameOutput {
        let image = &frame.image;
        // Checked again: `located` may come from a thread that did not check.
        let output = crate::source::check_frame_size(image.width(), image.height())
            .and(located)
            .and_then(|located| self.finish(image, frame.index, frame.time_s, located));
        output.unwrap_or_else(|e| {
            self.smoother.reset();
            FrameOutput::none(FrameRecord::no_face(
                frame.index,
                frame.time_s,
                Some(e.to_string()),
            ))
        })
    }

    /// Everything after locating the face: crop, TrackNet, refinement, smoothing.
    fn finish(
        &mut self,
        image: &RgbImage,
        index: usize,
        time_s: f64,
        located: Option<LocatedFace>,
    ) -> Result<FrameOutput> {
        let Some(located) = located else {
            self.smoother.reset();
            return Ok(FrameOutput::none(FrameRecord::no_face(
                index,
                time_s,
                Some(self.no_face_note.clone()),
            )));
        };
        let mut times = StageTimes {
            detect_ms: located.detect_ms,
            landmarks_ms: located.landmarks_ms,
            ..StageTimes::default()
        };
        let intrinsics = self.intrinsics(image.width(), image.height());
        let (crop, observations, confidence) = match located.ibug68 {
            None => {
                let side = image.width().min(image.height()) as f32;
                let centre = Vec2::new(image.width() as f32, image.height() as f32) * 0.5;
                (Rect::square(centre, side), None, 1.0)
            }
            Some(ibug) => {
                let points: Vec<Vec2> = ibug
                    .iter()
                    .take(crate::preprocess::CROP_LANDMARKS)
                    .filter_map(|p| p.map(|(p, _)| p))
                    .collect();
                let crop = self.manifest.crop.crop_for_landmarks(&points)?;
                let observations = LandmarkObservations::from_ibug68(&ibug);
                (crop, Some(observations), located.confidence)
            }
        };
        let dense_observations = match (&self.dense, located.dense) {
            (Some(_), Some(points)) => {
                let mut observations = LandmarkObservations::new();
                for (k, (p, c)) in points.iter().enumerate() {
                    observations.push(k, *p, *c);
                }
                Some(observations)
            }
            _ => None,
        };
        // The crop, as in training, at TrackNet's size and (kept for personalization) at
        // ModelNet's: both sampled from the frame with the training code's box prefilter,
        // so ModelNet sees what it would have seen beside a TrackNet of its own size.
        let t = Instant::now();
        let s = self.manifest.track_input_size;
        let input = sample_rect(image, crop, s, s, self.manifest.normalisation)?;
        let m = self.manifest.input_size;
        let model_input = if m == s {
            None
        } else {
            Some(sample_rect(image, crop, m, m, self.manifest.normalisation)?)
        };
        times.crop_ms = ms(t);
        // TrackNet.
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
            (observations.as_ref(), dense_observations.as_ref()),
            &intrinsics,
            confidence,
            &mut times,
        )?;
        Ok(FrameOutput {
            record,
            input: Some(model_input.unwrap_or(input)),
            crop: Some(crop),
            tracknet: Some(tracknet),
            refined: Some(refined),
            observations,
            dense_observations,
            confidence,
            times,
        })
    }

    /// Tracks a whole source in a two-stage pipeline: one thread decodes frames and
    /// locates the face (detector, landmarks) while this one crops, runs TrackNet, refines
    /// and smooths the frame before. On two cores this overlaps the landmark network with
    /// TrackNet, so frames come out at the pace of the slower stage rather than of both
    /// added up; the results are the same as calling [`Tracker::process`] frame by frame
    /// (each stage keeps its own order).
    ///
    /// `on_event` sees every frame in order, and returns [`ControlFlow::Break`] to stop
    /// early (Ctrl-C, a frame limit). A frame whose size differs from the one before starts
    /// a new sequence (a folder of mixed images). Returns the source's error if the
    /// footage broke off; what was delivered before stays delivered.
    pub fn track_source(
        &mut self,
        source: &mut dyn FrameSource,
        mut on_event: impl FnMut(TrackEvent) -> ControlFlow<()>,
    ) -> Result<()> {
        self.reset();
        // The locator moves to the worker thread for the length of the call.
        let mut locator = std::mem::replace(&mut self.locator, Locator::PreCropped);
        let (sender, receiver) = mpsc::sync_channel::<Staged>(PIPELINE_DEPTH);
        let result = std::thread::scope(|scope| {
            let locator = &mut locator;
            scope.spawn(move || {
                let mut size = None;
                loop {
                    let item = match source.next_frame() {
                        Ok(Next::End) => break,
                        Ok(Next::Skipped(skip)) => Staged::Skipped(skip),
                        Ok(Next::Frame(frame)) => {
                            let dims = frame.image.dimensions();
                            if size.is_some_and(|s| s != dims) {
                                locator.reset();
                            }
                            size = Some(dims);
                            let located = crate::source::check_frame_size(dims.0, dims.1)
                                .and_then(|()| locator.locate(&frame.image));
                            Staged::Frame(frame, located)
                        }
                        Err(e) => {
                            let _ = sender.send(Staged::Broken(e));
                            break;
                        }
                    };
                    // The receiver is gone when the caller stopped: so does this stage.
                    if sender.send(item).is_err() {
                        break;
                    }
                }
            });
            let mut size = None;
            while let Ok(item) = receiver.recv() {
                let flow = match item {
                    // The smoothing filters go on over the gap (they know the times).
                    Staged::Skipped(skip) => on_event(TrackEvent::Skipped(skip)),
                    Staged::Frame(frame, located) => {
                        let dims = frame.image.dimensions();
                        if size.is_some_and(|s| s != dims) {
                            self.smoother.reset();
                            self.last_time_s = None;
                        }
                        size = Some(dims);
                        let output = self.process_located(&frame, located);
                        on_event(TrackEvent::Frame(frame, Box::new(output)))
                    }
                    Staged::Broken(e) => return Err(e),
                };
                if flow.is_break() {
                    break;
                }
            }
            drop(receiver);
            Ok(())
        });
        self.locator = locator;
        result
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
            (out.observations.as_ref(), out.dense_observations.as_ref()),
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
        (observations, dense_observations): (
            Option<&LandmarkObservations>,
            Option<&LandmarkObservations>,
        ),
        intrinsics: &Intrinsics,
        confidence: f32,
        times: &mut StageTimes,
    ) -> Result<(FaceParams, FrameRecord)> {
        let t = Instant::now();
        let refined = match (
            &self.config.refine,
            &self.dense,
            dense_observations,
            observations,
        ) {
            (Some(config), Some((_, dense)), Some(obs), _) => {
                dense.refine(intrinsics, tracknet, obs, config)?.params
            }
            (Some(config), _, _, Some(obs)) => {
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
            dense_observations: None,
            confidence: 0.0,
            times: StageTimes::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn some_face() -> LocatedFace {
        let mut ibug = [None; crate::openseeface::IBUG_LANDMARK_COUNT];
        for (k, slot) in ibug.iter_mut().enumerate() {
            // Landmark 30 was not found.
            if k != 30 {
                *slot = Some((Vec2::new(100.0 + k as f32 * 1.5, 200.25 - k as f32), 0.5));
            }
        }
        LocatedFace {
            ibug68: Some(Box::new(ibug)),
            dense: Some(
                (0..crate::mediapipe::MESH_POINTS)
                    .map(|k| (Vec2::new(k as f32, 0.5 * k as f32), 0.9))
                    .collect(),
            ),
            confidence: 0.75,
            detect_ms: 2.5,
            landmarks_ms: 20.0,
        }
    }

    #[test]
    fn the_flat_form_reads_back_what_was_written() {
        let without_dense = LocatedFace {
            dense: None,
            ..some_face()
        };
        for face in [some_face(), without_dense, LocatedFace::pre_cropped()] {
            let numbers = face.to_f32s();
            assert_eq!(numbers.len(), LOCATED_FACE_F32S);
            assert_eq!(LocatedFace::from_f32s(&numbers).expect("reads back"), face);
        }
        assert!(
            some_face().to_f32s()[4 + 3 * 30..4 + 3 * 31]
                .iter()
                .all(|v| v.is_nan())
        );
    }

    #[test]
    fn numbers_no_locator_writes_are_refused() {
        let good = some_face().to_f32s();
        let mut cases = vec![good[..good.len() - 1].to_vec(), Vec::new()];
        let mut half_missing = good.clone();
        half_missing[4] = f32::NAN;
        cases.push(half_missing);
        let mut bad_flag = good.clone();
        bad_flag[0] = 0.5;
        cases.push(bad_flag);
        let mut nan_confidence = good.clone();
        nan_confidence[1] = f32::NAN;
        cases.push(nan_confidence);
        // Dense points come whole or not at all.
        let mut half_dense = good;
        half_dense[DENSE_START + 3 * 100] = f32::NAN;
        cases.push(half_dense);
        for case in cases {
            let error = LocatedFace::from_f32s(&case).expect_err("refused");
            assert!(
                error.to_string().starts_with("invalid input: located face"),
                "{error}"
            );
        }
    }
}
