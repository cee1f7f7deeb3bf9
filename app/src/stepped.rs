//! Footage into a tracked, personalized performance a few frames at a time, on the caller's
//! thread. The browser has no threads (wasm32 without shared memory), so the studio calls
//! [`SteppedTracking::step`] once per UI frame with a time budget and draws in between. The
//! work is [`crate::footage::process_footage`]'s: track every frame (landmarks, TrackNet,
//! refinement), personalize on the most varied frames (ModelNet), track again with the
//! person's own blendshapes.

use std::collections::VecDeque;
use std::sync::Arc;

use face::camera::Intrinsics;
use face::{FaceModel, PersonalCorrections, PersonalizedBlendshapes};
use image::RgbImage;
use tracking::networks::ModelNet;
use tracking::pipeline::{FrameOutput, Tracker};
use tracking::record::FrameRecord;
use tracking::source::Frame;
use web_time::{Duration, Instant};

use crate::footage::{LivePreview, Progress};
use crate::studio_session::FrameOverlay;

/// What a live source has for the job right now.
pub enum LiveFrame {
    Frame(RgbImage),
    /// No new frame yet (the camera runs at its own pace).
    Waiting,
    /// The source ended, with the reason when it failed.
    Ended(Option<String>),
}

/// Where the frames come from.
pub enum FrameFeed {
    /// Frames already decoded (an image, dropped images, a decoded video, the demo's
    /// clip), at `fps`.
    Clip {
        frames: VecDeque<RgbImage>,
        fps: f64,
    },
    /// A live camera, polled once per step until it ends or the job is stopped.
    Live {
        next: Box<dyn FnMut() -> LiveFrame>,
        fps: f64,
    },
}

impl FrameFeed {
    pub fn clip(frames: Vec<RgbImage>, fps: f64) -> Self {
        Self::Clip {
            frames: frames.into(),
            fps,
        }
    }

    fn fps(&self) -> f64 {
        match self {
            Self::Clip { fps, .. } | Self::Live { fps, .. } => *fps,
        }
    }
}

/// Frames tracked, the time the tracker spent on them, and the wall-clock time from the
/// start of the first to the end of the last (which includes whatever the thread did in
/// between, such as drawing the studio): the page's "tracking fps".
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrackingRate {
    pub frames: usize,
    pub seconds: f64,
    pub wall_seconds: f64,
    /// Milliseconds in each stage, summed over the frames (the tracker's own timings).
    pub stage_ms: tracking::pipeline::StageTimes,
}

impl TrackingRate {
    /// Frames per second of tracker time.
    pub fn fps(&self) -> Option<f64> {
        (self.frames > 0 && self.seconds > 0.0).then(|| self.frames as f64 / self.seconds)
    }

    /// Frames per second of wall-clock time.
    pub fn wall_fps(&self) -> Option<f64> {
        (self.frames > 0 && self.wall_seconds > 0.0).then(|| self.frames as f64 / self.wall_seconds)
    }
}

/// The job's result: everything a studio session is made of.
pub struct Tracked {
    pub fps: f64,
    pub frames: Vec<RgbImage>,
    pub outputs: Vec<FrameOutput>,
    pub records: Vec<FrameRecord>,
    pub corrections: PersonalCorrections,
    pub blendshapes: Arc<PersonalizedBlendshapes>,
    /// Positions of the frames ModelNet saw.
    pub selected_frames: Vec<usize>,
    pub intrinsics: Intrinsics,
    pub rate: TrackingRate,
}

enum Stage {
    Tracking,
    Personalizing,
    Retracking {
        corrections: PersonalCorrections,
        blendshapes: Arc<PersonalizedBlendshapes>,
        picked: Vec<usize>,
        records: Vec<FrameRecord>,
    },
    Ended,
}

/// Tracks and personalizes a [`FrameFeed`] in steps.
pub struct SteppedTracking {
    face: Arc<FaceModel>,
    tracker: Tracker,
    model_net: Option<ModelNet>,
    feed: FrameFeed,
    stage: Stage,
    frames: Vec<RgbImage>,
    outputs: Vec<FrameOutput>,
    size: Option<(u32, u32)>,
    seen: usize,
    other_size: usize,
    stop_requested: bool,
    max_frames: usize,
    /// Frames kept are at most this many bytes (a wasm page has 4 GB at most).
    max_frame_bytes: usize,
    frame_bytes: usize,
    personalize_frames: usize,
    total: Option<usize>,
    pub progress: Progress,
    preview: Option<LivePreview>,
    pub rate: TrackingRate,
    first_frame_started: Option<Instant>,
}

