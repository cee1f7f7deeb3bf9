//! Shared by the integration tests: the template, the fixture and clip folders, temp dirs.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::{Arc, OnceLock};

use face::{FaceModel, Template};

pub fn face_model() -> Arc<FaceModel> {
    static MODEL: OnceLock<Arc<FaceModel>> = OnceLock::new();
    MODEL
        .get_or_init(|| {
            let template = Template::load_default(None)
                .unwrap_or_else(|e| panic!("the ICT template is needed for these tests: {e}"));
            Arc::new(FaceModel::new(template))
        })
        .clone()
}

pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// The parity fixture `python -m likeness_train.fixtures` writes (training/setup.sh).
pub fn fixture_dir() -> PathBuf {
    let dir = repo().join("training/.cache/tracking-fixture");
    assert!(
        dir.join("fixture.safetensors").is_file(),
        "{} is missing: run training/setup.sh (it runs python -m likeness_train.fixtures)",
        dir.display()
    );
    dir
}

pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("likeness-tracking-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

/// Reads an f32 tensor of the fixture.
pub fn tensor(st: &safetensors::SafeTensors<'_>, name: &str) -> (Vec<usize>, Vec<f32>) {
    let t = st
        .tensor(name)
        .unwrap_or_else(|e| panic!("fixture tensor {name}: {e}"));
    assert_eq!(t.dtype(), safetensors::Dtype::F32, "{name}");
    let data = t
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    (t.shape().to_vec(), data)
}

pub fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

/// Deterministic pseudo-random numbers in [-1, 1] (no rand dependency for tests).
pub fn noise(seed: u32) -> f64 {
    let mut x = seed.wrapping_mul(0x9E37_79B9) ^ 0x85EB_CA6B;
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846C_A68B);
    x ^= x >> 16;
    f64::from(x) / f64::from(u32::MAX) * 2.0 - 1.0
}

/// Features of the face in the real crop (`shared/testdata/faces/openseeface-raw1.png`), in
/// crop pixels, marked by eye on the image: the centres of the image-left and image-right
/// eye, the nose tip, the middle of the mouth.
pub const FACE_FEATURES_IN_CROP: [(f32, f32); 4] =
    [(78.0, 63.0), (137.0, 46.0), (116.0, 88.0), (122.0, 133.0)];

/// The real 224 x 224 face crop the tests use.
pub fn real_crop() -> image::RgbImage {
    let path = repo().join("../shared/testdata/faces/openseeface-raw1.png");
    match image::open(&path) {
        Ok(image) => image.to_rgb8(),
        Err(e) => panic!("cannot read the test face {}: {e}", path.display()),
    }
}

/// `crop` pasted at `offset` into a grey 640 x 480 frame, the size of a webcam frame.
pub fn frame_with_face(crop: &image::RgbImage, offset: (u32, u32)) -> image::RgbImage {
    let mut frame = image::RgbImage::from_pixel(640, 480, image::Rgb([128, 128, 128]));
    image::imageops::replace(&mut frame, crop, i64::from(offset.0), i64::from(offset.1));
    frame
}

/// Fails the test with the setup hint when ONNX Runtime's library cannot be loaded.
pub fn require_onnxruntime() {
    if let Err(e) = tracking::backend::onnxruntime_status() {
        panic!("ONNX Runtime is needed for this test (scripts/setup.sh installs it): {e}");
    }
}
