//! Import of the upstream ICT FaceKit folder: the real template written out as an
//! upstream-style folder and read back must give the same template as the safetensors
//! conversion; broken folders must give errors that name the offending file.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, Weak};

use face::ict_import::{
    LANDMARKS_68, NEUTRAL_FILE, VERTEX_INDICES_FILE, export_ict_folder, import_ict_folder,
    light_model_parts,
};
use face::{FaceError, Template};

/// A folder under the system temp dir, unique to this process and test, removed on drop
/// (also when the test fails).
struct TempFolder(PathBuf);

impl TempFolder {
    fn new(name: &str) -> Self {
        let path =
            std::env::temp_dir().join(format!("face-ict-import-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&path);
        std::fs::create_dir_all(&path)
            .unwrap_or_else(|e| panic!("cannot create {}: {e}", path.display()));
        Self(path)
    }
}

impl Drop for TempFolder {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The real template and its export, shared by the tests that run at the same time: the
/// export writes ~150 MB of OBJ text, too much to repeat per test. Dropped (and the folder
/// removed) when the last test holding it ends.
struct Fixture {
    template: Template,
    /// Parent of the exported `FaceXModel/` folder, like a clone of the upstream repository.
    repo: TempFolder,
}

impl Fixture {
    fn facex(&self) -> PathBuf {
        self.repo.0.join("FaceXModel")
    }
}

fn fixture() -> Arc<Fixture> {
    static SHARED: Mutex<Weak<Fixture>> = Mutex::new(Weak::new());
    let mut shared = SHARED.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(f) = shared.upgrade() {
        return f;
    }
    let path = face::template::default_template_path();
    let mut template = Template::load_safetensors(&path)
        .unwrap_or_else(|e| panic!("the template is needed for these tests: {e}"));
    // Three identity components are enough to check the identity path and keep it fast.
    let v = template.vertex_count();
    template.identity_count = template.identity_count.min(3);
    template
        .identity_deltas
        .truncate(template.identity_count * v);
    let repo = TempFolder::new("shared");
    let fixture = Fixture { template, repo };
    export_ict_folder(&fixture.template, &fixture.facex())
        .unwrap_or_else(|e| panic!("export failed: {e}"));
    let fixture = Arc::new(fixture);
    *shared = Arc::downgrade(&fixture);
    fixture
}

/// A copy of the shared export in its own folder (hard links where possible, so only the
/// file a test breaks costs space and time).
fn copy_of_export(fixture: &Fixture, name: &str) -> TempFolder {
    let dest = TempFolder::new(name);
    let entries = std::fs::read_dir(fixture.facex()).unwrap_or_else(|e| panic!("{e}"));
    for entry in entries {
        let entry = entry.unwrap_or_else(|e| panic!("{e}"));
        let target = dest.0.join(entry.file_name());
        if std::fs::hard_link(entry.path(), &target).is_err() {
            std::fs::copy(entry.path(), &target).unwrap_or_else(|e| panic!("{e}"));
        }
    }
    dest
}

/// Replaces a (possibly hard-linked) file without touching the shared original.
fn replace(path: &Path, text: &str) {
    let _ = std::fs::remove_file(path);
    std::fs::write(path, text).unwrap_or_else(|e| panic!("cannot write {}: {e}", path.display()));
}

fn read(path: &Path) -> String {
    std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()))
}

fn max_abs_diff(a: &[glam::Vec3], b: &[glam::Vec3]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).abs().max_element())
        .fold(0.0, f32::max)
}

fn assert_malformed(result: face::Result<Template>, file: &str, also: &[&str]) -> String {
    match result {
        Err(e @ FaceError::MalformedTemplate { .. }) => {
            let message = e.to_string();
            assert!(
                message.contains(file),
                "message does not name {file}: {message}"
            );
            for word in also {
                assert!(message.contains(word), "message lacks `{word}`: {message}");
            }
            message
        }
        Err(e) => panic!("expected MalformedTemplate naming {file}, got {e:?}"),
        Ok(_) => panic!("expected MalformedTemplate naming {file}, import succeeded"),
    }
}

