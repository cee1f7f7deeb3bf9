//! The `likeness` binary as a user runs it: good output for good input, a clear message and
//! a non-zero exit for bad input.

mod common;

use common::{likeness, out_dir, stderr};

#[test]
fn screenshot_writes_the_requested_size_and_expressions_change_it() {
    let dir = out_dir("shots");
    let neutral = dir.join("neutral.png");
    let jaw = dir.join("jaw.png");
    let o = likeness(&[
        "screenshot",
        "--out",
        neutral.to_str().unwrap(),
        "--size",
        "200x160",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let o = likeness(&[
        "screenshot",
        "--out",
        jaw.to_str().unwrap(),
        "--size",
        "200x160",
        "--weights",
        "jawOpen=0.9",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let a = image::open(&neutral).expect("png").to_rgba8();
    let b = image::open(&jaw).expect("png").to_rgba8();
    assert_eq!(a.dimensions(), (200, 160));
    let changed = a.pixels().zip(b.pixels()).filter(|(p, q)| p != q).count();
    assert!(changed > 300, "jawOpen changed only {changed} pixels");
}

#[test]
fn out_of_range_weights_are_clamped_and_reported() {
    let dir = out_dir("clamp");
    let out = dir.join("c.png");
    let o = likeness(&[
        "screenshot",
        "--out",
        out.to_str().unwrap(),
        "--size",
        "64x64",
        "--weights",
        "jawOpen=1.7,eyeBlinkLeft=-0.5",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    let err = stderr(&o);
    assert!(
        err.contains("jawOpen=1.7") && err.contains("clamped to 1"),
        "{err}"
    );
    assert!(
        err.contains("eyeBlink_L=-0.5") && err.contains("clamped to 0"),
        "{err}"
    );
    assert!(out.is_file());
}

#[test]
fn bad_input_is_a_clear_error() {
    let dir = out_dir("bad");
    let out = dir.join("x.png");
    let out = out.to_str().unwrap();
    let cases: [(&[&str], &str); 6] = [
        (
            &["screenshot", "--out", out, "--weights", "jawOpen=NaN"],
            "jawOpen",
        ),
        (
            &["screenshot", "--out", out, "--weights", "smirk=0.5"],
            "unknown blendshape name `smirk`",
        ),
        (
            &["screenshot", "--out", out, "--view", "sideways"],
            "unknown view `sideways`",
        ),
        (
            &["screenshot", "--out", out, "--size", "12x"],
            "not a number",
        ),
        (
            &["screenshot", "--out", "/nonexistent/folder/x.png"],
            "/nonexistent/folder",
        ),
        (
            &[
                "--facemodel",
                "/nonexistent/model.safetensors",
                "screenshot",
                "--out",
                out,
            ],
            "ICT-FaceKit",
        ),
    ];
    for (args, needle) in cases {
        let o = likeness(args);
        assert!(!o.status.success(), "{args:?} should fail");
        let err = stderr(&o);
        assert!(
            err.contains(needle),
            "{args:?}: expected `{needle}` in: {err}"
        );
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    }
    assert!(
        !dir.join("x.png").exists(),
        "no image may be written on error"
    );
}

#[test]
fn the_headless_demo_writes_every_view() {
    let dir = out_dir("demo");
    let o = likeness(&["demo", "--headless", "--out", dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    for name in [
        "shaded_neutral",
        "shaded_expression",
        "shaded_three_quarter",
        "albedo",
        "wireframe",
        "landmarks",
        "mask_jawOpen",
    ] {
        let path = dir.join(format!("{name}.png"));
        let img = image::open(&path)
            .unwrap_or_else(|e| panic!("{}: {e}", path.display()))
            .to_rgba8();
        // Not a blank frame: the face covers a good part of the picture.
        let background = *img.get_pixel(0, 0);
        let face = img.pixels().filter(|p| **p != background).count();
        assert!(
            face > img.len() / 4 / 10,
            "{name}: only {face} non-background pixels"
        );
    }
    // The demo session's input: the synthetic person's clip at the demo camera's size.
    let input = image::open(dir.join("input_0000.png"))
        .expect("the demo's first input frame")
        .to_rgb8();
    assert_eq!(input.dimensions(), (640, 480));
    let inputs = std::fs::read_dir(&dir)
        .expect("output folder")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().starts_with("input_"))
        .count();
    // First, middle and the frames ModelNet saw (some may coincide).
    assert!(inputs >= 3, "{inputs} input frames written");
}

#[test]
fn export_fixture_writes_the_tensors_training_needs() {
    let dir = out_dir("fixture");
    let o = likeness(&["export-fixture", "--out", dir.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    let bytes = std::fs::read(dir.join("face_fixture.safetensors")).expect("fixture written");
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("valid safetensors");
    let shape = |name: &str| {
        st.tensor(name)
            .unwrap_or_else(|_| panic!("missing {name}"))
            .shape()
            .to_vec()
    };
    assert_eq!(shape("attention_masks"), vec![53, 128, 128]);
    assert_eq!(shape("mean_albedo")[1..], [512, 512, 3]);
    assert_eq!(shape("ref_shape_corrections"), vec![54, 128, 128, 3]);
    let vertices = shape("sample_uv")[0];
    assert_eq!(shape("ref_shape"), vec![vertices, 2 + 1]);
    assert!(
        !dir.join(".face_fixture.safetensors.tmp").exists(),
        "no temporary file left behind"
    );
}

#[test]
fn without_the_landmark_models_the_headless_demo_still_writes_the_3d_views() {
    let dir = out_dir("demo-no-models");
    let empty = out_dir("no-models");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_likeness"))
        .args(["demo", "--headless", "--out", dir.to_str().unwrap()])
        .env("LIKENESS_MODELS", &empty)
        .env(
            "XDG_RUNTIME_DIR",
            std::env::temp_dir().join("likeness-xdg-tests"),
        )
        .env_remove("LIKENESS_FACEMODEL")
        .output()
        .expect("run likeness");
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(dir.join("shaded_neutral.png").is_file());
    assert!(!dir.join("input_0000.png").exists());
    let message = stderr(&o);
    assert!(
        message.contains("demo session could not be built")
            && message.to_lowercase().contains("openseeface"),
        "{message}"
    );
}
