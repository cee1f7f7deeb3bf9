//! Footage in, records and sessions out: folders in natural order, unreadable frames as
//! "no face" records, video through ffmpeg (including empty and broken files), a live
//! virtual camera, huge images refused; the tracking JSON and session files round-trip.

mod common;

use std::process::Command;

use common::temp_dir;
use face::NUM_BLENDSHAPES;
use face::uv::CORRECTION_SIZE;
use tracking::FaceParams;
use tracking::record::{FrameRecord, TracksDocument};
use tracking::session::{FrameObservations, Session, SessionInfo};
use tracking::source::{InputSpec, Next, check_frame_size, natural_cmp};

fn ffmpeg(args: &[&str]) {
    let status = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y"])
        .args(args)
        .status()
        .expect("ffmpeg is installed by scripts/setup.sh");
    assert!(status.success(), "ffmpeg {args:?}");
}

/// A decoded frame's index and size, or why it was skipped or the footage stopped.
type FrameOutcome = Result<(usize, (u32, u32)), String>;

fn frames(spec: &InputSpec) -> Vec<FrameOutcome> {
    let mut source = spec.open(25.0).expect("open");
    let mut out = Vec::new();
    loop {
        match source.next_frame() {
            Ok(Next::Frame(f)) => out.push(Ok((f.index, f.image.dimensions()))),
            Ok(Next::Skipped(s)) => out.push(Err(s.error.to_string())),
            Ok(Next::End) => break,
            Err(e) => {
                out.push(Err(format!("fatal: {e}")));
                break;
            }
        }
        if out.len() > 100 {
            break;
        }
    }
    out
}

#[test]
fn natural_order() {
    let mut names = vec!["f10.png", "f2.png", "f1.png", "f02b.png", "a.png"];
    names.sort_by(|a, b| natural_cmp(a, b));
    assert_eq!(
        names,
        vec!["a.png", "f1.png", "f2.png", "f02b.png", "f10.png"]
    );
}

#[test]
fn folder_with_a_broken_image_keeps_going() {
    let dir = temp_dir("folder");
    for i in [1, 2, 10] {
        image::RgbImage::from_pixel(32, 24, image::Rgb([i as u8, 0, 0]))
            .save(dir.join(format!("frame_{i}.png")))
            .expect("png");
    }
    std::fs::write(dir.join("frame_3.png"), b"not a png").expect("write");
    std::fs::write(dir.join("notes.txt"), b"ignored").expect("write");
    let spec = InputSpec::parse(dir.to_str().unwrap()).expect("spec");
    assert!(matches!(spec, InputSpec::Folder(_)));
    let got = frames(&spec);
    assert_eq!(got.len(), 4, "{got:?}");
    assert_eq!(got[0], Ok((0, (32, 24))));
    assert_eq!(got[1], Ok((1, (32, 24))));
    assert!(
        got[2].as_ref().is_err_and(|e| e.contains("frame_3.png")),
        "{got:?}"
    );
    assert_eq!(got[3], Ok((3, (32, 24))));
    let empty = temp_dir("empty-folder");
    let err = InputSpec::parse(empty.to_str().unwrap())
        .unwrap()
        .open(30.0)
        .err()
        .expect("error");
    assert!(err.to_string().contains("has no images"), "{err}");
    assert!(InputSpec::parse("/no/such/file.mp4").is_err());
}

#[test]
fn video_files_decode_and_bad_ones_are_clear_errors() {
    let dir = temp_dir("video");
    let video = dir.join("clip.mp4");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=160x120:rate=25:duration=0.4",
        "-pix_fmt",
        "yuv420p",
        video.to_str().unwrap(),
    ]);
    let spec = InputSpec::parse(video.to_str().unwrap()).expect("spec");
    assert!(matches!(spec, InputSpec::Video(_)));
    let mut source = spec.open(30.0).expect("open video");
    assert!((source.fps() - 25.0).abs() < 1e-6);
    let mut n = 0;
    while let Next::Frame(f) = source.next_frame().expect("frame") {
        assert_eq!(f.image.dimensions(), (160, 120));
        assert!((f.time_s - n as f64 / 25.0).abs() < 1e-9);
        n += 1;
    }
    assert_eq!(n, 10);
    // An empty file and a text file named .mp4.
    let empty = dir.join("empty.mp4");
    std::fs::write(&empty, b"").expect("write");
    let err = InputSpec::parse(empty.to_str().unwrap())
        .unwrap()
        .open(30.0)
        .err()
        .expect("error");
    assert!(err.to_string().contains("empty.mp4"), "{err}");
    let text = dir.join("text.mp4");
    std::fs::write(&text, b"hello, this is not a video").expect("write");
    let Err(err) = InputSpec::parse(text.to_str().unwrap()).unwrap().open(30.0) else {
        panic!("a text file opened as a video");
    };
    assert!(err.to_string().contains("text.mp4"), "{err}");
    // A truncated stream (MPEG-TS has no index, so it stays readable): the frames before
    // the damage still come, then the end or an error, never a panic.
    let ts = dir.join("clip.ts");
    ffmpeg(&[
        "-f",
        "lavfi",
        "-i",
        "testsrc2=size=160x120:rate=25:duration=0.8",
        "-pix_fmt",
        "yuv420p",
        ts.to_str().unwrap(),
    ]);
    let bytes = std::fs::read(&ts).expect("read");
    let cut = dir.join("cut.ts");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).expect("write");
    let got = frames(&InputSpec::parse(cut.to_str().unwrap()).expect("spec"));
    let decoded = got.iter().filter(|f| f.is_ok()).count();
    assert!((1..20).contains(&decoded), "{got:?}");
    assert!(got[..decoded].iter().all(Result::is_ok), "{got:?}");
}

