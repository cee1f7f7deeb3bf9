//! The tracker end to end on held-out synthetic clips (python -m likeness_train.clips):
//! faces found and followed, landmarks close to the truth, refinement reducing the error;
//! pre-cropped input without the OpenSeeFace models; NaN network outputs becoming "no
//! face" records; personalization producing a session.

mod common;

use std::sync::Arc;

use common::face_model;
use tracking::backend::{BackendChoice, BackendKind, InferenceBackend, Tensor};
use tracking::evaluate::{Clip, default_clips_dir};
use tracking::networks::{Manifest, TrackNet, default_networks_dir};
use tracking::pipeline::{LocatedFace, LocatorChoice, Tracker, TrackerConfig};
use tracking::source::{FrameSource, Next};

fn clip() -> Clip {
    let root = default_clips_dir();
    let mut clips = Clip::load_all(&root).unwrap_or_else(|e| panic!("{e} (run training/setup.sh)"));
    clips.remove(0)
}

fn nme(landmarks: &[[f32; 2]], truth: &tracking::evaluate::TruthFrame) -> f32 {
    let norm = (truth.face_box[2] * truth.face_box[3]).sqrt();
    landmarks
        .iter()
        .zip(&truth.landmarks_68)
        .map(|(a, b)| glam::Vec2::from(*a).distance(glam::Vec2::from(*b)))
        .sum::<f32>()
        / (68.0 * norm)
}

#[test]
fn tracks_a_held_out_clip_and_refinement_reduces_landmark_error() {
    let clip = clip();
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::Tract),
        fov_deg: Some(clip.fov_deg()),
        locator: LocatorChoice::Landmarks,
        refine: None,
        smoothing: tracking::smooth::SmoothingConfig::off(),
        ..TrackerConfig::default()
    };
    let refine_config = tracking::refine::RefineConfig::default();
    let mut tracker = Tracker::new(face_model(), config, true).expect("tracker");
    let mut source = clip.source();
    let mut outputs = Vec::new();
    loop {
        match source.next_frame().expect("frame") {
            Next::Frame(f) => outputs.push(tracker.process(&f)),
            Next::End => break,
            Next::Skipped(s) => panic!("clip frame unreadable: {}", s.error),
        }
    }
    assert!(
        outputs.iter().all(|o| o.record.face),
        "every frame of the clip has a face"
    );
    let (w, h) = (clip.truth.width, clip.truth.height);
    tracker.set_refine(Some(refine_config));
    tracker.reset();
    let (mut before, mut after) = (0.0, 0.0);
    for (o, truth) in outputs.iter().zip(&clip.truth.frames) {
        let refined = tracker.retrack(o, w, h);
        before += nme(&o.record.track.as_ref().unwrap().landmarks_68, truth);
        after += nme(&refined.track.as_ref().unwrap().landmarks_68, truth);
    }
    let n = outputs.len() as f32;
    let (before, after) = (before / n, after / n);
    eprintln!(
        "NME TrackNet {:.2} %, refined {:.2} %",
        100.0 * before,
        100.0 * after
    );
    assert!(
        before < 0.15,
        "TrackNet's landmarks are far off: NME {before}"
    );
    assert!(
        after < before,
        "refinement did not help: {before} -> {after}"
    );
    // The identity fitted to the whole clip (tracking::identity) explains the detected
    // points better than the template, is used from then on, and keeps the landmarks about
    // as close to the truth (on these clips a detector's fixed offsets limit what it gains,
    // tracking/README.md).
    let fit = tracker
        .fit_identity(
            &outputs,
            w,
            h,
            &tracking::identity::IdentityConfig::default(),
        )
        .expect("identity fit");
    assert_eq!(fit.frames, outputs.len());
    assert!(
        fit.rms_after_px < fit.rms_before_px,
        "the identity did not explain the points better: {fit:?}"
    );
    assert!(fit.coefficients.iter().any(|a| a.abs() > 0.01), "{fit:?}");
    tracker.reset();
    let mut with_identity = 0.0;
    for (o, truth) in outputs.iter().zip(&clip.truth.frames) {
        with_identity += nme(
            &tracker
                .retrack(o, w, h)
                .track
                .as_ref()
                .unwrap()
                .landmarks_68,
            truth,
        );
    }
    let with_identity = with_identity / n;
    assert!(
        with_identity < 1.1 * after,
        "the clip's identity moved the landmarks away from the truth: {after} -> {with_identity}"
    );
    // Detection ran once; the follower kept the face afterwards.
    assert!(outputs[0].times.detect_ms > 0.0);
    assert!(
        outputs[1..]
            .iter()
            .filter(|o| o.times.detect_ms > 0.0)
            .count()
            <= 1
    );
}

