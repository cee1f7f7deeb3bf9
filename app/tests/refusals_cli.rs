//! What the CLI refuses rather than doing something absurd: an output that is also an
//! input (checked as the same file, not the same spelling), `track` / `personalize` with
//! the `auto` locator and no usable OpenSeeFace models, and tracks with absurd values.

mod common;

use std::path::{Path, PathBuf};
use std::process::Output;

use common::{likeness, out_dir};

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Runs `args`, expects failure whose message holds every one of `expect`, and no panic.
fn refused(args: &[&str], expect: &[&str]) {
    let o = likeness(args);
    let t = text(&o);
    assert!(!o.status.success(), "{args:?} succeeded: {t}");
    assert!(!t.contains("panicked"), "{args:?}: {t}");
    for e in expect {
        assert!(t.contains(e), "{args:?}: `{e}` missing from: {t}");
    }
}

/// `likeness retarget --tracks T --puppet P --out O`.
fn retarget_args<'a>(tracks: &'a Path, puppet: &'a Path, out: &'a Path) -> [&'a str; 7] {
    [
        "retarget",
        "--tracks",
        s(tracks),
        "--puppet",
        s(puppet),
        "--out",
        s(out),
    ]
}

/// A 160 x 120 image with a bright square in the top-right corner.
fn write_image(path: &Path) {
    image::RgbImage::from_fn(160, 120, |x, y| {
        if x > 110 && y < 50 {
            image::Rgb([230, 190, 170])
        } else {
            image::Rgb([40, 60, 80])
        }
    })
    .save(path)
    .expect("png");
}

const TRACKS: &str = r#"{"arkit_names": ["jawOpen"], "frames": [
  {"time_s": 0.0, "arkit_weights": [0.0], "rotation_deg": [0, 0, 0]},
  {"time_s": 0.1, "arkit_weights": [0.5], "rotation_deg": [10, -5, 2]}]}"#;