#[test]
fn live_virtual_camera_streams_with_wall_clock_times() {
    let spec = InputSpec::parse("ffmpeg:lavfi:testsrc2=size=96x64:rate=30").expect("spec");
    assert!(spec.is_footage());
    let mut source = spec.open(30.0).expect("open live source");
    assert!(source.is_live());
    let mut last = -1.0;
    for i in 0..5 {
        match source.next_frame().expect("frame") {
            Next::Frame(f) => {
                assert_eq!(f.index, i);
                assert_eq!(f.image.dimensions(), (96, 64));
                assert!(f.time_s >= last);
                last = f.time_s;
            }
            _ => panic!("a live source does not end"),
        }
    }
    drop(source); // kills ffmpeg
    let err = InputSpec::parse("ffmpeg:v4l2:/dev/no-such-camera")
        .unwrap()
        .open(30.0)
        .err()
        .expect("error");
    assert!(err.to_string().contains("camera"), "{err}");
    assert!(InputSpec::parse("ffmpeg:nocolon").is_err());
}

#[test]
fn huge_and_empty_frames_are_refused() {
    assert!(check_frame_size(640, 480).is_ok());
    let e = check_frame_size(20_000, 10).unwrap_err().to_string();
    assert!(e.contains("at most"), "{e}");
    assert!(check_frame_size(10_000, 10_000).is_err());
    assert!(check_frame_size(0, 10).is_err());
}

fn sample_document() -> TracksDocument {
    let mut doc = TracksDocument::new("test".into(), 30.0);
    let mut params = FaceParams::default();
    params.weights[26] = 0.7;
    params.pose =
        face::camera::HeadPose::from_degrees(10.0, -5.0, 2.0, glam::Vec3::new(1.0, 2.0, -80.0));
    let landmarks =
        std::array::from_fn(|i| glam::Vec2::new(100.0 + i as f32, 50.0 + 2.0 * i as f32));
    doc.frames
        .push(FrameRecord::with_face(0, 0.0, &params, &landmarks, 0.9));
    doc.frames
        .push(FrameRecord::no_face(1, 1.0 / 30.0, Some("no face".into())));
    doc
}

#[test]
fn tracking_json_round_trips_and_retarget_reads_it() {
    let doc = sample_document();
    let json = doc.to_json();
    let back = TracksDocument::from_json(&json).expect("parse");
    assert_eq!(back, doc);
    let value: serde_json::Value = serde_json::from_str(&json).expect("json");
    let f0 = &value["frames"][0];
    assert_eq!(
        f0["weights"].as_array().map(Vec::len),
        Some(NUM_BLENDSHAPES)
    );
    assert_eq!(f0["arkit_weights"].as_array().map(Vec::len), Some(52));
    assert_eq!(f0["landmarks_68"].as_array().map(Vec::len), Some(68));
    assert!((f0["rotation_deg"][0].as_f64().unwrap() - 10.0).abs() < 1e-4);
    assert_eq!(f0["face_box"][2].as_f64(), Some(67.0));
    assert_eq!(value["frames"][1]["face"], serde_json::json!(false));
    assert!(value["frames"][1].get("weights").is_none());
    let jaw = face::names::arkit_index("jawOpen").unwrap();
    assert!((f0["arkit_weights"][jaw].as_f64().unwrap() - 0.7).abs() < 1e-6);
    // The retargeting crate's reader takes it as is.
    let tracks = retarget_reads(&json);
    assert_eq!(tracks, 1);
    // Saved atomically; a missing folder is an error that names it.
    let dir = temp_dir("json");
    doc.save(&dir.join("t.json")).expect("save");
    assert_eq!(
        TracksDocument::load(&dir.join("t.json")).expect("load"),
        doc
    );
    assert!(doc.save(&dir.join("missing/t.json")).is_err());
    assert!(TracksDocument::from_json("{}").is_err());
}