#[test]
fn precropped_input_works_without_the_landmark_models_but_footage_does_not() {
    let empty = common::temp_dir("no-models");
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::Tract),
        models_dir: empty.clone(),
        smoothing: tracking::smooth::SmoothingConfig::off(),
        ..TrackerConfig::default()
    };
    // Images: the locator falls back to treating each image as a crop.
    let mut tracker = Tracker::new(face_model(), config.clone(), false).expect("tracker");
    assert!(!tracker.uses_landmarks());
    let image = image::RgbImage::from_fn(128, 128, |x, y| {
        image::Rgb([(x * 2) as u8, (y * 2) as u8, 128])
    });
    let out = tracker.process(&tracking::source::Frame {
        index: 0,
        time_s: 0.0,
        image,
        path: None,
    });
    assert!(out.record.face, "{:?}", out.record.note);
    let t = out.record.track.expect("track");
    assert!(t.weights.iter().all(|w| (0.0..=1.0).contains(w)));
    assert_eq!(t.confidence, 1.0);
    // Footage: a clear message.
    let err = Tracker::new(face_model(), config, true)
        .err()
        .expect("error")
        .to_string();
    assert!(
        err.contains("face detection") && err.contains(empty.to_str().unwrap()),
        "{err}"
    );
}

/// A backend whose outputs are NaN.
struct NanBackend;

impl InferenceBackend for NanBackend {
    fn kind(&self) -> BackendKind {
        BackendKind::Tract
    }
    fn run(&mut self, input: &Tensor) -> tracking::Result<Vec<Tensor>> {
        let b = input.shape[0];
        Ok(vec![
            Tensor::new(vec![b, 53], vec![f32::NAN; b * 53])?,
            Tensor::zeros(vec![b, 3]),
            Tensor::zeros(vec![b, 3]),
            Tensor::zeros(vec![b, 27]),
        ])
    }
}

#[test]
fn nan_network_outputs_are_reported_not_propagated() {
    let manifest = Manifest::load(&default_networks_dir()).expect("manifest");
    let mut net = TrackNet::from_backend(Box::new(NanBackend), &manifest);
    let s = manifest.track_input_size;
    let out = net.run(&Tensor::zeros(vec![2, 3, s, s])).expect("run");
    assert_eq!(out.len(), 2);
    for o in out {
        let e = o.expect_err("NaN is an error").to_string();
        assert!(e.contains("NaN"), "{e}");
    }
    let bad = net
        .run(&Tensor::zeros(vec![1, 3, 64, 64]))
        .expect_err("wrong size")
        .to_string();
    assert!(bad.contains("TrackNet takes"), "{bad}");
    let mut nan = tracking::networks::corrections_from_outputs(&[
        Tensor::zeros(vec![1, 3, 128, 128]),
        Tensor::zeros(vec![1, 53, 3, 128, 128]),
        Tensor::zeros(vec![1, 3, 128, 128]),
        Tensor::zeros(vec![1, 53, 3, 128, 128]),
    ]);
    assert!(nan.is_ok());
    let mut dr = Tensor::zeros(vec![1, 53, 3, 128, 128]);
    dr.data[12345] = f32::INFINITY;
    nan = tracking::networks::corrections_from_outputs(&[
        Tensor::zeros(vec![1, 3, 128, 128]),
        Tensor::zeros(vec![1, 53, 3, 128, 128]),
        Tensor::zeros(vec![1, 3, 128, 128]),
        dr,
    ]);
    let e = nan.expect_err("inf is an error").to_string();
    assert!(e.contains("dR"), "{e}");
}

#[test]
fn missing_networks_and_runtime_choices_are_clear() {
    let empty = common::temp_dir("no-networks");
    let config = TrackerConfig {
        networks_dir: empty,
        backend: BackendChoice::Only(BackendKind::Tract),
        ..TrackerConfig::default()
    };
    let e = Tracker::new(face_model(), config, false)
        .err()
        .expect("error")
        .to_string();
    assert!(
        e.contains("manifest.json") && e.contains("assets/models"),
        "{e}"
    );
    assert!("cuda".parse::<BackendChoice>().is_err());
    let _ = Arc::new(0);
}

