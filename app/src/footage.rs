//! Footage into a studio session, off the UI thread: an image, a folder of images, a video
//! file or a webcam is tracked (landmarks, TrackNet, refinement), personalized (ModelNet on
//! the most varied frames) and tracked again with the person's own blendshapes, the same
//! pipeline as `likeness personalize`, while the studio shows the progress and can cancel.
//! Natively the job runs on its own thread; in the browser, which has one, it is
//! [`crate::stepped::SteppedTracking`] advanced a slice per UI frame, behind the same
//! `FootageJob` interface.

#[cfg(not(target_arch = "wasm32"))]
pub use native::{FootageJob, process_footage};
#[cfg(target_arch = "wasm32")]
pub use stepped::FootageJob;

use crate::studio_session::FrameOverlay;

/// What to process.
#[derive(Clone, Debug)]
pub struct FootageRequest {
    /// An image, a folder of images, a video file, or `webcam[:DEVICE]`.
    pub input: String,
    /// The studio keeps every frame in memory at full size, so long footage is cut here
    /// (a webcam records until this many frames or until it is stopped).
    pub max_frames: usize,
    /// How many frames ModelNet personalizes from.
    pub personalize_frames: usize,
    /// What finds the face (File > Face locator).
    pub locator: tracking::pipeline::LocatorChoice,
}

impl FootageRequest {
    pub fn new(input: impl Into<String>) -> Self {
        Self {
            input: input.into(),
            max_frames: 600,
            personalize_frames: 8,
            locator: tracking::pipeline::LocatorChoice::Landmarks,
        }
    }
}

/// Where a job is.
#[derive(Clone, Debug, PartialEq)]
pub struct Progress {
    pub stage: &'static str,
    pub done: usize,
    pub total: Option<usize>,
}

/// The newest frame a job has tracked and what the tracker found in it: the live view of
/// a webcam while it records, and of any footage while it is tracked.
#[derive(Clone, Debug)]
pub struct LivePreview {
    /// How many frames the job had seen when this one came.
    pub seen: usize,
    pub image: image::RgbImage,
    pub overlay: FrameOverlay,
}

#[cfg(not(target_arch = "wasm32"))]
mod native {
    use std::ops::ControlFlow;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::mpsc;
    use std::sync::{Arc, Mutex};
    use std::thread::JoinHandle;

    use anyhow::{Context, Result, bail};
    use face::FaceModel;
    use tracking::pipeline::{TrackEvent, Tracker, TrackerConfig};
    use tracking::source::InputSpec;

    use super::{FootageRequest, LivePreview, Progress};
    use crate::scene::Scene;
    use crate::studio_session::{FrameOverlay, StudioSession};

