//! OpenSeeFace detection, landmarks and face following on a real face, with both backends.
//!
//! The models live outside the repository (`default_models_dir()`); when they are missing
//! these tests fail with the loader's message, which says where to get them. The ONNX
//! Runtime tests fail when its library cannot be loaded: the setup installs it.

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use glam::Vec2;
use image::{Rgb, RgbImage};
use tracking::openseeface::{
    FaceFollower, Landmarks66, OpenSeeFace, default_models_dir, model_files,
};
use tracking::preprocess::Rect;
use tracking::{BackendKind, TrackingError};

const CROP_SIDE: u32 = 224;
const CANVAS_WIDTH: u32 = 640;
const CANVAS_HEIGHT: u32 = 480;
const GREY: Rgb<u8> = Rgb([128, 128, 128]);

// The real crop is put in a webcam-sized frame (`frame_with_face`): the detector is made
// for whole frames, and on the bare crop, which the face fills completely, its peak stays
// just below upstream's threshold (0.58 against 0.6).
use common::{FACE_FEATURES_IN_CROP, frame_with_face, real_crop, require_onnxruntime};

fn load(kind: BackendKind) -> OpenSeeFace {
    if kind == BackendKind::OnnxRuntime {
        require_onnxruntime();
    }
    match OpenSeeFace::load(&default_models_dir(), kind, 2) {
        Ok(tracker) => tracker,
        Err(e) => panic!("cannot load the OpenSeeFace models for {kind}: {e}"),
    }
}

fn contains(rect: Rect, p: Vec2) -> bool {
    p.x >= rect.x && p.x <= rect.x + rect.width && p.y >= rect.y && p.y <= rect.y + rect.height
}

fn mean_point(landmarks: &Landmarks66, range: std::ops::Range<usize>) -> Vec2 {
    let n = range.len() as f32;
    range.map(|i| landmarks.points_in_frame[i]).sum::<Vec2>() / n
}

// --- detection ---------------------------------------------------------------------------

fn detects_exactly_the_real_face(kind: BackendKind) {
    let mut tracker = load(kind);
    let offset = (300, 200);
    let frame = frame_with_face(&real_crop(), offset);
    let detections = tracker.detect(&frame).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(detections.len(), 1, "{kind}: {detections:?}");
    let face = detections[0];
    assert!(
        face.confidence >= 0.6 && face.confidence <= 1.0,
        "{kind}: {face:?}"
    );
    for (x, y) in FACE_FEATURES_IN_CROP {
        let feature = Vec2::new(x + offset.0 as f32, y + offset.1 as f32);
        assert!(
            contains(face.face_box, feature),
            "{kind}: {face:?} misses {feature}"
        );
    }
    assert!(
        (100.0..300.0).contains(&face.face_box.width)
            && (100.0..300.0).contains(&face.face_box.height),
        "{kind}: box size {face:?} is not a face's"
    );
}

#[test]
fn tract_detects_exactly_the_real_face() {
    detects_exactly_the_real_face(BackendKind::Tract);
}

#[test]
fn onnxruntime_detects_exactly_the_real_face() {
    detects_exactly_the_real_face(BackendKind::OnnxRuntime);
}

fn finds_no_face_in_grey_or_noise(kind: BackendKind) {
    let mut tracker = load(kind);
    let grey = RgbImage::from_pixel(CANVAS_WIDTH, CANVAS_HEIGHT, GREY);
    let grey_faces = tracker.detect(&grey).unwrap_or_else(|e| panic!("{e}"));
    assert!(grey_faces.is_empty(), "{kind} on grey: {grey_faces:?}");
    // xorshift32: reproducible noise without a dependency.
    let mut state = 0x9E37_79B9_u32;
    let noise = RgbImage::from_fn(CANVAS_WIDTH, CANVAS_HEIGHT, |_, _| {
        let mut channel = || {
            state ^= state << 13;
            state ^= state >> 17;
            state ^= state << 5;
            (state >> 24) as u8
        };
        Rgb([channel(), channel(), channel()])
    });
    let noise_faces = tracker.detect(&noise).unwrap_or_else(|e| panic!("{e}"));
    assert!(noise_faces.is_empty(), "{kind} on noise: {noise_faces:?}");
}

#[test]
fn tract_finds_no_face_in_grey_or_noise() {
    finds_no_face_in_grey_or_noise(BackendKind::Tract);
}