#[test]
fn refinement_brings_the_model_closer_to_the_detected_landmarks_on_a_real_face() {
    let crop = common::repo().join("../shared/testdata/faces/openseeface-raw1.png");
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::Tract),
        ..TrackerConfig::default()
    };
    let a =
        tracking::evaluate::real_crop_agreement(face_model(), &crop, &config).expect("real crop");
    eprintln!(
        "real crop NME against OpenSeeFace: TrackNet {:.2} %, refined {:.2} %",
        100.0 * a.tracknet_nme,
        100.0 * a.refined_nme
    );
    assert!(
        a.tracknet_nme < 0.2,
        "TrackNet is lost on the real face: {}",
        a.tracknet_nme
    );
    // The shipped priors hold the fit near TrackNet's estimate: refinement takes 0.7-1.0
    // points of NME off (4.72 -> 4.02 % with the TrackNet of 2026-12-07 afternoon, 5.36 ->
    // 4.34 % at noon, 4.79 -> 3.79 % before); no refinement would take none. The better
    // TrackNet starts, the smaller the share it leaves to close, so the bound is absolute.
    assert!(
        a.refined_nme < a.tracknet_nme - 0.005,
        "refinement gained too little: {a:?}"
    );
}

/// The clip's first frames, then a frame that cannot be decoded, more frames, and then a
/// broken stream (as when a video file is cut off).
struct ScriptedSource {
    inner: tracking::source::ImageFiles,
    delivered: usize,
    skip_at: usize,
    break_at: usize,
}

impl FrameSource for ScriptedSource {
    fn next_frame(&mut self) -> tracking::Result<Next> {
        self.delivered += 1;
        if self.delivered == self.break_at {
            return Err(tracking::TrackingError::InvalidInput(
                "the stream broke".into(),
            ));
        }
        match self.inner.next_frame()? {
            Next::Frame(f) if self.delivered == self.skip_at => {
                Ok(Next::Skipped(tracking::source::FrameError {
                    index: f.index,
                    time_s: f.time_s,
                    error: tracking::TrackingError::InvalidInput("corrupt frame".into()),
                }))
            }
            other => Ok(other),
        }
    }
    fn len_hint(&self) -> Option<usize> {
        None
    }
    fn fps(&self) -> f64 {
        self.inner.fps()
    }
    fn describe(&self) -> String {
        "scripted".into()
    }
}

#[test]
fn the_two_stage_pipeline_gives_the_frame_by_frame_results_and_keeps_them_when_footage_breaks() {
    use std::ops::ControlFlow;
    use tracking::pipeline::TrackEvent;
    let clip = clip();
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::Tract),
        fov_deg: Some(clip.fov_deg()),
        locator: LocatorChoice::Landmarks,
        // Smoothing on: its state must see the frames in order, as frame by frame.
        ..TrackerConfig::default()
    };
    let mut tracker = Tracker::new(face_model(), config, true).expect("tracker");
    // Frame by frame, as the pipeline should see it: frames 1, 2, 4, 5, 6 (the 3rd is
    // unreadable and simply absent), then the stream breaks at the 7th read.
    let mut expected = Vec::new();
    let mut source = clip.source();
    for k in 1..=6 {
        match source.next_frame().expect("frame") {
            Next::Frame(_) if k == 3 => expected.push(None),
            Next::Frame(f) => expected.push(Some(tracker.process(&f).record)),
            _ => panic!("clip too short"),
        }
    }
    let mut scripted = ScriptedSource {
        inner: clip.source(),
        delivered: 0,
        skip_at: 3,
        break_at: 7,
    };
    let mut streamed = Vec::new();
    let result = tracker.track_source(&mut scripted, |event| {
        streamed.push(match event {
            TrackEvent::Frame(_, out) => Some(out.record),
            TrackEvent::Skipped(skip) => {
                assert_eq!(skip.index, 2, "the unreadable frame keeps its index");
                None
            }
        });
        ControlFlow::Continue(())
    });
    let error = result.expect_err("the broken stream is reported");
    assert!(error.to_string().contains("the stream broke"), "{error}");
    assert_eq!(
        streamed.len(),
        6,
        "everything before the break is delivered"
    );
    for (k, (a, b)) in expected.iter().zip(&streamed).enumerate() {
        assert_eq!(
            a, b,
            "frame {k} differs between the pipeline and frame by frame"
        );
    }
    assert!(expected.iter().flatten().all(|r| r.face));

    // Stopping early: the callback's Break ends the call after that frame.
    let mut seen = 0;
    tracker
        .track_source(&mut clip.source(), |_| {
            seen += 1;
            if seen == 2 {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        })
        .expect("a clean stop is not an error");
    assert_eq!(seen, 2);
    // The tracker is whole again afterwards: frame by frame still finds the face.
    let Next::Frame(f) = clip.source().next_frame().expect("frame") else {
        panic!("no frame")
    };
    assert!(tracker.process(&f).record.face);
}

