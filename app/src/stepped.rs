//! Footage into a tracked, personalized performance a few frames at a time, on the caller's
//! thread. The browser's wasm has no threads (wasm32 without shared memory), so the studio
//! calls [`SteppedTracking::step`] once per UI frame with a time budget and draws in
//! between; a [`RemoteFaceLocator`] (the page's Web Worker) can take the locating stage off
//! that thread. The work is [`crate::footage::process_footage`]'s: track every frame
//! (landmarks, TrackNet, refinement), personalize on the most varied frames (ModelNet),
//! track again with the person's own blendshapes.

use std::collections::VecDeque;
use std::sync::Arc;

use face::camera::Intrinsics;
use face::{FaceModel, PersonalCorrections, PersonalizedBlendshapes};
use image::RgbImage;
use tracking::networks::ModelNet;
use tracking::pipeline::{FrameOutput, LocatedFace, Tracker};
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

/// What comes back for a frame sent to a [`RemoteFaceLocator`].
pub enum LocatorReply {
    /// The locating stage's result for the oldest frame not yet answered.
    Located(tracking::Result<Option<LocatedFace>>),
    /// The locator cannot go on (its worker stopped); frames not yet answered never will be.
    Failed(String),
}

/// The locating stage (OpenSeeFace's detector and landmarks, [`LocatedFace::follow`])
/// running beside the caller's thread: in the browser, a Web Worker. With it the page's
/// thread only crops, runs TrackNet and refines, so the two stages overlap as the native
/// pipeline's threads do ([`Tracker::track_source`]). Frames are answered in the order
/// they were sent.
pub trait RemoteFaceLocator {
    /// Sends the next frame; `reset` forgets the face followed so far (a new clip).
    fn send(&mut self, image: &RgbImage, reset: bool) -> Result<(), String>;
    /// The answer for the oldest frame not yet answered, if it has come.
    fn receive(&mut self) -> Option<LocatorReply>;
}

/// Frames of a clip sent to a [`RemoteFaceLocator`] and not yet answered, at most: enough
/// to keep it busy while the page's thread draws a slow frame (a software-rendered canvas
/// takes a few hundred milliseconds), few enough to bound the memory.
const MAX_IN_FLIGHT: usize = 12;