    /// Tracks and personalizes `request.input`. `cancel` is checked between frames; `progress`
    /// hears about every frame and stage, `preview` gets every tracked frame.
    pub fn process_footage(
        scene: &Scene,
        request: &FootageRequest,
        cancel: &AtomicBool,
        mut progress: impl FnMut(Progress),
        mut preview: impl FnMut(LivePreview),
    ) -> Result<StudioSession> {
        let input = request.input.trim();
        let spec = InputSpec::parse(input).with_context(|| format!("cannot open `{input}`"))?;
        progress(Progress {
            stage: "loading the networks",
            done: 0,
            total: None,
        });
        let face = Arc::new(FaceModel::new(scene.model.template.clone()));
        let config = TrackerConfig {
            threads: 1,
            locator: request.locator,
            ..TrackerConfig::default()
        };
        // Anything a user opens may be real footage: without the landmark models that is an
        // error naming them, never every image silently taken as a face crop.
        let mut tracker = Tracker::new(face.clone(), config, true).with_context(|| {
            format!(
                "tracking needs the networks and the {} models",
                match request.locator {
                    tracking::pipeline::LocatorChoice::MediaPipe => "MediaPipe",
                    _ => "OpenSeeFace",
                }
            )
        })?;
        let mut source = spec
            // Images have no frame rate of their own: they play at 30 fps.
            .open(30.0)
            .with_context(|| format!("cannot open `{input}`"))?;
        let total = source.len_hint().map(|n| n.min(request.max_frames));
        let fps = source.fps();
        let live = source.is_live();
        let describe = source.describe();
        let mut frames = Vec::new();
        let mut outputs = Vec::new();
        let (mut skipped, mut other_size) = (0usize, 0usize);
        let mut size = None;
        let mut cancelled = false;
        let mut seen = 0usize;
        let result = tracker.track_source(source.as_mut(), |event| {
            seen += 1;
            match event {
                TrackEvent::Skipped(skip) => {
                    tracing::warn!("frame {}: {}", skip.index, skip.error);
                    skipped += 1;
                }
                TrackEvent::Frame(frame, out) => {
                    let dims = frame.image.dimensions();
                    // One session has one camera: frames of another size (a folder of mixed
                    // images) are left out and counted.
                    preview(LivePreview {
                        seen,
                        image: frame.image.clone(),
                        overlay: FrameOverlay::from_output(&out),
                    });
                    if *size.get_or_insert(dims) != dims {
                        other_size += 1;
                    } else {
                        frames.push(frame.image);
                        outputs.push(*out);
                    }
                }
            }
            progress(Progress {
                stage: "tracking",
                done: seen,
                total,
            });
            if cancel.load(Ordering::Relaxed) {
                // Stopping a live camera ends the recording; anything else is abandoned.
                cancelled = !live;
                return ControlFlow::Break(());
            }
            if frames.len() >= request.max_frames {
                return ControlFlow::Break(());
            }
            ControlFlow::Continue(())
        });
        if cancelled {
            bail!("cancelled");
        }
        if let Err(e) = result {
            if frames.is_empty() {
                return Err(e).with_context(|| format!("cannot read `{input}`"));
            }
            tracing::warn!(
                "{input}: {e} (keeping the {} frames before it)",
                frames.len()
            );
        }
        if skipped > 0 || other_size > 0 {
            tracing::warn!(
                "{input}: {skipped} unreadable frame(s) and {other_size} of another size left out"
            );
        }
        let Some((width, height)) = size.filter(|_| !frames.is_empty()) else {
            bail!("`{input}` has no readable frames");
        };
        if !outputs.iter().any(|o| o.record.face) {
            bail!("no face was found in `{input}`");
        }
        progress(Progress {
            stage: "personalizing (ModelNet)",
            done: 0,
            total: None,
        });
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let mut model_net =
            tracking::networks::ModelNet::load(&tracker.manifest, tracker.backend(), cores)?;
        let (corrections, picked) = tracking::personalize::personalize(
            &mut model_net,
            &outputs,
            request.personalize_frames,
        )?;
        if cancel.load(Ordering::Relaxed) {
            bail!("cancelled");
        }
        let blendshapes = Arc::new(face.personalize(&corrections)?);
        tracker.set_blendshapes(blendshapes.clone())?;
        tracker.reset();
        let mut records = Vec::with_capacity(outputs.len());
        for (k, out) in outputs.iter().enumerate() {
            records.push(tracker.retrack(out, width, height));
            progress(Progress {
                stage: "tracking with the personal blendshapes",
                done: k + 1,
                total: Some(outputs.len()),
            });
        }
        // The network inputs were kept for ModelNet only; they are most of a frame's memory.
        for out in &mut outputs {
            out.input = None;
        }
        // Positions in the session (frames left out shift source indices).
        let selected_frames = picked;
        Ok(StudioSession::from_tracking(
            &scene.model,
            describe,
            fps,
            frames,
            outputs,
            records,
            corrections,
            blendshapes,
            selected_frames,
            tracker.intrinsics(width, height),
        ))
    }

    enum JobMessage {
        Progress(Progress),
        Done(Result<Box<StudioSession>, String>),
    }

