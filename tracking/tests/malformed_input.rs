//! Inputs the fuzz targets (`fuzzing/`, `fuzz/`) found mishandled, each kept as a test of
//! the fix; the inputs themselves are in `fuzz/regressions/`.

use face::names::NUM_ARKIT;
use tracking::FaceParams;
use tracking::record::{CameraRecord, FrameRecord, TracksDocument};

fn document() -> TracksDocument {
    let mut doc = TracksDocument::new("clip.mp4".into(), 30.0);
    doc.camera = Some(CameraRecord {
        width: 640,
        height: 480,
        focal_px: 600.0,
        cx: 320.0,
        cy: 240.0,
    });
    let landmarks = std::array::from_fn(|i| glam::Vec2::new(100.0 + i as f32, 80.0));
    doc.frames.push(FrameRecord::with_face(
        0,
        0.0,
        &FaceParams::default(),
        &landmarks,
        0.9,
    ));
    doc
}

#[test]
fn numbers_beyond_f32_are_refused_not_read_as_infinite() {
    // fuzz/regressions/tracks_json/face-box-beyond-f32.json: a face box height of 3.5e38
    // read as an infinite f32, which the document then wrote as `null` and could not
    // read back.
    for pointer in [
        "/frames/0/face_box/3",
        "/frames/0/weights/5",
        "/frames/0/arkit_weights/0",
        "/frames/0/rotation_deg/1",
        "/frames/0/translation/2",
        "/frames/0/sh/4",
        "/frames/0/landmarks_68/10/0",
        "/frames/0/confidence",
        "/camera/focal_px",
        "/camera/cx",
    ] {
        let mut value: serde_json::Value = serde_json::from_str(&document().to_json()).unwrap();
        *value.pointer_mut(pointer).unwrap() = serde_json::json!(1234.5);
        let text = serde_json::to_string(&value)
            .unwrap()
            .replacen("1234.5", "3.5e38", 1);
        let e = TracksDocument::from_json(&text).expect_err(pointer);
        let expected = if pointer.starts_with("/camera") {
            "out of range"
        } else {
            "not a finite 32-bit float"
        };
        assert!(e.contains(expected), "{pointer}: {e}");
    }
    // The largest f32 still reads, and reads back.
    let mut value: serde_json::Value = serde_json::from_str(&document().to_json()).unwrap();
    value["frames"][0]["face_box"][3] = serde_json::json!(f32::MAX);
    let doc = TracksDocument::from_json(&value.to_string()).expect("f32::MAX");
    assert_eq!(TracksDocument::from_json(&doc.to_json()), Ok(doc));
    assert_eq!(
        document().frames[0]
            .track
            .as_ref()
            .unwrap()
            .arkit_weights
            .len(),
        NUM_ARKIT
    );
}

#[test]
fn probe_sizes_beyond_u32_are_refused_not_truncated() {
    use tracking::source::parse_probe_output;
    // fuzz/regressions/video/probe-width-beyond-u32.bin: a width of 2^32 + 64 was read as
    // 64 (`as u32`), a size the frames then do not have.
    for (w, h) in [
        (4_294_967_360u64, 48u64),
        (64, 4_294_967_297),
        (9_007_199_254_740_993, 48),
    ] {
        let json = format!(r#"{{"streams": [{{"width": {w}, "height": {h}}}]}}"#);
        assert!(parse_probe_output(json.as_bytes()).is_err(), "{w}x{h}");
    }
    let ok = parse_probe_output(
        br#"{"streams": [{"width": 64, "height": 48, "avg_frame_rate": "25/1"}]}"#,
    )
    .expect("a plain probe");
    assert_eq!((ok.width, ok.height, ok.fps), (64, 48, 25.0));
}

#[test]
fn probe_frame_rates_that_are_not_plausible_are_not_used() {
    use tracking::source::parse_probe_output;
    // `inf/1`, `1/1e-320` (infinite), `1e-300/1` (a frame every 1e300 s): each would give
    // every frame the same or an absurd time. They fall back to `r_frame_rate`, then 30.
    for rate in [
        "inf/1", "1/1e-320", "1e-300/1", "1e9/1", "NaN/1", "0/0", "-25/1",
    ] {
        let json = format!(
            r#"{{"streams": [{{"width": 64, "height": 48, "avg_frame_rate": "{rate}", "r_frame_rate": "24/1"}}]}}"#
        );
        let info = parse_probe_output(json.as_bytes()).expect(rate);
        assert_eq!(info.fps, 24.0, "{rate}");
        let json = format!(
            r#"{{"streams": [{{"width": 64, "height": 48, "avg_frame_rate": "{rate}", "r_frame_rate": "{rate}"}}]}}"#
        );
        assert_eq!(
            parse_probe_output(json.as_bytes()).expect(rate).fps,
            30.0,
            "{rate}"
        );
    }
    // Real rates, slow and fast, are kept.
    for (rate, fps) in [
        ("30000/1001", 30000.0 / 1001.0),
        ("1/10", 0.1),
        ("240/1", 240.0),
    ] {
        let json = format!(
            r#"{{"streams": [{{"width": 64, "height": 48, "avg_frame_rate": "{rate}"}}]}}"#
        );
        assert_eq!(
            parse_probe_output(json.as_bytes()).expect(rate).fps,
            fps,
            "{rate}"
        );
    }
}

/// A session file's bytes: the metadata of an empty tracking and the given tensors.
fn session_bytes(tensors: Vec<(&str, safetensors::tensor::TensorView<'_>)>) -> Vec<u8> {
    let mut meta = std::collections::HashMap::new();
    meta.insert("format".to_string(), "likeness-session".to_string());
    meta.insert("version".to_string(), "2".to_string());
    meta.insert(
        "info".to_string(),
        r#"{"created_by": "test", "source": "clip.mp4", "selected_frames": [], "backend": "tract"}"#
            .to_string(),
    );
    meta.insert(
        "tracks".to_string(),
        TracksDocument::new("clip.mp4".into(), 30.0).to_json(),
    );
    safetensors::serialize(tensors, Some(meta)).unwrap()
}

#[test]
fn footage_of_frames_beyond_the_limits_is_refused() {
    use safetensors::{Dtype, tensor::TensorView};
    use tracking::session::{Session, SessionParts};
    // fuzz/regressions/session/empty-footage-of-huge-frames.likeness: no frames of
    // 4294967295 x 4294967295 pixels (zero bytes of data) overflowed `w * h * 3`.
    let huge = TensorView::new(
        Dtype::U8,
        vec![0, u32::MAX as usize, u32::MAX as usize, 3],
        &[],
    )
    .unwrap();
    let bytes = session_bytes(vec![("frames", huge)]);
    let e = SessionParts::from_bytes(&bytes).expect_err("huge frames");
    assert!(e.contains("frames") && e.contains("at most"), "{e}");
    assert!(Session::from_bytes(&bytes).is_err());
    // Frames within the limits read (and the missing corrections are what is wrong).
    let small = TensorView::new(Dtype::U8, vec![0, 4, 6, 3], &[]).unwrap();
    let bytes = session_bytes(vec![("frames", small)]);
    let parts = SessionParts::from_bytes(&bytes).expect("an empty footage tensor of 6 x 4");
    assert_eq!(parts.footage, Some(Vec::new()));
    let e = Session::from_bytes(&bytes).expect_err("no corrections");
    assert!(e.contains("dS0"), "{e}");
}
