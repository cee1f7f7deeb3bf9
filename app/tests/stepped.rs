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
use likeness::stepped::{FrameFeed, LiveFrame, SteppedTracking};
use renderer::OffscreenRenderer;
use tracking::bundle::NetworkBytes;
use tracking::pipeline::TrackerConfig;
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