    /// A [`process_footage`] running on its own thread.
    pub struct FootageJob {
        pub input: String,
        pub progress: Progress,
        cancel: Arc<AtomicBool>,
        /// The newest [`LivePreview`], replaced by each tracked frame and taken by the UI.
        preview: Arc<Mutex<Option<LivePreview>>>,
        receiver: mpsc::Receiver<JobMessage>,
        thread: Option<JoinHandle<()>>,
    }

    impl FootageJob {
        /// Starts processing; `repaint` is called whenever there is news for the UI.
        pub fn start(
            scene: Arc<Scene>,
            request: FootageRequest,
            repaint: impl Fn() + Send + 'static,
        ) -> Result<Self> {
            let (sender, receiver) = mpsc::channel();
            let cancel = Arc::new(AtomicBool::new(false));
            let input = request.input.clone();
            let preview = Arc::new(Mutex::new(None));
            let thread = {
                let cancel = cancel.clone();
                let preview_slot = preview.clone();
                std::thread::Builder::new()
                    .name("likeness footage".into())
                    .spawn(move || {
                        let repaint = &repaint;
                        let result = process_footage(
                            &scene,
                            &request,
                            &cancel,
                            |p| {
                                let _ = sender.send(JobMessage::Progress(p));
                                repaint();
                            },
                            |frame| {
                                // A poisoned slot means the UI panicked: no one is watching.
                                if let Ok(mut slot) = preview_slot.lock() {
                                    *slot = Some(frame);
                                }
                                repaint();
                            },
                        )
                        .map(Box::new)
                        .map_err(|e| format!("{}: {e:#}", request.input));
                        let _ = sender.send(JobMessage::Done(result));
                        repaint();
                    })
                    .context("cannot start the footage thread")?
            };
            Ok(Self {
                input,
                progress: Progress {
                    stage: "starting",
                    done: 0,
                    total: None,
                },
                cancel,
                preview,
                receiver,
                thread: Some(thread),
            })
        }

        /// Asks the job to stop (a webcam stops recording and goes on to personalize).
        pub fn cancel(&self) {
            self.cancel.store(true, Ordering::Relaxed);
        }

        pub fn cancelling(&self) -> bool {
            self.cancel.load(Ordering::Relaxed)
        }

        /// The newest tracked frame since the last call, if one came.
        pub fn take_preview(&self) -> Option<LivePreview> {
            self.preview.lock().ok().and_then(|mut slot| slot.take())
        }

        /// Takes the news: `Some` once, when the job has ended.
        pub fn poll(&mut self) -> Option<Result<Box<StudioSession>, String>> {
            loop {
                match self.receiver.try_recv() {
                    Ok(JobMessage::Progress(p)) => self.progress = p,
                    Ok(JobMessage::Done(result)) => {
                        self.join();
                        return Some(result);
                    }
                    Err(mpsc::TryRecvError::Empty) => return None,
                    Err(mpsc::TryRecvError::Disconnected) => {
                        self.join();
                        return Some(Err(format!(
                            "{}: the footage thread stopped unexpectedly",
                            self.input
                        )));
                    }
                }
            }
        }

        fn join(&mut self) {
            if let Some(handle) = self.thread.take() {
                let _ = handle.join();
            }
        }
    }

    impl Drop for FootageJob {
        fn drop(&mut self) {
            // Closing the studio mid-job: stop the thread rather than leave it tracking.
            self.cancel();
        }
    }
}

/// The browser's footage job: [`crate::stepped::SteppedTracking`] driven by the studio's
/// frames (there are no threads), with the native job's interface.
#[cfg(target_arch = "wasm32")]
mod stepped {
    use std::cell::{Cell, RefCell};
    use std::sync::Arc;

    use anyhow::{Context, Result, bail};
    use face::FaceModel;
    use tracking::pipeline::TrackerConfig;
    use web_time::Duration;

    use super::{FootageRequest, LivePreview, Progress};
    use crate::scene::Scene;
    use crate::stepped::{FrameFeed, SteppedTracking};
    use crate::studio_session::StudioSession;