/// The same for a camera, whose newest frame is what matters: if tracking falls behind,
/// frames left in the camera are skipped rather than queued, so the preview lags by a few
/// frames at most.
const MAX_IN_FLIGHT_LIVE: usize = 3;

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
    /// The locating stage elsewhere; `None`: this thread does all of a frame.
    remote: Option<Box<dyn RemoteFaceLocator>>,
    /// Frames sent to `remote`, oldest first, waiting for their answer.
    in_flight: VecDeque<Frame>,
    /// The feed has no more frames for this job (ended, stopped or full).
    feed_done: bool,
    /// The last unit of work found nothing to do until the page's event loop runs (a
    /// camera frame or a worker's answer).
    waiting: bool,
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
            remote: None,
            in_flight: VecDeque::new(),
            feed_done: false,
            waiting: false,
        }
    }

    /// Locates faces with `remote` (the browser's worker) beside this thread, falling back
    /// to this thread's own tracker if it fails.
    pub fn with_remote_locator(mut self, remote: Option<Box<dyn RemoteFaceLocator>>) -> Self {
        self.remote = remote;
        self
    }

    /// Frames tracked so far in which a face was found.
    pub fn faces_found(&self) -> usize {
        self.outputs.iter().filter(|o| o.record.face).count()
    }

    /// Whether faces are being located beside this thread (a remote locator was given and
    /// has not failed).
    pub fn locating_beside(&self) -> bool {
        self.remote.is_some()
    }

    /// Whether the tracking stage is over (personalization or re-tracking follow).
    pub fn tracking_done(&self) -> bool {
        !matches!(self.stage, Stage::Tracking)
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
            if started.elapsed() >= budget || self.waiting {
                return None;
            }
        }
    }

    fn step_once(&mut self) -> Result<Option<Tracked>, String> {
        match &mut self.stage {
            Stage::Tracking => {
                self.waiting = false;
                if self.remote.is_some() {
                    self.track_next_beside()?;
                } else {
                    self.track_next()?;
                }
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

    /// The feed's next frame: `Ok(None)` when there is none now (`self.waiting`) or any
    /// more (`self.feed_done`).
    fn next_frame(&mut self) -> Result<Option<Frame>, String> {
        if self.feed_done {
            return Ok(None);
        }
        let kept = self.frames.len() + self.in_flight.len();
        let bytes = self.frame_bytes
            + self
                .in_flight
                .iter()
                .map(|f| f.image.as_raw().len())
                .sum::<usize>();
        let full = kept >= self.max_frames || bytes >= self.max_frame_bytes;
        if full && !self.stop_requested {
            tracing::warn!(
                "footage cut at {kept} frames ({} MB in memory)",
                bytes / 1_000_000
            );
        }
        let image = if self.stop_requested || full {
            None
        } else {
            match &mut self.feed {
                FrameFeed::Clip { frames, .. } => frames.pop_front(),
                FrameFeed::Live { next, .. } => match next() {
                    LiveFrame::Frame(image) => Some(image),
                    LiveFrame::Waiting => {
                        self.waiting = true;
                        return Ok(None);
                    }
                    LiveFrame::Ended(None) => None,
                    LiveFrame::Ended(Some(reason))
                        if self.frames.is_empty() && self.in_flight.is_empty() =>
                    {
                        return Err(reason);
                    }
                    LiveFrame::Ended(Some(reason)) => {
                        tracing::warn!("{reason} (keeping the {kept} frames before it)");
                        None
                    }
                },
            }
        };
        let Some(image) = image else {
            self.feed_done = true;
            return Ok(None);
        };
        let index = self.seen;
        self.seen += 1;
        Ok(Some(Frame {
            index,
            time_s: index as f64 / self.feed.fps().max(1e-3),
            image,
            path: None,
        }))
    }

    /// Tracks the next frame of the feed on this thread, or moves on to personalizing when
    /// there is none.
    fn track_next(&mut self) -> Result<(), String> {
        // Frames a failed remote locator left unanswered come first.
        let frame = match self.in_flight.pop_front() {
            Some(frame) => frame,
            None => match self.next_frame()? {
                Some(frame) => frame,
                None if self.feed_done => return self.end_tracking(),
                None => return Ok(()),
            },
        };
        let started = Instant::now();
        self.first_frame_started.get_or_insert(started);
        let out = self.tracker.process(&frame);
        self.rate.seconds += started.elapsed().as_secs_f64();
        self.keep(frame, out);
        Ok(())
    }

    /// Keeps the remote locator's queue full, then finishes the oldest frame it answered
    /// (crop, TrackNet, refinement here).
    fn track_next_beside(&mut self) -> Result<(), String> {
        let Some(mut remote) = self.remote.take() else {
            return self.track_next();
        };
        let depth = match self.feed {
            FrameFeed::Clip { .. } => MAX_IN_FLIGHT,
            FrameFeed::Live { .. } => MAX_IN_FLIGHT_LIVE,
        };
        while self.in_flight.len() < depth {
            let Some(frame) = self.next_frame()? else {
                break;
            };
            // The worker follows one face from frame to frame: a new job starts afresh.
            let first = self.seen == 1;
            self.first_frame_started.get_or_insert_with(Instant::now);
            let sent = remote.send(&frame.image, first);
            self.in_flight.push_back(frame);
            if let Err(e) = sent {
                tracing::warn!("the face locator beside the page failed ({e}); locating here");
                return Ok(());
            }
        }
        match remote.receive() {
            Some(LocatorReply::Located(located)) => {
                self.remote = Some(remote);
                let Some(frame) = self.in_flight.pop_front() else {
                    return Err("internal: the face locator answered a frame never sent".into());
                };
                let started = Instant::now();
                let out = self.tracker.process_located(&frame, located);
                self.rate.seconds += started.elapsed().as_secs_f64()
                    + (out.times.detect_ms + out.times.landmarks_ms) / 1e3;
                self.keep(frame, out);
                Ok(())
            }
            Some(LocatorReply::Failed(reason)) => {
                // The frames it did not answer are tracked here, from a fresh detection.
                tracing::warn!(
                    "the face locator beside the page stopped ({reason}); locating here"
                );
                Ok(())
            }
            None if self.in_flight.is_empty() && self.feed_done => {
                self.remote = Some(remote);
                self.end_tracking()
            }
            None => {
                self.remote = Some(remote);
                self.waiting = true;
                Ok(())
            }
        }
    }

    /// Counts a tracked frame and keeps it (a frame of another size is only counted).
    fn keep(&mut self, frame: Frame, out: FrameOutput) {
        self.rate.frames += 1;
        let t = &mut self.rate.stage_ms;
        t.detect_ms += out.times.detect_ms;
        t.landmarks_ms += out.times.landmarks_ms;
        t.crop_ms += out.times.crop_ms;
        t.tracknet_ms += out.times.tracknet_ms;
        t.refine_ms += out.times.refine_ms;
        t.smooth_ms += out.times.smooth_ms;
        if let Some(first) = self.first_frame_started {
            self.rate.wall_seconds = first.elapsed().as_secs_f64();
        }
        self.preview = Some(LivePreview {
            seen: frame.index + 1,
            image: frame.image.clone(),
            overlay: FrameOverlay::from_output(&out),
        });
        let dims = frame.image.dimensions();
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
            done: frame.index + 1,
            total: self.total,
        };
    }

    /// Every frame is tracked: on to personalizing, unless there is nothing to personalize.
    fn end_tracking(&mut self) -> Result<(), String> {
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