#[test]
fn export_then_import_reproduces_the_safetensors_template() {
    let fixture = fixture();
    let original = &fixture.template;

    // The exported neutral writes quads as quads, as upstream does.
    let neutral_text = read(&fixture.facex().join(NEUTRAL_FILE));
    let faces = neutral_text.lines().filter(|l| l.starts_with("f ")).count();
    let quads = neutral_text
        .lines()
        .filter(|l| l.starts_with("f ") && l.split_ascii_whitespace().count() == 5)
        .count();
    assert_eq!(faces, face::ict_import::LIGHT_MODEL_POLYGONS);
    assert_eq!(
        quads,
        original.triangles.len() - faces,
        "each quad fan-splits into one extra triangle"
    );

    // Passing the repository root (the parent of FaceXModel/) must work.
    let imported = import_ict_folder(&fixture.repo.0).unwrap_or_else(|e| panic!("{e}"));

    assert_eq!(imported.vertex_count(), original.vertex_count());
    let neutral_diff = max_abs_diff(&imported.neutral, &original.neutral);
    assert!(neutral_diff <= 1e-5, "neutral differs by {neutral_diff}");
    let expression_diff = max_abs_diff(&imported.expression_deltas, &original.expression_deltas);
    assert!(
        expression_diff <= 1e-5,
        "expression deltas differ by {expression_diff}"
    );
    assert_eq!(imported.identity_count, 3);
    let identity_diff = max_abs_diff(&imported.identity_deltas, &original.identity_deltas);
    assert!(
        identity_diff <= 1e-5,
        "identity deltas differ by {identity_diff}"
    );
    assert_eq!(imported.uvs, original.uvs);
    assert_eq!(imported.triangles, original.triangles);
    assert_eq!(imported.triangle_uvs, original.triangle_uvs);
    assert_eq!(imported.triangle_polygon, original.triangle_polygon);
    assert_eq!(imported.materials, original.materials);
    assert_eq!(imported.parts, original.parts);
    assert_eq!(imported.landmarks_68, original.landmarks_68);
}

#[test]
fn constants_match_the_safetensors_metadata() {
    // Without vertex_indices.json the import falls back to these constants, and the parts
    // always come from them.
    let fixture = fixture();
    assert_eq!(LANDMARKS_68, fixture.template.landmarks_68);
    assert_eq!(light_model_parts(), fixture.template.parts);
}

#[test]
fn import_without_vertex_indices_uses_the_landmark_constants() {
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "no-json");
    std::fs::remove_file(folder.0.join(VERTEX_INDICES_FILE)).unwrap_or_else(|e| panic!("{e}"));
    let imported = import_ict_folder(&folder.0).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(imported.landmarks_68, fixture.template.landmarks_68);
    assert_eq!(imported.triangles, fixture.template.triangles);
}

#[test]
fn missing_folder_is_template_not_found() {
    let missing = std::env::temp_dir().join(format!(
        "face-ict-import-{}-does-not-exist",
        std::process::id()
    ));
    match import_ict_folder(&missing) {
        Err(e @ FaceError::TemplateNotFound { .. }) => {
            assert!(
                e.to_string().contains(&missing.display().to_string()),
                "{e}"
            );
        }
        other => panic!("expected TemplateNotFound, got {:?}", other.map(|_| ())),
    }

    // A folder that exists but holds no neutral mesh.
    let empty = TempFolder::new("empty");
    match import_ict_folder(&empty.0) {
        Err(e @ FaceError::TemplateNotFound { .. }) => {
            let message = e.to_string();
            assert!(
                message.contains(&empty.0.display().to_string()),
                "{message}"
            );
            assert!(message.contains(NEUTRAL_FILE), "{message}");
        }
        other => panic!("expected TemplateNotFound, got {:?}", other.map(|_| ())),
    }
}