#[test]
fn retarget_refuses_an_output_that_is_an_input() {
    let dir = out_dir("same-retarget");
    let tracks = dir.join("tracks.json");
    std::fs::write(&tracks, TRACKS).expect("write");
    let puppet = dir.join("pip.glb");
    std::fs::copy(repo("assets/puppets/pip.glb"), &puppet).expect("copy");
    let mapping = dir.join("map.json");
    std::fs::write(&mapping, r#"{"version": 1}"#).expect("write");
    // Spelled differently: through `..`, through a symbolic link, through a hard link.
    let sub = dir.join("sub");
    std::fs::create_dir_all(&sub).expect("dir");
    let dotted = sub.join("../tracks.json");
    let linked = dir.join("linked.json");
    std::os::unix::fs::symlink(&tracks, &linked).expect("symlink");
    let hard = dir.join("hard.glb");
    std::fs::hard_link(&puppet, &hard).expect("hard link");
    let before = std::fs::read(&tracks).expect("read");
    for out in [&dotted, &linked] {
        refused(
            &retarget_args(&tracks, &puppet, out),
            &["--out", "--tracks", s(out), s(&tracks), "same file"],
        );
    }
    refused(
        &retarget_args(&tracks, &puppet, &hard),
        &["--out", "--puppet", "same file"],
    );
    refused(
        &[
            "retarget",
            "--tracks",
            s(&tracks),
            "--puppet",
            s(&puppet),
            "--mapping",
            s(&mapping),
            "--out",
            s(&mapping),
        ],
        &["--out", "--mapping", "same file"],
    );
    // The puppet's own mapping file, found beside it.
    let sidecar = retarget::mapping::sidecar_path(&puppet);
    std::fs::write(&sidecar, r#"{"version": 1}"#).expect("write");
    let sidecar_json = dir.join("pip.mapping.json");
    assert_eq!(sidecar, sidecar_json);
    refused(
        &retarget_args(&tracks, &puppet, &sidecar),
        &["mapping file", "same file"],
    );
    assert_eq!(std::fs::read(&tracks).expect("read"), before, "tracks kept");
    assert!(std::fs::read(&puppet).expect("read").starts_with(b"glTF"));
    // A new file beside the inputs is fine.
    let o = likeness(&retarget_args(&tracks, &puppet, &dir.join("anim.glb")));
    assert!(o.status.success(), "{}", text(&o));
}

#[test]
fn retarget_refuses_an_output_that_is_a_file_the_puppet_names() {
    let dir = out_dir("same-retarget-bin");
    let tracks = dir.join("tracks.json");
    std::fs::write(&tracks, TRACKS).expect("write");
    // The demo puppet as a `.gltf` whose buffer is the file `mesh.bin` beside it.
    let glb = std::fs::read(repo("assets/puppets/pip.glb")).expect("pip.glb");
    let raw = retarget::puppet::split_gltf(&glb, Path::new("pip.glb")).expect("split");
    let bin = raw.bin.expect("a binary chunk").into_owned();
    let mut json = raw.json;
    json["buffers"] = serde_json::json!([{"uri": "mesh.bin", "byteLength": bin.len()}]);
    let puppet = dir.join("pip.gltf");
    std::fs::write(&puppet, serde_json::to_vec(&json).expect("JSON")).expect("write");
    let mesh = dir.join("mesh.bin");
    std::fs::write(&mesh, &bin).expect("write");
    // It loads and exports as it is.
    let o = likeness(&retarget_args(&tracks, &puppet, &dir.join("anim.glb")));
    assert!(o.status.success(), "{}", text(&o));
    // Its buffer, spelled through `sub/..`, is not an output.
    std::fs::create_dir_all(dir.join("sub")).expect("dir");
    refused(
        &retarget_args(&tracks, &puppet, &dir.join("sub/../mesh.bin")),
        &["--out", "the puppet's buffer 0 (mesh.bin)", "same file"],
    );
    assert_eq!(std::fs::read(&mesh).expect("read"), bin, "the buffer kept");
}

#[test]
fn track_and_personalize_refuse_an_output_that_is_an_input() {
    let dir = out_dir("same-track");
    let frames = dir.join("frames");
    std::fs::create_dir_all(&frames).expect("dir");
    let image = frames.join("frame_0000.png");
    write_image(&image);
    write_image(&frames.join("frame_0001.png"));
    let before = std::fs::read(&image).expect("read");
    let image_other = dir.join("frames/../frames/frame_0000.png");
    let out = dir.join("t.json");
    let precropped = ["--locator", "precropped", "--quiet"];
    let with = |args: &[&str]| -> Vec<String> {
        args.iter()
            .chain(&precropped)
            .map(|a| a.to_string())
            .collect()
    };
    for (args, expect) in [
        (
            with(&["track", s(&image), "--out", s(&image_other)]),
            vec!["--out", "the input", "same file"],
        ),
        (
            with(&["track", s(&image), "--out", s(&out), "--csv", s(&image)]),
            vec!["--csv", "the input", "same file"],
        ),
        // Two outputs that are one file (neither exists yet).
        (
            with(&[
                "track",
                s(&image),
                "--out",
                s(&dir.join("x.out")),
                "--csv",
                s(&dir.join("sub/../x.out")),
            ]),
            vec!["--out", "--csv", "x.out", "same file"],
        ),
        // An image of the input folder.
        (
            with(&["track", s(&frames), "--out", s(&image)]),
            vec!["--out", "one of the images", "frames"],
        ),
        (
            with(&["personalize", s(&image), "--out", s(&image_other)]),
            vec!["--out", "the input", "same file"],
        ),
    ] {
        std::fs::create_dir_all(dir.join("sub")).expect("dir");
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        refused(&args, &expect);
    }
    assert_eq!(std::fs::read(&image).expect("read"), before, "frame kept");
    assert!(!dir.join("x.out").exists());
}

#[test]
fn the_face_template_is_never_an_output() {
    let dir = out_dir("same-template");
    // A stand-in template (the check comes before reading it).
    let template = dir.join("face.safetensors");
    std::fs::write(&template, b"not a template").expect("write");
    refused(
        &[
            "--facemodel",
            s(&template),
            "screenshot",
            "--out",
            s(&template),
        ],
        &["--out", "face template", "same file"],
    );
    let fixture = dir.join(likeness::fixture::FIXTURE_FILE);
    std::fs::write(&fixture, b"not a template").expect("write");
    refused(
        &[
            "--facemodel",
            s(&fixture),
            "export-fixture",
            "--out",
            s(&dir),
        ],
        &["--out", "face template", "same file"],
    );
    assert_eq!(std::fs::read(&template).expect("read"), b"not a template");
    assert_eq!(std::fs::read(&fixture).expect("read"), b"not a template");
}

#[test]
fn auto_locator_without_the_landmark_models_is_an_error_for_every_input() {
    let dir = out_dir("no-models");
    let image = dir.join("corner.png");
    write_image(&image);
    let folder = dir.join("frames");
    std::fs::create_dir_all(&folder).expect("dir");
    write_image(&folder.join("frame_0000.png"));
    // A mistyped folder, and a folder with broken model files.
    let missing = dir.join("openseefcae");
    let broken = dir.join("broken");
    std::fs::create_dir_all(&broken).expect("dir");
    for name in [
        "mnv3_detection_opt.onnx",
        "lm_model0_opt.onnx",
        "mnv3_detection_plain_b1.onnx",
        "lm_model0_plain_b1.onnx",
    ] {
        std::fs::write(broken.join(name), b"truncated").expect("write");
    }
    let out = dir.join("t.json");
    for models in [&missing, &broken] {
        for (command, input) in [
            ("track", &image),
            ("track", &folder),
            ("personalize", &image),
        ] {
            let out = if command == "track" {
                out.clone()
            } else {
                dir.join("p.likeness")
            };
            let args = [
                command,
                s(input),
                "--out",
                s(&out),
                "--models",
                s(models),
                "--quiet",
            ];
            let mut expect = vec!["face detection", s(models), "--locator precropped"];
            if models == &missing {
                // What should be in it.
                expect.extend(["does not exist", "lm_model0"]);
            }
            refused(&args, &expect);
        }
    }
    assert!(!out.exists(), "nothing written");
    // Chosen explicitly, pre-cropped input needs no models and says so in the output.
    let o = likeness(&[
        "track",
        s(&image),
        "--out",
        s(&out),
        "--models",
        s(&missing),
        "--locator",
        "precropped",
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", text(&o));
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&out).expect("output")).expect("JSON");
    assert_eq!(v["settings"]["locator"], serde_json::json!("precropped"));
}

#[test]
fn retarget_refuses_absurd_values_naming_the_file_frame_and_field() {
    let dir = out_dir("absurd");
    let puppet = repo("assets/puppets/pip.glb");
    let cases = [
        (
            "time.json",
            r#"{"arkit_names": ["jawOpen"], "frames": [{"time_s": 0, "arkit_weights": [0]}, {"time_s": 1e39, "arkit_weights": [0]}]}"#,
            vec!["time.json", "frame 1", "`time_s`"],
        ),
        (
            "rotation.json",
            r#"{"arkit_names": ["jawOpen"], "frames": [{"arkit_weights": [0], "rotation_deg": [1e30, 0, 0]}]}"#,
            vec!["rotation.json", "frame 0", "`rotation_deg` yaw"],
        ),
        (
            "weight.json",
            r#"{"arkit_names": ["jawOpen"], "frames": [{"arkit_weights": [1e300]}]}"#,
            vec!["weight.json", "frame 0", "`jawOpen`"],
        ),
        (
            "backwards.csv",
            "Timecode,BlendShapeCount,JawOpen\n00:00:01:00.000,1,0\n00:00:00:42.000,1,0\n",
            vec!["backwards.csv", "line 3", "Timecode"],
        ),
        (
            "nan.csv",
            "Timecode,BlendShapeCount,JawOpen\n00:00:01:00.000,1,0\n00:00:01:NaN,1,0\n",
            vec!["nan.csv", "line 3", "Timecode", "finite"],
        ),
    ];
    for (name, content, expect) in cases {
        let tracks = dir.join(name);
        std::fs::write(&tracks, content).expect("write");
        let out = dir.join("anim.glb");
        refused(&retarget_args(&tracks, &puppet, &out), &expect);
        assert!(!out.exists(), "{name}: nothing written");
    }
}