#[test]
fn onnxruntime_finds_no_face_in_grey_or_noise() {
    finds_no_face_in_grey_or_noise(BackendKind::OnnxRuntime);
}

// --- landmarks ---------------------------------------------------------------------------

/// Detects the face in the real crop pasted into a frame and returns its landmarks and the
/// pasted crop's rectangle.
fn landmarks_of_real_face(tracker: &mut OpenSeeFace) -> (Landmarks66, Rect) {
    let offset = (300, 200);
    let frame = frame_with_face(&real_crop(), offset);
    let detections = tracker.detect(&frame).unwrap_or_else(|e| panic!("{e}"));
    let Some(face) = detections.first() else {
        panic!("{}: no face detected", tracker.kind());
    };
    let landmarks = tracker
        .landmarks(&frame, face.face_box)
        .unwrap_or_else(|e| panic!("{e}"));
    let pasted = Rect {
        x: offset.0 as f32,
        y: offset.1 as f32,
        width: CROP_SIDE as f32,
        height: CROP_SIDE as f32,
    };
    (landmarks, pasted)
}

fn landmarks_have_sane_anatomy(kind: BackendKind) {
    let mut tracker = load(kind);
    let (landmarks, pasted) = landmarks_of_real_face(&mut tracker);
    let p = &landmarks.points_in_frame;
    for (i, point) in p.iter().enumerate() {
        assert!(
            contains(pasted, *point),
            "{kind}: point {i} at {point} is off the face image"
        );
    }
    assert!(
        landmarks.mean_confidence > 0.7,
        "{kind}: mean confidence {}",
        landmarks.mean_confidence
    );
    let brows = mean_point(&landmarks, 17..27).y;
    let eyes = mean_point(&landmarks, 36..48).y;
    let nose_tip = p[30].y;
    let mouth = mean_point(&landmarks, 48..66).y;
    let chin = p[8].y;
    assert!(
        brows < eyes && eyes < nose_tip && nose_tip < mouth && mouth < chin,
        "{kind}: brows {brows}, eyes {eyes}, nose tip {nose_tip}, mouth {mouth}, chin {chin}"
    );
    // The jaw runs from the image-left side of the face over the chin to the image-right.
    assert!(
        p[0].x < p[8].x && p[8].x < p[16].x,
        "{kind}: jaw {:?}",
        &p[0..17]
    );
    let left_side = p[0..4].iter().map(|q| q.x).fold(f32::MIN, f32::max);
    let right_side = p[13..17].iter().map(|q| q.x).fold(f32::MAX, f32::min);
    assert!(left_side < right_side, "{kind}: jaw {:?}", &p[0..17]);
    // The image-left eye (36-41) is left of the image-right eye (42-47).
    assert!(mean_point(&landmarks, 36..42).x < mean_point(&landmarks, 42..48).x);
}

#[test]
fn tract_landmarks_have_sane_anatomy() {
    landmarks_have_sane_anatomy(BackendKind::Tract);
}

#[test]
fn onnxruntime_landmarks_have_sane_anatomy() {
    landmarks_have_sane_anatomy(BackendKind::OnnxRuntime);
}