/// The browser locates faces in a Web Worker and tracks the rest on the page's thread; the
/// locating stage's result crosses as numbers. Tracking that way must be tracking.
#[test]
fn a_face_located_elsewhere_and_sent_as_numbers_tracks_as_in_one_tracker() {
    let clip = clip();
    let networks = tracking::bundle::NetworkBytes::read(
        &default_networks_dir(),
        Some(&tracking::openseeface::default_models_dir()),
    )
    .expect("networks and OpenSeeFace models");
    let config = TrackerConfig {
        fov_deg: Some(clip.fov_deg()),
        ..TrackerConfig::default()
    };
    let mut whole = networks
        .tracker(face_model(), config.clone(), true)
        .expect("tracker");
    let mut split = networks
        .tracker(face_model(), config, true)
        .expect("tracker");
    let mut follower = networks
        .face_follower()
        .expect("follower")
        .expect("OpenSeeFace models were given");
    let mut source = clip.source();
    for k in 0..8 {
        let Next::Frame(frame) = source.next_frame().expect("frame") else {
            panic!("clip frame {k} unreadable");
        };
        let expected = whole.process(&frame);
        let located = LocatedFace::follow(&mut follower, &frame.image)
            .expect("located")
            .expect("the clip shows a face");
        let numbers = located.to_f32s();
        assert_eq!(numbers.len(), tracking::pipeline::LOCATED_FACE_F32S);
        let received = LocatedFace::from_f32s(&numbers).expect("the flat form reads back");
        let output = split.process_located(&frame, Ok(Some(received)));
        assert!(expected.record.face);
        assert_eq!(output.record, expected.record, "frame {k}");
        assert_eq!(output.crop, expected.crop, "frame {k}");
    }
    // An error of the locating stage is that frame's "no face" record, saying why; the
    // next frame tracks again.
    let Next::Frame(frame) = source.next_frame().expect("frame") else {
        panic!("clip frame unreadable");
    };
    let failed = split.process_located(
        &frame,
        Err(tracking::TrackingError::Relayed("the worker broke".into())),
    );
    assert!(!failed.record.face);
    assert!(format!("{:?}", failed.record).contains("the worker broke"));
    let located = LocatedFace::follow(&mut follower, &frame.image).expect("located");
    assert!(split.process_located(&frame, Ok(located)).record.face);
}

