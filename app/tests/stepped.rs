//! The browser's way of making the demo and tracking footage: a slice of work per UI frame
//! on one thread, with the networks read from bytes (tract), run natively here against the
//! same expectations as the threaded pipeline.

use std::collections::VecDeque;
use std::sync::Arc;

use glam::Vec2;
use likeness::demo::{
    DemoConfig, SteppedDemo, demo_motion, landmark_nme, render_clip, synthetic_person,
};
use likeness::scene::Scene;
use likeness::stepped::{FrameFeed, LiveFrame, LocatorReply, RemoteFaceLocator, SteppedTracking};
use renderer::OffscreenRenderer;
use tracking::bundle::NetworkBytes;
use tracking::pipeline::{LocatedFace, TrackerConfig};
use web_time::Duration;

fn scene_with_networks() -> Arc<Scene> {
    let mut scene = Scene::load(None).unwrap_or_else(|e| panic!("the template: {e}"));
    let networks = NetworkBytes::read(
        &tracking::networks::default_networks_dir(),
        Some(&tracking::openseeface::default_models_dir()),
    )
    .unwrap_or_else(|e| panic!("the networks and OpenSeeFace models: {e}"));
    scene.networks = Some(Arc::new(networks));
    Arc::new(scene)
}

fn config() -> DemoConfig {
    DemoConfig {
        frames: 24,
        personalize_frames: 4,
        ..DemoConfig::default()
    }
}

/// The demo's clip, rendered the blocking way.
fn clip(scene: &Scene, config: &DemoConfig) -> Vec<image::RgbImage> {
    let truth = synthetic_person(&scene.model, scene.albedo.face(), config.seed);
    let person = scene.model.personalize(&truth).expect("person");
    let motion = demo_motion(&scene.model, &person, config);
    render_clip(scene, &truth, &person, &motion, config).expect("clip")
}

fn stepped_tracking(scene: &Scene, feed: FrameFeed) -> SteppedTracking {
    let networks = scene.networks.as_ref().expect("networks");
    let face = Arc::new(face::FaceModel::new(scene.model.template.clone()));
    let tracker = networks
        .tracker(
            face.clone(),
            TrackerConfig {
                threads: 1,
                fov_deg: Some(DemoConfig::default().fov_deg),
                ..TrackerConfig::default()
            },
            true,
        )
        .expect("tracker from bytes");
    SteppedTracking::new(
        face,
        tracker,
        networks.model_net().expect("ModelNet"),
        feed,
        600,
        4,
    )
}

#[test]
fn the_stepped_demo_renders_the_same_clip_and_tracks_it_as_well_as_the_threaded_one() {
    let scene = scene_with_networks();
    let config = config();
    let networks = scene.networks.clone().expect("networks");
    let mut demo = SteppedDemo::new(scene.clone(), networks, config.clone(), |mesh, textures| {
        Ok(OffscreenRenderer::new(mesh, textures)?)
    })
    .expect("demo");
    let mut stages = Vec::new();
    let mut steps = 0;
    let started = web_time::Instant::now();
    let (session, rate) = loop {
        steps += 1;
        assert!(started.elapsed().as_secs() < 600, "the demo never ended");
        // As a UI would: a short slice of work, then the rest of a frame for other things
        // (the GPU finishes a clip frame meanwhile).
        let result = demo.step(Duration::from_millis(1));
        std::thread::sleep(std::time::Duration::from_millis(1));
        if stages.last() != Some(&demo.progress.stage) {
            stages.push(demo.progress.stage);
        }
        if let Some(result) = result {
            break result.unwrap_or_else(|e| panic!("stepped demo: {e:#}"));
        }
    };
    // A slice per call: at least one call per clip frame rendered and per frame tracked.
    assert!(steps >= 2 * config.frames, "{steps} steps");
    for stage in [
        "rendering the demo clip",
        "tracking",
        "tracking with the personal blendshapes",
    ] {
        assert!(stages.contains(&stage), "{stages:?}");
    }
    // The clip is the blocking renderer's, pixel for pixel.
    let expected = clip(&scene, &config);
    assert_eq!(session.frames.len(), config.frames);
    for (k, (a, b)) in session.frames.iter().zip(&expected).enumerate() {
        assert!(a == b, "clip frame {k} differs from render_clip's");
    }
    assert_eq!((rate.frames, session.records.len()), (24, 24));
    assert!(rate.seconds > 0.0 && rate.fps().is_some_and(|f| f > 0.0));
    assert!(
        session.records.iter().all(|r| r.face),
        "every frame shows the face"
    );
    assert_eq!(session.selected_frames.len(), 4);
    session.learned.validate().expect("finite corrections");
    // The same accuracy bound as the threaded demo's test (tests/demo.rs).
    let nme = landmark_nme(&scene.model, &session, |k| {
        session.records[k]
            .track
            .as_ref()
            .map(|t| t.landmarks_68.iter().map(|p| Vec2::from(*p)).collect())
    })
    .expect("landmarks");
    eprintln!("stepped demo (tract) landmark NME {:.2} %", 100.0 * nme);
    assert!(nme < 0.06, "NME {nme}");
}