/// The mouth in the iBUG layout is a closed outer contour 48-59 around an inner one with
/// 61-63 above 67-65: this fails if OpenSeeFace's mouth order is mapped wrongly.
#[test]
fn ibug68_mouth_from_the_real_face_is_well_formed() {
    let mut tracker = load(BackendKind::Tract);
    let (landmarks, _) = landmarks_of_real_face(&mut tracker);
    let ibug = landmarks.to_ibug68();
    assert!(ibug[60].is_none() && ibug[64].is_none());
    let point = |i: usize| match ibug[i] {
        Some((p, _)) => p,
        None => panic!("iBUG point {i} missing"),
    };
    for i in (0..68).filter(|&i| i != 60 && i != 64) {
        assert!(ibug[i].is_some(), "iBUG point {i} missing");
    }
    // The corners are the mouth's extreme points along the line through them.
    let (left, right) = (point(48), point(54));
    let along = (right - left).normalize();
    for i in (49..54).chain(55..60).chain([61, 62, 63, 65, 66, 67]) {
        let t = (point(i) - left).dot(along);
        assert!(
            t > 0.0 && t < (right - left).length(),
            "iBUG {i} is beyond a mouth corner"
        );
    }
    // Upper outer lip above upper inner lip above lower inner lip above lower outer lip,
    // column by column (left, middle, right), measured across the line of the corners.
    let across = Vec2::new(-along.y, along.x); // points down the face
    let depth = |i: usize| (point(i) - left).dot(across);
    for (upper_outer, upper_inner, lower_inner, lower_outer) in
        [(50, 61, 67, 58), (51, 62, 66, 57), (52, 63, 65, 56)]
    {
        assert!(
            depth(upper_outer) < depth(upper_inner)
                && depth(upper_inner) < depth(lower_inner)
                && depth(lower_inner) < depth(lower_outer),
            "mouth column {upper_outer}/{upper_inner}/{lower_inner}/{lower_outer}: {} {} {} {}",
            depth(upper_outer),
            depth(upper_inner),
            depth(lower_inner),
            depth(lower_outer)
        );
    }
    // Upper outer lip runs from the left corner to the right one, the lower one back.
    for pair in [49, 50, 51, 52, 53]
        .windows(2)
        .chain([55, 56, 57, 58, 59].windows(2))
    {
        let (a, b) = (
            (point(pair[0]) - left).dot(along),
            (point(pair[1]) - left).dot(along),
        );
        let forward = pair[0] < 54;
        assert_eq!(
            a < b,
            forward,
            "iBUG {} and {} in the wrong order",
            pair[0],
            pair[1]
        );
    }
}

fn backends_agree(tracker_a: &mut OpenSeeFace, tracker_b: &mut OpenSeeFace) {
    let frame = frame_with_face(&real_crop(), (300, 200));
    let (det_a, det_b) = match (tracker_a.detect(&frame), tracker_b.detect(&frame)) {
        (Ok(a), Ok(b)) => (a, b),
        (a, b) => panic!("detection failed: {a:?} {b:?}"),
    };
    assert_eq!(det_a.len(), det_b.len());
    for (a, b) in det_a.iter().zip(&det_b) {
        assert!((a.confidence - b.confidence).abs() < 1e-3, "{a:?} vs {b:?}");
        let corners = |r: Rect| [r.x, r.y, r.x + r.width, r.y + r.height];
        for (ca, cb) in corners(a.face_box).iter().zip(corners(b.face_box)) {
            assert!((ca - cb).abs() < 0.5, "{a:?} vs {b:?}");
        }
    }
    // The same box for both, so only the landmark networks are compared; on the framed
    // face and on the bare crop (whose crop is the whole image).
    let cases = [
        (frame.clone(), det_a[0].face_box),
        (
            real_crop(),
            Rect {
                x: 0.0,
                y: 0.0,
                width: CROP_SIDE as f32,
                height: CROP_SIDE as f32,
            },
        ),
    ];
    for (image, face_box) in &cases {
        let (a, b) = match (
            tracker_a.landmarks(image, *face_box),
            tracker_b.landmarks(image, *face_box),
        ) {
            (Ok(a), Ok(b)) => (a, b),
            (a, b) => panic!("landmarks failed: {a:?} {b:?}"),
        };
        let pairs = a.points_in_frame.iter().zip(&b.points_in_frame);
        for (i, (pa, pb)) in pairs.enumerate() {
            let distance = (*pa - *pb).length();
            assert!(distance < 0.5, "point {i} differs by {distance} px");
        }
        let confidences = a.confidence.iter().zip(&b.confidence);
        for (i, (ca, cb)) in confidences.enumerate() {
            assert!((ca - cb).abs() < 1e-3, "confidence {i}: {ca} vs {cb}");
        }
    }
}

#[test]
fn onnxruntime_and_tract_agree_within_half_a_pixel() {
    let mut ort = load(BackendKind::OnnxRuntime);
    let mut tract = load(BackendKind::Tract);
    backends_agree(&mut ort, &mut tract);
}

