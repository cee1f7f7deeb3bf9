//! `likeness retarget` end to end through the binary: hand-written tracks onto the
//! project's puppets in all three output formats, and clear failures for bad input.

use std::path::{Path, PathBuf};
use std::process::Command;

fn likeness(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_likeness"))
        .args(args)
        .output()
        .expect("run likeness");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

/// A fresh folder per test: tests run in parallel, and a shared one would be emptied by
/// one test under another.
fn temp_dir(test: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "likeness-cli-retarget-{test}-{}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

const TRACKS: &str = r#"{"arkit_names": ["JawOpen", "eyeBlink_L", "mouthSmileLeft"],
 "frames": [
  {"time_s": 0.0, "arkit_weights": [0.0, 0.0, 0.0], "rotation_deg": [0, 0, 0]},
  {"time_s": 0.1, "arkit_weights": [0.5, 1.0, 0.2], "rotation_deg": [10, -5, 2]},
  {"face": false},
  {"time_s": 0.3, "arkit_weights": [1.0, 0.0, 0.8], "rotation_deg": [-10, 5, 0]}
 ]}"#;

#[test]
fn retargets_hand_written_tracks_in_every_format() {
    let dir = temp_dir("formats");
    let tracks = dir.join("tracks.json");
    std::fs::write(&tracks, TRACKS).unwrap();
    for puppet in ["assets/puppets/pip.glb", "assets/puppets/bolt.glb"] {
        for ext in ["glb", "csv", "json"] {
            let out = dir.join(format!("anim.{ext}"));
            let (ok, text) = likeness(&[
                "retarget",
                "--tracks",
                tracks.to_str().unwrap(),
                "--puppet",
                repo(puppet).to_str().unwrap(),
                "--out",
                out.to_str().unwrap(),
            ]);
            assert!(ok, "{puppet} -> {ext}: {text}");
            assert!(
                text.contains("mapped 52 channel(s)") && text.contains("wrote"),
                "{text}"
            );
            assert!(out.metadata().unwrap().len() > 0);
        }
        // The JSON holds three frames (one had no face), the jaw weight of frame 1 is 0.5.
        let json: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(dir.join("anim.json")).unwrap()).unwrap();
        let frames = json["frames"].as_array().unwrap();
        assert_eq!(frames.len(), 3);
        let targets = json["targets"].as_array().unwrap();
        let jaw = targets
            .iter()
            .position(|t| {
                t["name"]
                    .as_str()
                    .unwrap()
                    .to_ascii_lowercase()
                    .ends_with("jawopen")
            })
            .unwrap();
        assert!((frames[1]["weights"][jaw].as_f64().unwrap() - 0.5).abs() < 1e-6);
    }
    // The CSV reads back as tracks and retargets again.
    let csv = dir.join("anim.csv");
    let again = dir.join("again.json");
    let (ok, text) = likeness(&[
        "retarget",
        "--tracks",
        csv.to_str().unwrap(),
        "--puppet",
        repo("assets/puppets/pip.glb").to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(ok, "{text}");
}

#[test]
fn bad_inputs_fail_with_a_clear_message() {
    let dir = temp_dir("bad-inputs");
    let tracks = dir.join("tracks.json");
    std::fs::write(&tracks, TRACKS).unwrap();
    let broken = dir.join("broken.glb");
    std::fs::write(&broken, b"glTF\x02\x00\x00\x00").unwrap();
    let not_json = dir.join("bad_tracks.json");
    std::fs::write(&not_json, "frames: 1").unwrap();
    let pip = repo("assets/puppets/pip.glb");
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec![
                "--tracks".into(),
                tracks.display().to_string(),
                "--puppet".into(),
                broken.display().to_string(),
                "--out".into(),
                dir.join("x.glb").display().to_string(),
            ],
            "broken.glb",
        ),
        (
            vec![
                "--tracks".into(),
                not_json.display().to_string(),
                "--puppet".into(),
                pip.display().to_string(),
                "--out".into(),
                dir.join("x.glb").display().to_string(),
            ],
            "not a tracking file",
        ),
        (
            vec![
                "--tracks".into(),
                tracks.display().to_string(),
                "--puppet".into(),
                pip.display().to_string(),
                "--out".into(),
                dir.join("x.fbx").display().to_string(),
            ],
            ".glb, .csv or .json",
        ),
        (
            vec![
                "--tracks".into(),
                tracks.display().to_string(),
                "--puppet".into(),
                dir.join("missing.vrm").display().to_string(),
                "--out".into(),
                dir.join("x.glb").display().to_string(),
            ],
            "missing.vrm",
        ),
    ];
    for (args, expect) in cases {
        let mut full = vec!["retarget".to_string()];
        full.extend(args);
        let refs: Vec<&str> = full.iter().map(String::as_str).collect();
        let (ok, text) = likeness(&refs);
        assert!(!ok, "{full:?} succeeded");
        assert!(text.contains(expect), "{full:?}: {text}");
        assert!(!text.contains("panicked"), "{text}");
    }
}