#[test]
fn a_live_feed_is_polled_without_blocking_and_stopping_it_personalizes_what_was_recorded() {
    let scene = scene_with_networks();
    let config = DemoConfig {
        frames: 10,
        ..config()
    };
    let mut frames: VecDeque<_> = clip(&scene, &config).into();
    let mut calls = 0usize;
    // A camera with a new frame on every other poll.
    let next = move || {
        calls += 1;
        if calls.is_multiple_of(2) {
            return LiveFrame::Waiting;
        }
        match frames.pop_front() {
            Some(frame) => LiveFrame::Frame(frame),
            None => LiveFrame::Ended(None),
        }
    };
    let mut job = stepped_tracking(
        &scene,
        FrameFeed::Live {
            next: Box::new(next),
            fps: 30.0,
        },
    );
    let mut tracked = 0;
    let mut polls = 0;
    while tracked < 6 {
        polls += 1;
        assert!(polls < 100, "the live job does not advance");
        // A long budget: the job returns as soon as the camera has nothing new.
        assert!(job.step(Duration::from_secs(60)).is_none());
        if let Some(preview) = job.take_preview() {
            assert_eq!(preview.image.dimensions(), (640, 480));
            assert_eq!(preview.overlay.model.len(), 68);
            tracked = preview.seen;
        }
    }
    assert_eq!(job.progress.total, None, "a camera has no length");
    job.stop();
    assert!(job.stopping());
    let result = loop {
        if let Some(result) = job.step(Duration::from_millis(5)) {
            break result;
        }
    };
    let tracked = result.unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(tracked.frames.len(), 6, "the frames before Stop, no more");
    assert_eq!(tracked.records.len(), 6);
    assert!(
        tracked.outputs.iter().all(|o| o.input.is_none()),
        "inputs freed"
    );
    assert_eq!(tracked.rate.frames, 6);
}

#[test]
fn feeds_without_frames_or_faces_end_with_a_clear_error() {
    let scene = scene_with_networks();
    let run = |feed| {
        let mut job = stepped_tracking(&scene, feed);
        loop {
            if let Some(result) = job.step(Duration::from_millis(50)) {
                break result.err().unwrap_or_else(|| "no error".into());
            }
        }
    };
    assert_eq!(run(FrameFeed::clip(Vec::new(), 30.0)), "no readable frames");
    let grey = image::RgbImage::from_pixel(320, 240, image::Rgb([90, 90, 90]));
    assert_eq!(
        run(FrameFeed::clip(vec![grey.clone(); 3], 30.0)),
        "no face was found"
    );
    let failing = FrameFeed::Live {
        next: Box::new(|| LiveFrame::Ended(Some("the camera could not start: denied".into()))),
        fps: 30.0,
    };
    assert_eq!(run(failing), "the camera could not start: denied");
}