impl SteppedTracking {
    /// `model_net` is loaded up front so a missing or damaged network fails here, not after
    /// the footage was tracked.
    pub fn new(
        face: Arc<FaceModel>,
        tracker: Tracker,
        model_net: ModelNet,
        feed: FrameFeed,
        max_frames: usize,
        personalize_frames: usize,
    ) -> Self {
        let total = match &feed {
            FrameFeed::Clip { frames, .. } => Some(frames.len().min(max_frames)),
            FrameFeed::Live { .. } => None,
        };
        Self {
            face,
            tracker,
            model_net: Some(model_net),
            feed,
            stage: Stage::Tracking,
            frames: Vec::new(),
            outputs: Vec::new(),
            size: None,
            seen: 0,
            other_size: 0,
            stop_requested: false,
            max_frames: max_frames.max(1),
            max_frame_bytes: usize::MAX,
            frame_bytes: 0,
            personalize_frames,
            total,
            progress: Progress {
                stage: "tracking",
                done: 0,
                total,
            },
            preview: None,
            rate: TrackingRate::default(),
            first_frame_started: None,
        }
    }

    /// Stops taking frames once those kept reach `bytes` (a recording ends there, a clip is
    /// cut), so long or large footage cannot exhaust a browser page's memory.
    pub fn with_memory_limit(mut self, bytes: usize) -> Self {
        self.max_frame_bytes = bytes;
        self
    }

    /// Ends the tracking stage: a live source stops recording and what was recorded is
    /// personalized (the caller drops the job to abandon it instead).
    pub fn stop(&mut self) {
        self.stop_requested = true;
    }

    pub fn stopping(&self) -> bool {
        self.stop_requested
    }

    /// The newest tracked frame since the last call.
    pub fn take_preview(&mut self) -> Option<LivePreview> {
        self.preview.take()
    }

    /// Works until `budget` is spent (at least one unit of work: a frame, ModelNet, or a
    /// few re-tracked frames); `Some` once, when the job has ended.
    pub fn step(&mut self, budget: Duration) -> Option<Result<Tracked, String>> {
        let started = Instant::now();
        loop {
            match self.step_once() {
                Ok(Some(tracked)) => {
                    self.stage = Stage::Ended;
                    return Some(Ok(tracked));
                }
                Ok(None) => {}
                Err(e) => {
                    self.stage = Stage::Ended;
                    return Some(Err(e));
                }
            }
            if matches!(self.stage, Stage::Ended) {
                return None;
            }
            if started.elapsed() >= budget || self.waiting_for_camera() {
                return None;
            }
        }
    }

    fn waiting_for_camera(&self) -> bool {
        matches!(self.stage, Stage::Tracking) && matches!(self.feed, FrameFeed::Live { .. })
    }

    fn step_once(&mut self) -> Result<Option<Tracked>, String> {
        match &mut self.stage {
            Stage::Tracking => {
                self.track_next()?;
                Ok(None)
            }
            Stage::Personalizing => {
                self.personalize()?;
                Ok(None)
            }
            Stage::Retracking { records, .. } if records.len() < self.outputs.len() => {
                let (width, height) = self.size.unwrap_or((1, 1));
                // Refinement alone is fast: several frames per unit of work.
                let end = (records.len() + 8).min(self.outputs.len());
                for out in &self.outputs[records.len()..end] {
                    records.push(self.tracker.retrack(out, width, height));
                }
                self.progress = Progress {
                    stage: "tracking with the personal blendshapes",
                    done: records.len(),
                    total: Some(self.outputs.len()),
                };
                Ok(None)
            }
            Stage::Retracking { .. } => {
                let Stage::Retracking {
                    corrections,
                    blendshapes,
                    picked,
                    records,
                } = std::mem::replace(&mut self.stage, Stage::Ended)
                else {
                    return Err("internal: the re-tracking stage was lost".into());
                };
                let (width, height) = self.size.unwrap_or((1, 1));
                let mut outputs = std::mem::take(&mut self.outputs);
                // The network inputs were kept for ModelNet only; they are most of a
                // frame's memory.
                for out in &mut outputs {
                    out.input = None;
                }
                Ok(Some(Tracked {
                    fps: self.feed.fps(),
                    frames: std::mem::take(&mut self.frames),
                    outputs,
                    records,
                    corrections,
                    blendshapes,
                    selected_frames: picked,
                    intrinsics: self.tracker.intrinsics(width, height),
                    rate: self.rate,
                }))
            }
            Stage::Ended => Ok(None),
        }
    }