/// The browser's MediaPipe locator: the tracker made from fetched bytes tracks as the one
/// loaded from files (both on tract), and the worker's follower, made from the networks and
/// the 68 points sent as numbers (it has no template), locates the face as that tracker's.
#[test]
fn mediapipe_from_bytes_tracks_as_from_files_and_in_a_worker() {
    let clip = clip();
    let mediapipe_dir = tracking::mediapipe::default_models_dir();
    let mut networks =
        tracking::bundle::NetworkBytes::read(&default_networks_dir(), None).expect("networks");
    let config = TrackerConfig {
        fov_deg: Some(clip.fov_deg()),
        backend: BackendChoice::Only(BackendKind::Tract),
        locator: LocatorChoice::MediaPipe,
        mediapipe_dir: mediapipe_dir.clone(),
        ..TrackerConfig::default()
    };
    let refused = networks
        .tracker(face_model(), config.clone(), true)
        .err()
        .expect("MediaPipe's locator without its models");
    assert!(
        refused.to_string().contains("face_landmark.onnx"),
        "{refused}"
    );
    networks.mediapipe =
        Some(tracking::bundle::MediaPipeBytes::read(&mediapipe_dir).expect("MediaPipe models"));
    let mut from_files = Tracker::new(face_model(), config.clone(), true).expect("tracker");
    let mut from_bytes = networks
        .tracker(face_model(), config.clone(), true)
        .expect("tracker");
    let mut split = networks
        .tracker(face_model(), config, true)
        .expect("tracker");
    let bytes = networks.mediapipe.as_ref().expect("set above");
    let points = bytes
        .correspondence
        .ibug68_points(&face_model().template)
        .expect("points");
    let numbers = tracking::mediapipe::ibug68_points_to_f32s(&points);
    let received = tracking::mediapipe::ibug68_points_from_f32s(&numbers).expect("read back");
    assert_eq!(received, points);
    let mut worker = tracking::bundle::mesh_follower(&bytes.detector, &bytes.mesh, received)
        .expect("the worker's follower");
    let mut source = clip.source();
    for k in 0..4 {
        let Next::Frame(frame) = source.next_frame().expect("frame") else {
            panic!("clip frame {k} unreadable");
        };
        let expected = from_files.process(&frame);
        assert!(expected.record.face, "frame {k}");
        assert!(
            expected.dense_observations.is_some(),
            "refined on the dense points"
        );
        let output = from_bytes.process(&frame);
        assert_eq!(output.record, expected.record, "frame {k}");
        let located = LocatedFace::follow_mesh(&mut worker, &frame.image)
            .expect("located")
            .expect("the clip shows a face");
        let sent = LocatedFace::from_f32s(&located.to_f32s()).expect("the flat form reads back");
        let output = split.process_located(&frame, Ok(Some(sent)));
        assert_eq!(output.record, expected.record, "frame {k}");
    }
}

/// The points' flat form refuses what is not such points.
#[test]
fn ibug68_points_from_bad_numbers_are_refused() {
    use tracking::mediapipe::{IBUG68_POINTS_F32S, ibug68_points_from_f32s};
    assert!(ibug68_points_from_f32s(&[0.0; 5]).is_err());
    let mut numbers = vec![0.0f32; IBUG68_POINTS_F32S];
    assert!(ibug68_points_from_f32s(&numbers).is_ok());
    numbers[6] = 468.0;
    assert!(ibug68_points_from_f32s(&numbers).is_err());
    numbers[6] = 1.5;
    assert!(ibug68_points_from_f32s(&numbers).is_err());
    numbers[6] = 3.0;
    numbers[7] = f32::NAN;
    let refused = ibug68_points_from_f32s(&numbers).expect_err("a NaN weight");
    assert!(refused.to_string().contains("landmark 1"), "{refused}");
}

/// Issue 31, item 4: the default refinement (its weight sparsity chosen on clips of seed
/// 9002, tracking/README.md) may never make the held-out clips' expression MAE worse than
/// TrackNet alone, and still lowers their landmark error.
#[test]
fn the_default_refinement_never_raises_the_held_out_expression_error() {
    let clips = Clip::load_all(&default_clips_dir())
        .unwrap_or_else(|e| panic!("{e} (run training/setup.sh)"));
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::OnnxRuntime),
        locator: LocatorChoice::Landmarks,
        refine: None,
        smoothing: tracking::smooth::SmoothingConfig::off(),
        ..TrackerConfig::default()
    };
    let default = tracking::refine::RefineConfig::default();
    let tuning = tracking::evaluate::tune_refinement(face_model(), &clips, &config, &[default])
        .expect("tracking the held-out clips");
    let (tracknet, refined) = (&tuning.tracknet, &tuning.rows[0].1);
    eprintln!(
        "held-out clips: expression MAE TrackNet {:.4}, refined {:.4}; NME {:.2} % -> {:.2} %",
        tracknet.expression_mae,
        refined.expression_mae,
        100.0 * tracknet.landmark_nme,
        100.0 * refined.landmark_nme
    );
    assert!(tracknet.frames > 100, "{} frames tracked", tracknet.frames);
    assert!(
        refined.expression_mae <= tracknet.expression_mae,
        "the default refinement raised the held-out expression MAE: {} -> {}",
        tracknet.expression_mae,
        refined.expression_mae
    );
    assert!(
        refined.landmark_nme < tracknet.landmark_nme,
        "the default refinement did not lower the landmark error: {} -> {}",
        tracknet.landmark_nme,
        refined.landmark_nme
    );
}