#[test]
fn truncated_obj_is_malformed_and_named() {
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "truncated");

    // Neutral cut in the middle of a `v` line (after its second coordinate).
    let neutral_path = folder.0.join(NEUTRAL_FILE);
    let text = read(&neutral_path);
    let line_start = text.match_indices("\nv ").nth(1000).map(|(i, _)| i + 1);
    let line_start = line_start.unwrap_or_else(|| panic!("the export has too few vertices"));
    let line = &text[line_start..];
    let cut = line_start + line.match_indices(' ').nth(2).map(|(i, _)| i).unwrap_or(0);
    replace(&neutral_path, &text[..cut]);
    let expected_line = format!("line {}", text[..line_start].lines().count() + 1);
    assert_malformed(
        import_ict_folder(&folder.0),
        NEUTRAL_FILE,
        &[&expected_line],
    );

    // An expression cut at a line boundary among its vertices: the vertex count no longer
    // matches. (A shape cut after its last `v` line still imports: only positions are read
    // from shapes.)
    replace(&neutral_path, &text);
    let shape_path = folder.0.join("eyeBlink_L.obj");
    let shape = read(&shape_path);
    let cut = shape
        .match_indices("\nv ")
        .nth(20_000)
        .map_or(0, |(i, _)| i + 1);
    replace(&shape_path, &shape[..cut]);
    assert_malformed(
        import_ict_folder(&folder.0),
        "eyeBlink_L.obj",
        &["vertices"],
    );
}

#[test]
fn non_numeric_coordinate_is_malformed_and_named() {
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "non-numeric");
    let shape_path = folder.0.join("mouthClose.obj");
    let text = read(&shape_path);
    let mut line_no = 0;
    let broken: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(i, l)| {
            if line_no == 0 && l.starts_with("v ") && i > 100 {
                line_no = i + 1;
                "v 1.5 abc 2.0".to_string()
            } else {
                l.to_string()
            }
        })
        .collect();
    replace(&shape_path, &broken.join("\n"));
    let message = assert_malformed(
        import_ict_folder(&folder.0),
        "mouthClose.obj",
        &[&format!("line {line_no}"), "abc"],
    );
    assert!(message.contains("non-numeric"), "{message}");
}

#[test]
fn expression_with_wrong_vertex_count_is_malformed_and_named() {
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "vertex-count");
    let shape_path = folder.0.join("jawOpen.obj");
    let text = read(&shape_path);
    // One extra vertex at the end.
    replace(&shape_path, &format!("{text}v 0 0 0\n"));
    let message = assert_malformed(import_ict_folder(&folder.0), "jawOpen.obj", &["vertices"]);
    let expected = format!("{} vertices", face::ict_import::LIGHT_MODEL_VERTICES + 1);
    assert!(message.contains(&expected), "{message}");
}

#[test]
fn missing_expression_is_malformed_and_named() {
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "missing-expression");
    std::fs::remove_file(folder.0.join("noseSneer_R.obj")).unwrap_or_else(|e| panic!("{e}"));
    assert_malformed(
        import_ict_folder(&folder.0),
        "noseSneer_R.obj",
        &["missing"],
    );
}

#[test]
fn other_meshes_are_rejected_before_the_part_table_is_applied() {
    let folder = TempFolder::new("tiny");
    replace(
        &folder.0.join(NEUTRAL_FILE),
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n\
         usemtl M_Face\nf 1/1 2/2 3/3 4/4\n",
    );
    assert_malformed(import_ict_folder(&folder.0), NEUTRAL_FILE, &["26719"]);
}

#[test]
fn shuffled_vertex_order_is_rejected() {
    // Another upstream revision has the same counts but another vertex order; swapping a
    // face vertex with an eyelash vertex in the faces imitates that.
    let fixture = fixture();
    let folder = copy_of_export(&fixture, "shuffled");
    let neutral_path = folder.0.join(NEUTRAL_FILE);
    let text = read(&neutral_path);
    let swapped: Vec<String> = text
        .lines()
        .map(|l| {
            if !l.starts_with("f ") {
                return l.to_string();
            }
            let corners: Vec<String> = l
                .split_ascii_whitespace()
                .skip(1)
                .map(|c| match c.split_once('/') {
                    Some(("1", uv)) => format!("26719/{uv}"),
                    Some(("26719", uv)) => format!("1/{uv}"),
                    _ => c.to_string(),
                })
                .collect();
            format!("f {}", corners.join(" "))
        })
        .collect();
    replace(&neutral_path, &swapped.join("\n"));
    assert_malformed(
        import_ict_folder(&folder.0),
        NEUTRAL_FILE,
        &["vertex order"],
    );
}