    /// Tracks the next frame of the feed, or moves on to personalizing when there is none.
    fn track_next(&mut self) -> Result<(), String> {
        let full = self.frames.len() >= self.max_frames || self.frame_bytes >= self.max_frame_bytes;
        if full && !self.stop_requested {
            tracing::warn!(
                "footage cut at {} frames ({} MB in memory)",
                self.frames.len(),
                self.frame_bytes / 1_000_000
            );
        }
        let image = if self.stop_requested || full {
            None
        } else {
            match &mut self.feed {
                FrameFeed::Clip { frames, .. } => frames.pop_front(),
                FrameFeed::Live { next, .. } => match next() {
                    LiveFrame::Frame(image) => Some(image),
                    LiveFrame::Waiting => return Ok(()),
                    LiveFrame::Ended(None) => None,
                    LiveFrame::Ended(Some(reason)) if self.frames.is_empty() => {
                        return Err(reason);
                    }
                    LiveFrame::Ended(Some(reason)) => {
                        tracing::warn!(
                            "{reason} (keeping the {} frames before it)",
                            self.frames.len()
                        );
                        None
                    }
                },
            }
        };
        let Some(image) = image else {
            if self.other_size > 0 {
                tracing::warn!("{} frame(s) of another size left out", self.other_size);
            }
            if self.frames.is_empty() {
                return Err("no readable frames".into());
            }
            if !self.outputs.iter().any(|o| o.record.face) {
                return Err("no face was found".into());
            }
            self.stage = Stage::Personalizing;
            self.progress = Progress {
                stage: "personalizing (ModelNet)",
                done: 0,
                total: None,
            };
            return Ok(());
        };
        let dims = image.dimensions();
        let index = self.seen;
        self.seen += 1;
        let frame = Frame {
            index,
            time_s: index as f64 / self.feed.fps().max(1e-3),
            image,
            path: None,
        };
        let started = Instant::now();
        let out = self.tracker.process(&frame);
        self.rate.seconds += started.elapsed().as_secs_f64();
        self.rate.frames += 1;
        let t = &mut self.rate.stage_ms;
        t.detect_ms += out.times.detect_ms;
        t.landmarks_ms += out.times.landmarks_ms;
        t.crop_ms += out.times.crop_ms;
        t.tracknet_ms += out.times.tracknet_ms;
        t.refine_ms += out.times.refine_ms;
        t.smooth_ms += out.times.smooth_ms;
        let first = *self.first_frame_started.get_or_insert(started);
        self.rate.wall_seconds = first.elapsed().as_secs_f64();
        self.preview = Some(LivePreview {
            seen: self.seen,
            image: frame.image.clone(),
            overlay: FrameOverlay::from_output(&out),
        });
        // One session has one camera: frames of another size are left out and counted.
        if *self.size.get_or_insert(dims) != dims {
            self.other_size += 1;
        } else {
            self.frame_bytes += frame.image.as_raw().len();
            self.frames.push(frame.image);
            self.outputs.push(out);
        }
        self.progress = Progress {
            stage: "tracking",
            done: self.seen,
            total: self.total,
        };
        Ok(())
    }

    fn personalize(&mut self) -> Result<(), String> {
        let mut model_net = self
            .model_net
            .take()
            .ok_or("internal: ModelNet ran twice")?;
        let (corrections, picked) = tracking::personalize::personalize(
            &mut model_net,
            &self.outputs,
            self.personalize_frames,
        )
        .map_err(|e| format!("personalization failed: {e}"))?;
        let blendshapes = Arc::new(
            self.face
                .personalize(&corrections)
                .map_err(|e| format!("personalization failed: {e}"))?,
        );
        self.tracker
            .set_blendshapes(blendshapes.clone())
            .map_err(|e| format!("personalization failed: {e}"))?;
        self.tracker.reset();
        self.stage = Stage::Retracking {
            corrections,
            blendshapes,
            picked,
            records: Vec::with_capacity(self.outputs.len()),
        };
        Ok(())
    }
}