#[test]
fn a_memory_limit_ends_a_recording_with_the_frames_that_fit() {
    let scene = scene_with_networks();
    let config = DemoConfig {
        frames: 6,
        ..config()
    };
    let mut frames: VecDeque<_> = clip(&scene, &config).into();
    let frame_bytes = 640 * 480 * 3;
    let next = move || match frames.pop_front() {
        Some(frame) => LiveFrame::Frame(frame),
        None => LiveFrame::Waiting,
    };
    // Room for three frames and a half: the fourth frame crosses the limit and is the last.
    let mut job = stepped_tracking(
        &scene,
        FrameFeed::Live {
            next: Box::new(next),
            fps: 30.0,
        },
    )
    .with_memory_limit(3 * frame_bytes + frame_bytes / 2);
    let started = web_time::Instant::now();
    let tracked = loop {
        // The camera never ends by itself: only the limit can end this recording.
        assert!(
            started.elapsed().as_secs() < 120,
            "the limit did not end the recording"
        );
        if let Some(result) = job.step(Duration::from_millis(50)) {
            break result.unwrap_or_else(|e| panic!("{e}"));
        }
    };
    assert_eq!(
        tracked.frames.len(),
        4,
        "the recording ends by itself at the limit"
    );
}

/// The browser's face-locating worker, as a thread: frames in, located faces back as
/// numbers, in order. `fails_after`: it stops (as a worker that crashed) after answering
/// that many frames.
struct ThreadLocator {
    frames: Option<std::sync::mpsc::Sender<(image::RgbImage, bool)>>,
    answers: std::sync::mpsc::Receiver<Result<Option<Vec<f32>>, String>>,
    answered: usize,
    fails_after: Option<usize>,
    sent_resets: Arc<std::sync::Mutex<Vec<bool>>>,
    /// The most frames sent and not yet answered at once.
    most_outstanding: Arc<std::sync::atomic::AtomicUsize>,
}

impl ThreadLocator {
    fn start(scene: &Scene, fails_after: Option<usize>) -> Self {
        let networks = scene.networks.clone().expect("networks");
        let (frames, inbox) = std::sync::mpsc::channel::<(image::RgbImage, bool)>();
        let (outbox, answers) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            let mut follower = networks
                .face_follower()
                .expect("follower")
                .expect("OpenSeeFace models");
            for (image, reset) in inbox {
                if reset {
                    follower.reset();
                }
                let answer = LocatedFace::follow(&mut follower, &image)
                    .map(|found| found.map(|face| face.to_f32s()))
                    .map_err(|e| e.to_string());
                if outbox.send(answer).is_err() {
                    break;
                }
            }
        });
        Self {
            frames: Some(frames),
            answers,
            answered: 0,
            fails_after,
            sent_resets: Arc::default(),
            most_outstanding: Arc::default(),
        }
    }
}

impl RemoteFaceLocator for ThreadLocator {
    fn send(&mut self, image: &image::RgbImage, reset: bool) -> Result<(), String> {
        let mut sent = self.sent_resets.lock().expect("lock");
        sent.push(reset);
        self.most_outstanding.fetch_max(
            sent.len() - self.answered,
            std::sync::atomic::Ordering::Relaxed,
        );
        let frames = self.frames.as_ref().ok_or("the worker stopped")?;
        frames
            .send((image.clone(), reset))
            .map_err(|_| "the worker stopped".to_string())
    }

    fn receive(&mut self) -> Option<LocatorReply> {
        if self.fails_after.is_some_and(|n| self.answered >= n) {
            self.frames = None;
            return Some(LocatorReply::Failed("the worker crashed".into()));
        }
        let answer = self.answers.try_recv().ok()?;
        self.answered += 1;
        Some(LocatorReply::Located(
            answer
                .map_err(tracking::TrackingError::Relayed)
                .and_then(|numbers| numbers.map(|n| LocatedFace::from_f32s(&n)).transpose()),
        ))
    }
}