fn retarget_reads(json: &str) -> usize {
    // retarget is not a dependency of tracking; parse the fields it needs the same way.
    let v: serde_json::Value = serde_json::from_str(json).expect("json");
    v["frames"].as_array().map_or(0, |f| {
        f.iter().filter(|f| f["arkit_weights"].is_array()).count()
    })
}

#[test]
fn session_round_trips_and_bad_files_are_refused() {
    let mut corrections = face::PersonalCorrections::zeros();
    corrections.identity_shape.data[5] = 0.25;
    corrections.expression_shapes[26].data[3 * (CORRECTION_SIZE * 10 + 7) + 1] = -0.5;
    corrections.dynamic_albedo[45].data[100] = 0.125;
    let session = Session {
        info: SessionInfo {
            created_by: "test".into(),
            source: "clip.mp4".into(),
            selected_frames: vec![0, 7, 3],
            backend: "tract".into(),
            networks: String::new(),
        },
        corrections,
        tracks: sample_document(),
        footage: None,
        observations: Vec::new(),
    };
    let dir = temp_dir("session");
    let path = dir.join("person.likeness");
    session.save(&path).expect("save");
    let back = Session::load(&path).expect("load");
    assert_eq!(back, session);
    // No temporary file is left behind.
    assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 1);
    // Damaged, foreign and future files.
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(dir.join("cut.likeness"), &bytes[..bytes.len() / 2]).unwrap();
    assert!(Session::load(&dir.join("cut.likeness")).is_err());
    std::fs::write(dir.join("text.likeness"), b"hello").unwrap();
    let e = Session::load(&dir.join("text.likeness"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("not a Likeness session"), "{e}");
    let future = {
        let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
        let header = String::from_utf8(bytes[8..8 + header_len].to_vec()).unwrap();
        let patched = header.replace("\"version\":\"2\"", "\"version\":\"9\"");
        assert_ne!(patched, header, "the header holds the version");
        let mut out = (patched.len() as u64).to_le_bytes().to_vec();
        out.extend_from_slice(patched.as_bytes());
        out.extend_from_slice(&bytes[8 + header_len..]);
        out
    };
    std::fs::write(dir.join("future.likeness"), future).unwrap();
    let e = Session::load(&dir.join("future.likeness"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("newer"), "{e}");
}

/// A file with its header's version replaced.
fn with_version(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let header_len = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header = String::from_utf8(bytes[8..8 + header_len].to_vec()).unwrap();
    let patched = header.replace(
        &format!("\"version\":\"{from}\""),
        &format!("\"version\":\"{to}\""),
    );
    assert_ne!(patched, header, "the header holds the version");
    let mut out = (patched.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(patched.as_bytes());
    out.extend_from_slice(&bytes[8 + header_len..]);
    out
}

#[test]
fn session_keeps_its_footage_and_observations_and_version_1_still_loads() {
    let tracks = sample_document();
    let n = tracks.frames.len();
    let footage: Vec<image::RgbImage> = (0..n)
        .map(|k| {
            image::RgbImage::from_fn(5, 3, |x, y| image::Rgb([k as u8, x as u8, y as u8 * 40]))
        })
        .collect();
    let observations: Vec<FrameObservations> = (0..n)
        .map(|k| FrameObservations {
            detected: vec![[k as f32, 1.5], [2.0, 3.25]],
            crop: (k % 2 == 0).then_some([1.0, 2.0, 30.0, 40.0]),
        })
        .collect();
    let session = Session {
        info: SessionInfo::default(),
        corrections: face::PersonalCorrections::zeros(),
        tracks,
        footage: Some(footage),
        observations,
    };
    let dir = temp_dir("session-footage");
    let path = dir.join("studio.likeness");
    session.save(&path).expect("save");
    let back = Session::load(&path).expect("load");
    assert_eq!(back, session, "frames and observations round-trip exactly");

    // Footage that does not match the tracking is refused when saving.
    let mut short = session.clone();
    short.footage.as_mut().unwrap().pop();
    assert!(short.save(&dir.join("short.likeness")).is_err());
    let mut mixed = session.clone();
    mixed.footage.as_mut().unwrap()[0] = image::RgbImage::new(4, 3);
    assert!(mixed.save(&dir.join("mixed.likeness")).is_err());

    // A version 1 file (no footage) still loads.
    let mut plain = session.clone();
    plain.footage = None;
    plain.observations.clear();
    let bytes = plain.to_bytes().unwrap();
    std::fs::write(dir.join("v1.likeness"), with_version(&bytes, "2", "1")).unwrap();
    let v1 = Session::load(&dir.join("v1.likeness")).expect("a version 1 file loads");
    assert_eq!(v1, plain);
}