    /// How long one UI frame may spend on the job (at least one frame is tracked).
    const STEP_BUDGET: Duration = Duration::from_millis(30);

    /// Footage kept in a page's memory (which is 4 GB at most, for everything): 600 frames
    /// at 640x480, 360 at 1280x720.
    const MAX_FOOTAGE_BYTES: usize = 1 << 30;

    pub struct FootageJob {
        pub input: String,
        pub progress: Progress,
        scene: Arc<Scene>,
        live: bool,
        tracking: RefCell<SteppedTracking>,
        cancelled: Cell<bool>,
    }

    impl FootageJob {
        /// Paths mean nothing in a browser: footage comes as bytes (dropped or picked
        /// files, the camera) through [`FootageJob::start_feed`].
        pub fn start(
            _scene: Arc<Scene>,
            request: FootageRequest,
            _repaint: impl Fn() + Send + 'static,
        ) -> Result<Self> {
            bail!(
                "`{}`: in the browser, open footage by dropping image or video files on the \
                 page, with File > Open, or from the webcam",
                request.input
            )
        }

        /// Tracks and personalizes `feed`, called `input` in messages, finding faces with
        /// `locator`: with `remote_locator` (the same locator) beside the page's thread when
        /// there is one.
        pub fn start_feed(
            scene: Arc<Scene>,
            input: String,
            feed: FrameFeed,
            locator: tracking::pipeline::LocatorChoice,
            remote_locator: Option<Box<dyn crate::stepped::RemoteFaceLocator>>,
        ) -> Result<Self> {
            let networks = scene
                .networks
                .clone()
                .context("the networks were not loaded, so footage cannot be tracked")?;
            let face = Arc::new(FaceModel::new(scene.model.template.clone()));
            let config = TrackerConfig {
                threads: 1,
                locator,
                ..TrackerConfig::default()
            };
            let tracker = networks.tracker(face.clone(), config, true)?;
            let model_net = networks.model_net()?;
            let live = matches!(feed, FrameFeed::Live { .. });
            let request = FootageRequest::new(input.clone());
            let tracking = SteppedTracking::new(
                face,
                tracker,
                model_net,
                feed,
                request.max_frames,
                request.personalize_frames,
            )
            .with_memory_limit(MAX_FOOTAGE_BYTES)
            .with_remote_locator(remote_locator);
            Ok(Self {
                input,
                progress: tracking.progress.clone(),
                scene,
                live,
                tracking: RefCell::new(tracking),
                cancelled: Cell::new(false),
            })
        }

        /// A camera stops recording and goes on to personalize; anything else is
        /// abandoned.
        pub fn cancel(&self) {
            if self.live {
                if let Ok(mut tracking) = self.tracking.try_borrow_mut() {
                    tracking.stop();
                }
            } else {
                self.cancelled.set(true);
            }
        }

        pub fn cancelling(&self) -> bool {
            self.cancelled.get() || self.tracking.try_borrow().is_ok_and(|t| t.stopping())
        }

        pub fn take_preview(&self) -> Option<LivePreview> {
            self.tracking.try_borrow_mut().ok()?.take_preview()
        }

        /// Does the next slice of the work; `Some` once, when the job has ended.
        pub fn poll(&mut self) -> Option<Result<Box<StudioSession>, String>> {
            if self.cancelled.get() {
                return Some(Err(format!("{}: cancelled", self.input)));
            }
            let tracking = self.tracking.get_mut();
            let result = tracking.step(STEP_BUDGET);
            self.progress = tracking.progress.clone();
            let tracked = match result? {
                Ok(tracked) => tracked,
                Err(e) => return Some(Err(format!("{}: {e}", self.input))),
            };
            Some(Ok(Box::new(StudioSession::from_tracking(
                &self.scene.model,
                self.input.clone(),
                tracked.fps,
                tracked.frames,
                tracked.outputs,
                tracked.records,
                tracked.corrections,
                tracked.blendshapes,
                tracked.selected_frames,
                tracked.intrinsics,
            ))))
        }
    }
}