/// Draws the landmarks, three times enlarged, into `landmarks-openseeface.png` of the test
/// output directory: the evidence for the mouth order (module documentation of
/// `openseeface`). Colours: jaw white, brows and nose and eyes grey, and in the iBUG
/// layout the mouth corners 48/54 red, upper outer lip 49-53 green, lower outer lip 55-59
/// blue, upper inner lip 61-63 yellow, lower inner lip 65-67 cyan.
#[test]
fn landmark_overlay_is_written() {
    const SCALE: u32 = 3;
    let mut tracker = load(BackendKind::Tract);
    let crop = real_crop();
    let whole = Rect {
        x: 0.0,
        y: 0.0,
        width: CROP_SIDE as f32,
        height: CROP_SIDE as f32,
    };
    let landmarks = tracker
        .landmarks(&crop, whole)
        .unwrap_or_else(|e| panic!("{e}"));
    let mut canvas = image::imageops::resize(
        &crop,
        CROP_SIDE * SCALE,
        CROP_SIDE * SCALE,
        image::imageops::FilterType::Nearest,
    );
    let colour = |ibug: usize| match ibug {
        0..=16 => Rgb([255, 255, 255]),
        48 | 54 => Rgb([255, 0, 0]),
        49..=53 => Rgb([0, 255, 0]),
        55..=59 => Rgb([0, 0, 255]),
        61..=63 => Rgb([255, 255, 0]),
        65..=67 => Rgb([0, 255, 255]),
        _ => Rgb([160, 160, 160]),
    };
    for (ibug, entry) in landmarks.to_ibug68().iter().enumerate() {
        let Some((p, _)) = entry else { continue };
        let centre = *p * SCALE as f32;
        for dy in -2i32..=2 {
            for dx in -2i32..=2 {
                let (x, y) = (centre.x as i32 + dx, centre.y as i32 + dy);
                if (0..canvas.width() as i32).contains(&x)
                    && (0..canvas.height() as i32).contains(&y)
                {
                    canvas.put_pixel(x as u32, y as u32, colour(ibug));
                }
            }
        }
    }
    let path = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("landmarks-openseeface.png");
    if let Err(e) = canvas.save(&path) {
        panic!("cannot write {}: {e}", path.display());
    }
    assert!(path.is_file());
}

// --- following a face --------------------------------------------------------------------

fn follower_follows_and_redetects(kind: BackendKind) {
    let crop = real_crop();
    let mut follower = FaceFollower::new(load(kind));
    let shift = Vec2::new(8.0, 4.0);
    let offsets: Vec<(u32, u32)> = (0..5u32).map(|i| (200 + 8 * i, 120 + 4 * i)).collect();
    let mut centres: Vec<Vec2> = Vec::new();
    let mut boxes: Vec<Rect> = Vec::new();
    for (i, &offset) in offsets.iter().enumerate() {
        let result = follower.step(&frame_with_face(&crop, offset));
        let Some(result) = result.unwrap_or_else(|e| panic!("{e}")) else {
            panic!("{kind}: lost the face in frame {i}");
        };
        assert_eq!(result.detected, i == 0, "{kind}: frame {i} detection");
        assert_eq!(
            result.detect_ms > 0.0,
            i == 0,
            "{kind}: frame {i} detection time"
        );
        assert!(result.landmarks_ms > 0.0);
        let Some(landmark_box) = result.landmarks.bounding_box() else {
            panic!("{kind}: degenerate landmarks in frame {i}");
        };
        centres.push(landmark_box.centre());
        boxes.push(result.face_box);
        eprintln!(
            "{kind} frame {i}: detection {:.1} ms, landmarks {:.1} ms, confidence {:.3}",
            result.detect_ms, result.landmarks_ms, result.landmarks.mean_confidence
        );
    }
    // The landmarks move with the face, and so does the box used (the previous frame's
    // landmark box). Frame 0 is left out: its landmarks come from the detector's box, a
    // different framing that moves them by a few pixels against the later frames' (and
    // frame 1 uses them as its box).
    for i in 2..centres.len() {
        let moved = centres[i] - centres[i - 1];
        assert!(
            (moved - shift).length() < 2.0,
            "{kind}: frame {i} moved {moved}, not {shift}"
        );
    }
    for i in 3..boxes.len() {
        let moved = boxes[i].centre() - boxes[i - 1].centre();
        assert!(
            (moved - shift).length() < 2.0,
            "{kind}: box {i} moved {moved}, not {shift}"
        );
    }

    // The face disappears: the landmarks lose confidence, the detector runs and finds none.
    let grey = RgbImage::from_pixel(CANVAS_WIDTH, CANVAS_HEIGHT, GREY);
    let lost = follower.step(&grey).unwrap_or_else(|e| panic!("{e}"));
    assert!(lost.is_none(), "{kind}: a face in a grey frame: {lost:?}");
    assert!(follower.last_timings().detect_ms > 0.0);
    assert!(follower.previous_box().is_none());

    // It comes back elsewhere: detected again, then followed without the detector. The two
    // frames repeat the first two steps (detection, then the box of detection-framed
    // landmarks), so their landmarks are frames 0 and 1's, moved by the displacement, up to
    // the detector's grid (4 of its 224 pixels, 11 x 9 frame pixels here), which frames
    // the face a little differently at another position.
    let back = (260, 150);
    let moved_to =
        |from: (u32, u32)| Vec2::new(back.0 as f32 - from.0 as f32, back.1 as f32 - from.1 as f32);
    let expected = [
        (true, centres[0] + moved_to(offsets[0])),
        (false, centres[1] + moved_to(offsets[1])),
    ];
    for (i, (detected, expected_centre)) in expected.into_iter().enumerate() {
        let result = follower.step(&frame_with_face(&crop, back));
        let Some(result) = result.unwrap_or_else(|e| panic!("{e}")) else {
            panic!("{kind}: face not found again ({i})");
        };
        assert_eq!(result.detected, detected, "{kind}: return frame {i}");
        let centre = result.landmarks.bounding_box().map(|b| b.centre());
        let error = centre.map(|c| (c - expected_centre).length());
        eprintln!("{kind}: return frame {i} is {error:?} px from where expected");
        assert!(
            error.is_some_and(|e| e < 4.0),
            "{kind}: return frame {i}: centre {centre:?} vs {expected_centre}"
        );
    }

    // A reset forgets the face: the next frame detects again.
    follower.reset();
    let result = follower.step(&frame_with_face(&crop, back));
    assert!(
        matches!(result, Ok(Some(ref r)) if r.detected),
        "{kind}: {result:?}"
    );
}