/// Issue 32: a frame without a face says why, in the locator's terms; the same tracker
/// then finds the real face (the MediaPipe locator also in the 224 px close-up, which
/// OpenSeeFace's detector misses, and that miss is explained too).
#[test]
fn every_frame_without_a_face_says_why() {
    let grey = image::RgbImage::from_pixel(640, 480, image::Rgb([128, 128, 128]));
    let close_up =
        image::open(common::repo().join("../shared/testdata/faces/openseeface-raw1.png"))
            .expect("the real crop")
            .to_rgb8();
    for (locator, name) in [
        (LocatorChoice::Landmarks, "OpenSeeFace"),
        (LocatorChoice::MediaPipe, "BlazeFace"),
    ] {
        let config = TrackerConfig {
            backend: BackendChoice::Only(BackendKind::Tract),
            locator,
            ..TrackerConfig::default()
        };
        let mut tracker = Tracker::new(face_model(), config, true).unwrap();
        let frame = |index: usize, image: &image::RgbImage| tracking::source::Frame {
            index,
            time_s: index as f64 / 30.0,
            image: image.clone(),
            path: None,
        };
        let out = tracker.process(&frame(0, &grey));
        assert!(!out.record.face);
        let note = out.record.note.clone().unwrap_or_default();
        assert!(
            note.starts_with("no face found") && note.contains(name),
            "{locator:?}: {note}"
        );
        let out = tracker.process(&frame(1, &close_up));
        match locator {
            LocatorChoice::MediaPipe => assert!(out.record.face, "{:?}", out.record.note),
            _ => assert!(
                !out.record.face
                    && out
                        .record
                        .note
                        .is_some_and(|n| n.contains("--locator mediapipe")),
                "OpenSeeFace on the close-up"
            ),
        }
    }
}

/// Issue 32, item 2: with the MediaPipe locator, refinement fits Face Mesh's 468 points
/// through the ICT correspondence: on a held-out clip every frame carries them, the fit
/// brings the model's corresponding vertices closer to them than TrackNet's estimate, and
/// the landmark error against the truth stays within 15 % of TrackNet's. (It does not
/// lower it: with the TrackNet shipped on 2026-12-07, TrackNet's own landmarks, 2.0 % NME
/// on these frames, are nearer the truth than Face Mesh's points over the template's
/// landmarks; tracking/README.md.)
#[test]
fn the_mediapipe_locator_refines_on_all_468_points() {
    use tracking::mediapipe::{IctCorrespondence, default_models_dir};
    let clip = clip();
    let config = TrackerConfig {
        backend: BackendChoice::Only(BackendKind::OnnxRuntime),
        fov_deg: Some(clip.fov_deg()),
        locator: LocatorChoice::MediaPipe,
        smoothing: tracking::smooth::SmoothingConfig::off(),
        ..TrackerConfig::default()
    };
    let mut tracker = Tracker::new(face_model(), config, true).expect("tracker");
    assert_eq!(tracker.locator_name(), "mediapipe");
    let vertices = IctCorrespondence::load(&default_models_dir())
        .expect("correspondence")
        .vertices;
    let blendshapes = face_model().template_blendshapes();
    let (width, height) = (clip.truth.width, clip.truth.height);
    let k = tracker.intrinsics(width, height);
    // Mean pixel distance of the corresponding vertices under `params` to the observed points.
    let to_points = |params: &tracking::FaceParams,
                     observed: &tracking::refine::LandmarkObservations| {
        let w = params.blendshape_weights();
        observed
            .points
            .iter()
            .map(|o| {
                let p = blendshapes.vertex(vertices[o.index] as usize, &w);
                k.project(params.pose.transform(p))
                    .expect("in front")
                    .distance(o.pixel)
            })
            .sum::<f32>()
            / observed.points.len() as f32
    };
    let mut source = clip.source();
    let (mut before, mut after, mut fit_before, mut fit_after, mut frames) =
        (0.0f32, 0.0f32, 0.0f32, 0.0f32, 0usize);
    while let Next::Frame(frame) = source.next_frame().expect("frame") {
        let truth = &clip.truth.frames[frame.index];
        let out = tracker.process(&frame);
        assert!(
            out.record.face,
            "frame {}: {:?}",
            frame.index, out.record.note
        );
        let dense = out.dense_observations.as_ref().expect("dense points");
        assert_eq!(dense.len(), 468);
        let (tracknet, refined) = (
            out.tracknet.expect("TrackNet"),
            out.refined.expect("refined"),
        );
        fit_before += to_points(&tracknet, dense);
        fit_after += to_points(&refined, dense);
        let unrefined = tracker.project_landmarks(&tracknet, &k);
        let refined = tracker.project_landmarks(&refined, &k);
        before += nme(&unrefined.map(|p| p.to_array()), truth);
        after += nme(&refined.map(|p| p.to_array()), truth);
        frames += 1;
        if frames == 24 {
            break;
        }
    }
    let n = frames as f32;
    eprintln!(
        "{frames} frames: to Face Mesh's points {:.2} -> {:.2} px; landmark NME TrackNet {:.4}, refined {:.4}",
        fit_before / n,
        fit_after / n,
        before / n,
        after / n
    );
    // 3.29 -> 2.68 px with the TrackNet of 2026-12-07 noon (3.43 -> 2.57 px before): the
    // priors hold the fit near TrackNet's estimate (tracking/README.md, "What refinement
    // can do for the weights at best"); a fit that ignored the points would stay at 1.0.
    assert!(
        fit_after < 0.85 * fit_before,
        "the fit did not approach the points: {fit_before} -> {fit_after} px"
    );
    assert!(after < 1.15 * before, "TrackNet {before}, refined {after}");
}

