//! A missing, truncated or wrongly shaped template gives an error that names the path, says
//! what is wrong and where to get the model; never a panic.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use face::error::TEMPLATE_DOWNLOAD_HINT;
use face::{FaceError, Template};
use safetensors::tensor::{Dtype, TensorView};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!(
        "likeness-template-errors-{}-{name}",
        std::process::id()
    ));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("temp dir");
    dir
}

fn assert_malformed(result: face::Result<Template>, path: &Path, needle: &str) {
    match result {
        Err(e @ FaceError::MalformedTemplate { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains(&path.display().to_string()), "{msg}");
            assert!(msg.contains(needle), "expected `{needle}` in: {msg}");
            assert!(msg.contains("ICT-FaceKit"), "{msg}");
        }
        Err(other) => panic!("expected MalformedTemplate, got {other}"),
        Ok(_) => panic!("a broken template loaded"),
    }
}

/// A tiny but complete template in the project's safetensors layout (a tetrahedron with
/// all 53 expressions), so each test can break one thing.
struct TinyTemplate {
    tensors: Vec<(String, Dtype, Vec<usize>, Vec<u8>)>,
    metadata: serde_json::Value,
}

fn f32_bytes(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}
fn i32_bytes(values: &[i32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

impl TinyTemplate {
    fn new() -> Self {
        let v = 4;
        let neutral = [
            0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0f32,
        ];
        let deltas: Vec<f32> = (0..53 * v * 3).map(|k| (k % 7) as f32 * 0.01).collect();
        let tris = [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2i32];
        let uv = [0.1, 0.1, 0.9, 0.1, 0.5, 0.9, 0.5, 0.5f32];
        let tensors = vec![
            (
                "neutral".to_owned(),
                Dtype::F32,
                vec![v, 3],
                f32_bytes(&neutral),
            ),
            (
                "expression_deltas".to_owned(),
                Dtype::F32,
                vec![53, v, 3],
                f32_bytes(&deltas),
            ),
            ("uv".to_owned(), Dtype::F32, vec![4, 2], f32_bytes(&uv)),
            (
                "triangles".to_owned(),
                Dtype::I32,
                vec![4, 3],
                i32_bytes(&tris),
            ),
            (
                "triangle_uvs".to_owned(),
                Dtype::I32,
                vec![4, 3],
                i32_bytes(&tris),
            ),
            (
                "triangle_polygon".to_owned(),
                Dtype::I32,
                vec![4],
                i32_bytes(&[0, 1, 2, 3]),
            ),
        ];
        let metadata = serde_json::json!({
            "expression_names": face::ICT_NAMES.to_vec(),
            "parts": [{"name": "face", "vertices": {"start": 0, "end": 4}, "polygons": {"start": 0, "end": 4}}],
            "materials": [{"name": "M_Face", "first_polygon": 0}],
            "landmarks_68": vec![0u32; 68],
        });
        Self { tensors, metadata }
    }

    fn replace(&mut self, name: &str, dtype: Dtype, shape: Vec<usize>, data: Vec<u8>) {
        let t = self
            .tensors
            .iter_mut()
            .find(|t| t.0 == name)
            .expect("tensor");
        *t = (name.to_owned(), dtype, shape, data);
    }

    fn write(&self, path: &Path) {
        let views: Vec<(String, TensorView<'_>)> = self
            .tensors
            .iter()
            .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).expect("view")))
            .collect();
        let meta = HashMap::from([("ict_facekit".to_owned(), self.metadata.to_string())]);
        safetensors::serialize_to_file(views, Some(meta), path).expect("write");
    }
}

#[test]
fn the_tiny_template_itself_loads() {
    let dir = temp_dir("ok");
    let path = dir.join("tiny.safetensors");
    TinyTemplate::new().write(&path);
    let t = Template::load(&path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(t.vertex_count(), 4);
    assert_eq!(t.triangles.len(), 4);
}

#[test]
fn a_missing_file_names_the_path_and_where_to_get_the_model() {
    let path = Path::new("/nonexistent/likeness/ict_face_model.safetensors");
    let err = Template::load(path).expect_err("must fail");
    assert!(matches!(err, FaceError::TemplateNotFound { .. }), "{err}");
    let msg = err.to_string();
    assert!(msg.contains("/nonexistent/likeness"), "{msg}");
    assert!(msg.contains(TEMPLATE_DOWNLOAD_HINT), "{msg}");
}

#[test]
fn a_folder_without_a_model_is_not_found() {
    let dir = temp_dir("empty-folder");
    let err = Template::load(&dir).expect_err("must fail");
    assert!(
        err.to_string().contains(&dir.display().to_string()),
        "{err}"
    );
}

#[test]
fn a_truncated_file_is_malformed() {
    let dir = temp_dir("truncated");
    let full = dir.join("full.safetensors");
    TinyTemplate::new().write(&full);
    let bytes = std::fs::read(&full).expect("read");
    for cut in [0usize, 5, 100, bytes.len() - 10] {
        let path = dir.join(format!("cut{cut}.safetensors"));
        std::fs::write(&path, &bytes[..cut]).expect("write");
        assert_malformed(Template::load(&path), &path, "not a safetensors file");
    }
}

#[test]
fn wrongly_shaped_tensors_are_named() {
    let dir = temp_dir("shapes");
    let path = dir.join("t.safetensors");

    let mut t = TinyTemplate::new();
    t.replace(
        "expression_deltas",
        Dtype::F32,
        vec![53, 5, 3],
        f32_bytes(&vec![0.0; 53 * 5 * 3]),
    );
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "expression_deltas");

    let mut t = TinyTemplate::new();
    t.replace("uv", Dtype::F32, vec![4, 3], f32_bytes(&[0.0; 12]));
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "uv");

    let mut t = TinyTemplate::new();
    t.replace("neutral", Dtype::I32, vec![4, 3], i32_bytes(&[0; 12]));
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "neutral");

    let mut t = TinyTemplate::new();
    t.replace(
        "triangles",
        Dtype::I32,
        vec![4, 3],
        i32_bytes(&[0, 1, 2, 0, 2, 9, 0, 3, 1, 1, 3, 2]),
    );
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "triangle 1 refers to index 9");
}

#[test]
fn bad_metadata_and_values_are_named() {
    let dir = temp_dir("meta");
    let path = dir.join("t.safetensors");

    let mut t = TinyTemplate::new();
    t.metadata["expression_names"][26] = serde_json::json!("notJawOpen");
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "jawOpen");

    let mut t = TinyTemplate::new();
    t.metadata["landmarks_68"] = serde_json::json!([1, 2, 3]);
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "landmarks_68");

    let mut t = TinyTemplate::new();
    t.metadata = serde_json::json!({"something": "else"});
    t.write(&path);
    assert_malformed(Template::load(&path), &path, "ict_facekit");

    let mut t = TinyTemplate::new();
    let mut neutral = vec![0.0f32; 12];
    neutral[4] = f32::NAN;
    t.replace("neutral", Dtype::F32, vec![4, 3], f32_bytes(&neutral));
    t.write(&path);
    assert_malformed(
        Template::load(&path),
        &path,
        "neutral vertex 1 is not finite",
    );
}
