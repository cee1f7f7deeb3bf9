//! `likeness track` and `likeness personalize` as a user runs them: on held-out synthetic
//! clips (training/setup.sh renders them), a video, a still, and bad input.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{likeness, out_dir};

fn clip_dir() -> PathBuf {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../training/.cache/clips-s9001/clip_00");
    assert!(
        dir.join("truth.json").is_file(),
        "{} is missing: run training/setup.sh",
        dir.display()
    );
    dir
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).expect("output")).expect("JSON")
}

#[test]
fn track_a_clip_folder_to_json_and_csv() {
    let dir = out_dir("clip");
    let (out, csv) = (dir.join("t.json"), dir.join("t.csv"));
    let o = likeness(&[
        "track",
        clip_dir().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--csv",
        csv.to_str().unwrap(),
        "--fov",
        "50",
        "--max-frames",
        "12",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let v = json(&out);
    assert_eq!(v["blendshape_names"].as_array().map(Vec::len), Some(53));
    assert_eq!(v["arkit_names"].as_array().map(Vec::len), Some(52));
    let frames = v["frames"].as_array().expect("frames");
    assert_eq!(frames.len(), 12);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f["index"].as_u64(), Some(i as u64));
        assert_eq!(f["face"], serde_json::json!(true), "frame {i}: {f}");
        assert_eq!(f["weights"].as_array().map(Vec::len), Some(53));
        assert_eq!(f["arkit_weights"].as_array().map(Vec::len), Some(52));
        assert_eq!(f["sh"].as_array().map(Vec::len), Some(27));
        assert_eq!(f["landmarks_68"].as_array().map(Vec::len), Some(68));
        assert_eq!(f["face_box"].as_array().map(Vec::len), Some(4));
        assert!(
            f["confidence"]
                .as_f64()
                .is_some_and(|c| (0.0..=1.0).contains(&c))
        );
        assert!((f["time_s"].as_f64().unwrap() - i as f64 / 30.0).abs() < 1e-9);
    }
    let csv_text = std::fs::read_to_string(&csv).expect("csv");
    let lines: Vec<&str> = csv_text.lines().collect();
    assert_eq!(lines.len(), 13);
    assert_eq!(lines[0].split(',').count(), 63); // timecode, count, 61 values
    assert!(lines[0].starts_with("Timecode,BlendShapeCount,EyeBlinkLeft"));
    // The retargeting command takes the output as is.
    let puppet = Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/puppets/pip.glb");
    let anim = dir.join("anim.json");
    let o = likeness(&[
        "retarget",
        "--tracks",
        out.to_str().unwrap(),
        "--puppet",
        puppet.to_str().unwrap(),
        "--out",
        anim.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn track_a_video_and_a_still() {
    let dir = out_dir("video");
    let video = dir.join("clip.mp4");
    let status = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-framerate", "30", "-i"])
        .arg(clip_dir().join("frame_%04d.png"))
        .args(["-frames:v", "8", "-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .arg(&video)
        .status()
        .expect("ffmpeg");
    assert!(status.success());
    let out = dir.join("v.json");
    let o = likeness(&[
        "track",
        video.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let v = json(&out);
    assert_eq!(v["frames"].as_array().map(Vec::len), Some(8));
    assert!(
        v["frames"]
            .as_array()
            .unwrap()
            .iter()
            .all(|f| f["face"] == serde_json::json!(true))
    );
    assert_eq!(v["complete"], serde_json::json!(true));
    // A still: smoothing is off.
    let still = clip_dir().join("frame_0000.png");
    let out = dir.join("s.json");
    let o = likeness(&[
        "track",
        still.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let v = json(&out);
    assert_eq!(v["frames"].as_array().map(Vec::len), Some(1));
    assert!(
        v["settings"]["smoothing"]
            .as_str()
            .is_some_and(|s| s.contains("off") || s.contains("Off")),
        "{}",
        v["settings"]
    );
    // A grey image has no face: a record that says so, not an error.
    let grey = dir.join("grey.png");
    image::RgbImage::from_pixel(320, 240, image::Rgb([120, 120, 120]))
        .save(&grey)
        .expect("png");
    let o = likeness(&[
        "track",
        grey.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(json(&out)["frames"][0]["face"], serde_json::json!(false));
}

#[test]
fn personalize_writes_a_session_with_the_tracking() {
    let dir = out_dir("personalize");
    let out = dir.join("person.likeness");
    let o = likeness(&[
        "personalize",
        clip_dir().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--frames",
        "4",
        "--max-frames",
        "16",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let session = tracking::session::Session::load(&out).expect("session");
    assert_eq!(session.info.selected_frames.len(), 4);
    assert_eq!(session.tracks.frames.len(), 16);
    assert!(
        session.corrections.expression_shapes[26].max_abs() > 0.0,
        "ModelNet's dS of jawOpen is all zero"
    );
    assert!(session.tracks.frames.iter().all(|f| f.face));
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = out_dir("bad");
    let out = dir.join("t.json");
    let out_s = out.to_str().unwrap();
    for (args, expect) in [
        (
            vec!["track", "/no/such/clip.mp4", "--out", out_s],
            "no such file",
        ),
        (
            vec![
                "track",
                clip_dir().to_str().unwrap(),
                "--out",
                "/no/such/dir/t.json",
            ],
            "does not exist",
        ),
        (
            vec![
                "track",
                clip_dir().to_str().unwrap(),
                "--out",
                out_s,
                "--smooth",
                "beta=-1",
            ],
            "beta",
        ),
        (
            vec![
                "track",
                clip_dir().to_str().unwrap(),
                "--out",
                out_s,
                "--backend",
                "cuda",
            ],
            "unknown backend",
        ),
        (
            vec![
                "track",
                clip_dir().to_str().unwrap(),
                "--out",
                out_s,
                "--fov",
                "500",
            ],
            "--fov",
        ),
        (
            vec![
                "personalize",
                clip_dir().to_str().unwrap(),
                "--out",
                out_s,
                "--frames",
                "0",
            ],
            "--frames",
        ),
    ] {
        let o = likeness(&args);
        assert!(!o.status.success(), "{args:?} succeeded");
        let t = text(&o);
        assert!(t.contains(expect), "{args:?}: {t}");
        assert!(!t.contains("panicked"), "{t}");
    }
    // A text file named like a video.
    let fake = dir.join("fake.mp4");
    std::fs::write(&fake, b"not a video").expect("write");
    let o = likeness(&["track", fake.to_str().unwrap(), "--out", out_s, "--quiet"]);
    assert!(!o.status.success());
    assert!(text(&o).contains("fake.mp4"), "{}", text(&o));
    // Video input without the landmark models: real footage says what is missing.
    let o = likeness(&[
        "track",
        "ffmpeg:lavfi:testsrc2=size=64x48",
        "--out",
        out_s,
        "--models",
        dir.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(!o.status.success());
    assert!(text(&o).contains("face detection"), "{}", text(&o));
}

/// `--locator mediapipe`: MediaPipe's BlazeFace and Face Mesh find the real 224 px
/// close-up (which OpenSeeFace's detector misses) and the output says which locator ran;
/// a models folder without MediaPipe's files is an error naming them.
#[test]
fn track_a_close_up_with_the_mediapipe_locator() {
    let dir = out_dir("mediapipe");
    let out = dir.join("t.json");
    let still = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/testdata/faces/openseeface-raw1.png");
    let o = likeness(&[
        "track",
        still.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--locator",
        "mediapipe",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let v = json(&out);
    assert_eq!(v["settings"]["locator"], serde_json::json!("mediapipe"));
    let frame = &v["frames"][0];
    assert_eq!(frame["face"], serde_json::json!(true), "{frame}");
    let points = frame["landmarks_68"].as_array().expect("landmarks");
    assert_eq!(points.len(), 68);
    for p in points {
        let (x, y) = (p[0].as_f64().unwrap(), p[1].as_f64().unwrap());
        assert!(
            (0.0..224.0).contains(&x) && (0.0..224.0).contains(&y),
            "{p}"
        );
    }
    let empty = dir.join("no-models");
    std::fs::create_dir_all(&empty).unwrap();
    let o = likeness(&[
        "track",
        still.to_str().unwrap(),
        "--out",
        dir.join("u.json").to_str().unwrap(),
        "--locator",
        "mediapipe",
        "--models",
        empty.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(!o.status.success());
    let message = text(&o);
    assert!(
        message.contains("face_detection_short_range.onnx")
            && message.contains("mediapipe==0.10.14"),
        "{message}"
    );
}

/// The close-up OpenSeeFace's detector misses is found with OpenSeeFace's locator through
/// the fallback detector (RetinaFace); `--no-fallback-detector` turns it off, and the
/// no-face record then says how to get it back (issue 32, item 7).
#[test]
fn the_fallback_detector_finds_the_close_up_and_can_be_turned_off() {
    let dir = out_dir("fallback");
    let still = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/testdata/faces/openseeface-raw1.png");
    let run = |name: &str, extra: &[&str]| {
        let out = dir.join(name);
        let mut args = vec![
            "track",
            still.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--locator",
            "openseeface",
            "--backend",
            "onnxruntime",
            "--quiet",
        ];
        args.extend_from_slice(extra);
        let o = likeness(&args);
        assert!(o.status.success(), "{}", text(&o));
        json(&out)
    };
    let with = run("with.json", &[]);
    assert_eq!(
        with["frames"][0]["face"],
        serde_json::json!(true),
        "{}",
        with["frames"][0]
    );
    let without = run("without.json", &["--no-fallback-detector"]);
    let frame = &without["frames"][0];
    assert_eq!(frame["face"], serde_json::json!(false), "{frame}");
    let note = frame["note"].as_str().unwrap_or_default();
    assert!(
        note.contains("RetinaFace") && note.contains("mediapipe"),
        "{note}"
    );
}
