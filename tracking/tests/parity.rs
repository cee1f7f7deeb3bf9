//! Preprocessing and inference identical to training: the crop, the input tensor and the
//! networks' outputs against what the training code computed (ONNX Runtime in Python) on
//! the fixture `python -m likeness_train.fixtures` exports; and the two Rust backends
//! against each other.

mod common;

use common::{fixture_dir, max_abs_diff, tensor};
use glam::Vec2;
use tracking::backend::{BackendKind, onnxruntime_status};
use tracking::networks::{Manifest, ModelNet, TrackNet, default_networks_dir};
use tracking::personalize::stack;
use tracking::preprocess::{Rect, sample_rect};
use tracking::source::read_image;

/// One fixture frame: the image, its landmarks, the training code's crop and its inputs
/// for TrackNet and for ModelNet (each at its network's size).
type FixtureFrame = (image::RgbImage, Vec<Vec2>, [f32; 4], Vec<f32>, Vec<f32>);

struct Fixture {
    frames: Vec<FixtureFrame>,
    bytes: Vec<u8>,
}

fn load_fixture() -> Fixture {
    let dir = fixture_dir();
    let meta: serde_json::Value = serde_json::from_str(
        &std::fs::read_to_string(dir.join("fixture.json")).expect("fixture.json"),
    )
    .expect("fixture.json is JSON");
    let bytes = std::fs::read(dir.join("fixture.safetensors")).expect("fixture.safetensors");
    let st = safetensors::SafeTensors::deserialize(&bytes).expect("safetensors");
    let count = meta["frames"].as_u64().unwrap_or(0) as usize;
    assert!(
        count >= 4,
        "the fixture has {count} frames, expected at least 4"
    );
    let frames = (0..count)
        .map(|k| {
            let image =
                read_image(&dir.join(format!("frames/frame_{k}.png"))).expect("fixture frame");
            let (_, lm) = tensor(&st, &format!("landmarks_{k}"));
            let lm = lm.chunks_exact(2).map(|p| Vec2::new(p[0], p[1])).collect();
            let (_, crop) = tensor(&st, &format!("crop_{k}"));
            let (_, input) = tensor(&st, &format!("input_{k}"));
            let (_, model_input) = tensor(&st, &format!("model_input_{k}"));
            (
                image,
                lm,
                [crop[0], crop[1], crop[2], crop[3]],
                input,
                model_input,
            )
        })
        .collect();
    Fixture { frames, bytes }
}

#[test]
fn crop_and_input_tensor_match_the_training_code() {
    let manifest = Manifest::load(&default_networks_dir()).expect("manifest");
    let fx = load_fixture();
    for (k, (image, landmarks, crop, input, model_input)) in fx.frames.iter().enumerate() {
        let rect = manifest.crop.crop_for_landmarks(landmarks).expect("crop");
        let got = rect.to_array();
        for (a, b) in got.iter().zip(crop) {
            assert!(
                (a - b).abs() < 1e-3,
                "frame {k}: crop {got:?} vs training {crop:?}"
            );
        }
        let fixture_rect = Rect {
            x: crop[0],
            y: crop[1],
            width: crop[2],
            height: crop[3],
        };
        for (network, s, want) in [
            ("TrackNet", manifest.track_input_size, input),
            ("ModelNet", manifest.input_size, model_input),
        ] {
            let tensor =
                sample_rect(image, fixture_rect, s, s, manifest.normalisation).expect("sample");
            let d = max_abs_diff(&tensor.data, want);
            assert!(
                d < 1e-4,
                "frame {k}: {network}'s input tensor differs by {d}"
            );
        }
    }
}

fn track_outputs_match(kind: BackendKind) {
    let manifest = Manifest::load(&default_networks_dir()).expect("manifest");
    let fx = load_fixture();
    let st = safetensors::SafeTensors::deserialize(&fx.bytes).expect("safetensors");
    let mut net = TrackNet::load(&manifest, kind, 2).expect("TrackNet");
    let s = manifest.track_input_size;
    for (k, (_, _, _, input, _)) in fx.frames.iter().enumerate() {
        let t = tracking::Tensor::new(vec![1, 3, s, s], input.clone()).expect("tensor");
        let out = net.run(&t).expect("run").remove(0).expect("finite");
        for (name, got) in [
            ("w", out.weights.to_vec()),
            ("euler", out.euler_rad.to_array().to_vec()),
            ("translation", out.translation_ref.to_array().to_vec()),
            ("gamma", out.gamma.to_vec()),
        ] {
            let (_, want) = tensor(&st, &format!("{name}_{k}"));
            let d = max_abs_diff(&got, &want);
            assert!(d < 1e-4, "{kind}: frame {k} `{name}` differs by {d}");
        }
    }
    // ModelNet on all the fixture's inputs.
    let mut model = ModelNet::load(&manifest, kind, 2).expect("ModelNet");
    let m = manifest.input_size;
    let inputs: Vec<tracking::Tensor> = fx
        .frames
        .iter()
        .map(|f| tracking::Tensor::new(vec![1, 3, m, m], f.4.clone()).expect("tensor"))
        .collect();
    let refs: Vec<&tracking::Tensor> = inputs.iter().collect();
    let corrections = model
        .run(&stack(&refs).expect("stack"))
        .expect("ModelNet run");
    let (_, ds0) = tensor(&st, "dS0");
    let n = 128 * 128;
    // Spot-check channel planes against the Python outputs (layout conversion included).
    for c in 0..3 {
        for t in [0usize, 777, 8191, n - 1] {
            let got = corrections.identity_shape.data[t * 3 + c];
            let want = ds0[c * n + t];
            assert!(
                (got - want).abs() < 1e-4,
                "{kind}: dS0[{c}, {t}] {got} vs {want}"
            );
        }
    }
    let (_, dr) = tensor(&st, "dR");
    let i = 26; // jawOpen
    let mut worst: f32 = 0.0;
    for c in 0..3 {
        for t in 0..n {
            let got = corrections.dynamic_albedo[i].data[t * 3 + c];
            worst = worst.max((got - dr[(i * 3 + c) * n + t]).abs());
        }
    }
    assert!(worst < 1e-4, "{kind}: dR of jawOpen differs by {worst}");
}

#[test]
fn tract_outputs_match_the_training_code() {
    track_outputs_match(BackendKind::Tract);
}

#[test]
fn onnxruntime_outputs_match_the_training_code() {
    onnxruntime_status().unwrap_or_else(|e| panic!("scripts/setup.sh installs ONNX Runtime: {e}"));
    track_outputs_match(BackendKind::OnnxRuntime);
}