#[test]
fn the_manifest_gives_each_network_its_input_size() {
    // A manifest from before TrackNet and ModelNet could differ has `input_size` alone,
    // and it is both networks' size; `track_input_size` is TrackNet's (160 px beside a
    // 128 px ModelNet); an implausible size is refused by name.
    let dir = default_networks_dir();
    let text = std::fs::read_to_string(dir.join("manifest.json")).expect("manifest.json");
    let mut json: serde_json::Value = serde_json::from_str(&text).expect("JSON");
    let object = json.as_object_mut().expect("an object");
    object.remove("track_input_size");
    let web = object.remove("web_track_net");
    object.insert("input_size".into(), 128.into());
    let old = Manifest::from_json(&dir, &json.to_string()).expect("an older manifest");
    assert_eq!((old.input_size, old.track_input_size), (128, 128));
    assert_eq!(
        old.for_web(),
        old,
        "no web TrackNet: the browser reads what native does"
    );
    json["track_input_size"] = 160.into();
    let both = Manifest::from_json(&dir, &json.to_string()).expect("two sizes");
    assert_eq!((both.input_size, both.track_input_size), (128, 160));
    // TrackNet's translation refers to its own input's focal length.
    let ratio = both.reference_focal_px() / old.reference_focal_px();
    assert!((ratio - 1.25).abs() < 1e-5, "{ratio}");
    // The browser's TrackNet: its own size for the browser, nothing changed natively.
    json["web_track_net"] = serde_json::json!({"file": "track_net_web.onnx", "input_size": 128});
    let with_web = Manifest::from_json(&dir, &json.to_string()).expect("a web TrackNet");
    assert_eq!(with_web.track_input_size, 160);
    assert_eq!(with_web.for_web().track_input_size, 128);
    assert_eq!(with_web.for_web().input_size, 128);
    for file in ["../track_net.onnx", "", "models/a.onnx"] {
        json["web_track_net"]["file"] = file.into();
        let e = Manifest::from_json(&dir, &json.to_string())
            .expect_err("not a file name")
            .to_string();
        assert!(e.contains("is not a file name"), "{e}");
    }
    // The shipped manifest names one (the export always writes it).
    assert!(web.is_some(), "the shipped manifest has no web_track_net");
    json["web_track_net"] = web.expect("checked");
    json["track_input_size"] = 4096.into();
    let e = Manifest::from_json(&dir, &json.to_string())
        .expect_err("implausible")
        .to_string();
    assert!(e.contains("track_input_size 4096"), "{e}");
    // TrackNet refuses a crop of ModelNet's size when its own differs.
    let mut net = TrackNet::from_backend(Box::new(NanBackend), &both);
    let e = net
        .run(&Tensor::zeros(vec![1, 3, 128, 128]))
        .expect_err("wrong size")
        .to_string();
    assert!(e.contains("[B, 3, 160, 160]"), "{e}");
}