fn run_to_end(mut job: SteppedTracking) -> likeness::stepped::Tracked {
    let started = web_time::Instant::now();
    loop {
        assert!(started.elapsed().as_secs() < 600, "the job never ended");
        if let Some(result) = job.step(Duration::from_millis(20)) {
            break result.unwrap_or_else(|e| panic!("{e}"));
        }
        // As the page does between UI frames: the locator works meanwhile.
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
}

#[test]
fn faces_located_beside_the_job_track_as_on_its_own_thread() {
    let scene = scene_with_networks();
    let config = DemoConfig {
        frames: 16,
        ..config()
    };
    let frames = clip(&scene, &config);
    let alone = run_to_end(stepped_tracking(
        &scene,
        FrameFeed::clip(frames.clone(), 30.0),
    ));
    let locator = ThreadLocator::start(&scene, None);
    let resets = locator.sent_resets.clone();
    let outstanding = locator.most_outstanding.clone();
    let job = stepped_tracking(&scene, FrameFeed::clip(frames.clone(), 30.0))
        .with_remote_locator(Some(Box::new(locator)));
    assert!(job.locating_beside());
    let beside = run_to_end(job);
    // The same frames, the same records, the same person, in the same order.
    assert_eq!(beside.frames.len(), 16);
    assert_eq!(beside.records, alone.records);
    assert_eq!(beside.selected_frames, alone.selected_frames);
    assert_eq!(beside.rate.frames, 16);
    // The worker's own time counts in the tracker's.
    assert!(beside.rate.stage_ms.landmarks_ms > 0.0);
    // Only the job's first frame starts the worker's face afresh.
    let resets = resets.lock().expect("lock").clone();
    assert_eq!(resets.len(), 16);
    assert!(resets[0] && resets[1..].iter().all(|r| !r), "{resets:?}");
    // A clip keeps the worker's queue full, within bounds.
    let most = outstanding.load(std::sync::atomic::Ordering::Relaxed);
    assert!((2..=12).contains(&most), "{most} frames outstanding");

    // A camera with a frame on every poll: a few frames outstanding at most, the rest of
    // the camera's frames are skipped rather than queued.
    let locator = ThreadLocator::start(&scene, None);
    let outstanding = locator.most_outstanding.clone();
    let camera_frames = frames.clone();
    let mut polls = 0usize;
    let camera = move || {
        polls += 1;
        LiveFrame::Frame(camera_frames[polls % camera_frames.len()].clone())
    };
    let mut live = stepped_tracking(
        &scene,
        FrameFeed::Live {
            next: Box::new(camera),
            fps: 30.0,
        },
    )
    .with_remote_locator(Some(Box::new(locator)));
    while live.rate.frames < 8 {
        assert!(live.step(Duration::from_millis(20)).is_none());
        std::thread::sleep(std::time::Duration::from_millis(1));
    }
    let most = outstanding.load(std::sync::atomic::Ordering::Relaxed);
    assert!((1..=3).contains(&most), "{most} camera frames outstanding");

    // A worker that crashes part way: the job finishes every frame on its own thread.
    let crashing = stepped_tracking(&scene, FrameFeed::clip(frames, 30.0))
        .with_remote_locator(Some(Box::new(ThreadLocator::start(&scene, Some(5)))));
    let recovered = run_to_end(crashing);
    assert_eq!(recovered.records.len(), 16);
    assert!(
        recovered.records.iter().all(|r| r.face),
        "every frame shows the face"
    );
    // Personalization saw other landmarks, so the final records differ; what the worker
    // answered before it crashed was tracked as before.
    for k in 0..5 {
        let (a, b) = (&recovered.outputs[k], &alone.outputs[k]);
        assert_eq!((a.crop, a.tracknet), (b.crop, b.tracknet), "frame {k}");
    }
}