#[test]
fn tract_follower_follows_and_redetects() {
    follower_follows_and_redetects(BackendKind::Tract);
}

#[test]
fn onnxruntime_follower_follows_and_redetects() {
    follower_follows_and_redetects(BackendKind::OnnxRuntime);
}

/// Two faces: a small copy of the real crop, which the detector scores higher, and the
/// full-size one. Detection lists both, most confident first; the follower takes the
/// largest.
fn follower_takes_the_largest_face(kind: BackendKind) {
    let crop = real_crop();
    let large_offset = (340, 200);
    let mut frame = frame_with_face(&crop, large_offset);
    let small = image::imageops::resize(&crop, 112, 112, image::imageops::FilterType::Triangle);
    image::imageops::replace(&mut frame, &small, 40, 60);
    let mut follower = FaceFollower::new(load(kind));
    let detections = follower
        .tracker_mut()
        .detect(&frame)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(detections.len(), 2, "{kind}: {detections:?}");
    assert!(detections[0].confidence >= detections[1].confidence);
    let result = follower.step(&frame).unwrap_or_else(|e| panic!("{e}"));
    let Some(result) = result else {
        panic!("{kind}: no face followed");
    };
    let large = Rect {
        x: large_offset.0 as f32,
        y: large_offset.1 as f32,
        width: CROP_SIDE as f32,
        height: CROP_SIDE as f32,
    };
    let centre = result.landmarks.bounding_box().map(|b| b.centre());
    assert!(
        centre.is_some_and(|c| contains(large, c)),
        "{kind}: followed the face at {centre:?}, not the large one"
    );
}

#[test]
fn tract_follower_takes_the_largest_face() {
    follower_takes_the_largest_face(BackendKind::Tract);
}

#[test]
fn onnxruntime_follower_takes_the_largest_face() {
    follower_takes_the_largest_face(BackendKind::OnnxRuntime);
}

// --- timings -----------------------------------------------------------------------------

fn median_timings(kind: BackendKind) {
    const RUNS: usize = 15;
    let mut tracker = load(kind);
    let frame = frame_with_face(&real_crop(), (300, 200));
    let mut detect = Vec::with_capacity(RUNS);
    let mut landmarks = Vec::with_capacity(RUNS);
    let mut face_box = None;
    for _ in 0..RUNS {
        let started = std::time::Instant::now();
        let faces = tracker.detect(&frame).unwrap_or_else(|e| panic!("{e}"));
        detect.push(started.elapsed());
        face_box = faces.first().map(|f| f.face_box);
    }
    let Some(face_box) = face_box else {
        panic!("{kind}: no face");
    };
    for _ in 0..RUNS {
        let started = std::time::Instant::now();
        tracker
            .landmarks(&frame, face_box)
            .unwrap_or_else(|e| panic!("{e}"));
        landmarks.push(started.elapsed());
    }
    detect.sort();
    landmarks.sort();
    eprintln!(
        "{kind} ({} build), median of {RUNS} on a 640x480 frame incl. resampling: detect {:?}, landmarks {:?}",
        if cfg!(debug_assertions) {
            "debug"
        } else {
            "release"
        },
        detect[RUNS / 2],
        landmarks[RUNS / 2]
    );
    assert!(detect[RUNS / 2] > Duration::ZERO && landmarks[RUNS / 2] > Duration::ZERO);
}

#[test]
fn tract_timings_are_measured() {
    median_timings(BackendKind::Tract);
}

#[test]
fn onnxruntime_timings_are_measured() {
    median_timings(BackendKind::OnnxRuntime);
}

// --- broken installations ----------------------------------------------------------------

#[test]
fn missing_models_give_missing_model_with_a_hint() {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("no-such-models/openseeface");
    for kind in [BackendKind::Tract, BackendKind::OnnxRuntime] {
        let error = match OpenSeeFace::load(&dir, kind, 1) {
            Ok(_) => panic!("{kind}: loaded models from a missing directory"),
            Err(e) => e,
        };
        let TrackingError::MissingModel { path, hint } = &error else {
            panic!("{kind}: expected MissingModel, got {error}");
        };
        assert!(path.starts_with(&dir), "{kind}: {}", path.display());
        let message = error.to_string();
        for needle in [
            "emilianavt/OpenSeeFace",
            "models/",
            "--models",
            "LIKENESS_MODELS",
            "does not exist",
        ] {
            assert!(
                hint.contains(needle),
                "{kind}: hint lacks `{needle}`: {message}"
            );
        }
    }
}

/// A copy of the models in `name` with the detector (or the landmark network) cut to a
/// third of its length.
fn models_with_truncated_file(name: &str, kind: BackendKind, truncate_detector: bool) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let (detector, landmarks) = model_files(&default_models_dir(), kind);
    if let Err(e) = std::fs::create_dir_all(&dir) {
        panic!("cannot create {}: {e}", dir.display());
    }
    for (source, truncate) in [
        (detector, truncate_detector),
        (landmarks, !truncate_detector),
    ] {
        let bytes = std::fs::read(&source)
            .unwrap_or_else(|e| panic!("cannot read the model {}: {e}", source.display()));
        let kept = if truncate {
            &bytes[..bytes.len() / 3]
        } else {
            &bytes[..]
        };
        let Some(file_name) = source.file_name() else {
            panic!("{} has no file name", source.display());
        };
        let target = dir.join(file_name);
        if let Err(e) = std::fs::write(&target, kept) {
            panic!("cannot write {}: {e}", target.display());
        }
    }
    dir
}

fn truncated_models_fail_cleanly(kind: BackendKind) {
    if kind == BackendKind::OnnxRuntime {
        require_onnxruntime();
    }
    for truncate_detector in [true, false] {
        let name = format!("truncated-openseeface-{kind}-{truncate_detector}");
        let dir = models_with_truncated_file(&name, kind, truncate_detector);
        let error = match OpenSeeFace::load(&dir, kind, 1) {
            Ok(_) => panic!("{kind}: loaded a truncated model"),
            Err(e) => e,
        };
        let file = if truncate_detector {
            "mnv3_detection"
        } else {
            "lm_model0"
        };
        let TrackingError::Decode { path, .. } = &error else {
            panic!("{kind}: expected a Decode error naming the file, got {error}");
        };
        let named = path.file_name().map(|n| n.to_string_lossy().into_owned());
        assert!(
            path.starts_with(&dir) && named.is_some_and(|n| n.starts_with(file)),
            "{kind}: the error names {}, not the truncated {file}",
            path.display()
        );
        assert!(
            error.to_string().contains("emilianavt/OpenSeeFace"),
            "{error}"
        );
    }
}

#[test]
fn tract_truncated_model_gives_an_error() {
    truncated_models_fail_cleanly(BackendKind::Tract);
}

#[test]
fn onnxruntime_truncated_model_gives_an_error() {
    truncated_models_fail_cleanly(BackendKind::OnnxRuntime);
}
