//! Import (and export) of the upstream ICT FaceKit folder (`FaceXModel/` of the public
//! repository `ICT-VGL/ICT-FaceKit`), so that the converted safetensors file is a
//! convenience and not a hidden dependency: a user outside this workplace can point the app
//! at a clone of the upstream repository and get the same [`Template`].
//!
//! The import reproduces the conversion exactly: positions and texture coordinates in file
//! order, polygons fan-split into triangles `(0, 1, 2), (0, 2, 3), ...` in file order, one
//! material run per `usemtl`, blendshapes and identity components stored as differences to
//! the neutral mesh.
//!
//! The upstream folder does not describe the geometry parts (face, head and neck, eyes, ...),
//! so they are constants here, valid for the vertex order of the ICT FaceKit light model
//! (26,719 vertices, face first); the 68 landmarks come from the folder's
//! `vertex_indices.json` when it lists them, else from constants for the same order. Another
//! revision of the upstream folder has the same counts but a different vertex order; the
//! import recognises it by checking that the part table fits the mesh topology, instead of
//! silently attaching wrong parts.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::error::{FaceError, Result};
use crate::names::ICT_NAMES;
use crate::template::{MaterialRun, NUM_LANDMARKS, Part, RawTemplate, Template};

/// Upstream folder name inside the repository.
pub const FACEX_FOLDER: &str = "FaceXModel";
/// Upstream neutral mesh S_0; its presence is what identifies an ICT FaceKit folder.
pub const NEUTRAL_FILE: &str = "generic_neutral_mesh.obj";
/// Upstream index lists (expression names, fitting vertices, landmarks).
pub const VERTEX_INDICES_FILE: &str = "vertex_indices.json";
/// Upstream material library referenced by every OBJ.
pub const MATERIAL_FILE: &str = "ICTFaceModelMaterial.mtl";
/// Vertex count of the ICT FaceKit light model, the layout [`light_model_parts`] and
/// [`LANDMARKS_68`] are written for.
pub const LIGHT_MODEL_VERTICES: usize = 26_719;
/// Polygon count of the ICT FaceKit light model.
pub const LIGHT_MODEL_POLYGONS: usize = 26_384;

/// Geometry parts of the light model: name, half-open vertex range, half-open polygon range.
/// The light model keeps each part contiguous in both vertices and polygons, but the data
/// folder does not record the ranges (taken from the project's safetensors conversion).
const LIGHT_MODEL_PARTS: [(&str, Range<u32>, Range<u32>); 17] = [
    ("face", 0..9409, 0..9230),
    ("head_and_neck", 9409..11248, 9230..11144),
    ("mouth_socket", 11248..13294, 11144..13226),
    ("eye_socket_left", 13294..13678, 13226..13630),
    ("eye_socket_right", 13678..14062, 13630..14034),
    ("gums_and_tongue", 14062..17039, 14034..17006),
    ("teeth", 17039..21451, 17006..21496),
    ("eyeball_left", 21451..23021, 21496..23094),
    ("eyeball_right", 23021..24591, 23094..24692),
    ("lacrimal_fluid_left", 24591..24795, 24692..24855),
    ("lacrimal_fluid_right", 24795..24999, 24855..25018),
    ("eye_blend_left", 24999..25023, 25018..25033),
    ("eye_blend_right", 25023..25047, 25033..25048),
    ("eye_occlusion_left", 25047..25199, 25048..25176),
    ("eye_occlusion_right", 25199..25351, 25176..25304),
    ("eyelashes_left", 25351..26035, 25304..25844),
    ("eyelashes_right", 26035..26719, 25844..26384),
];

/// Vertex of each of the 68 Multi-PIE / iBUG landmarks on the light model; used when the
/// folder's `vertex_indices.json` is missing or does not list them.
pub const LANDMARKS_68: [u32; NUM_LANDMARKS] = [
    1225, 1888, 1052, 367, 1719, 1722, 2199, 1447, 966, 3661, //
    4390, 3927, 3924, 2608, 3272, 4088, 3443, 268, 493, 1914, //
    2044, 1401, 3615, 4240, 4114, 2734, 2509, 978, 4527, 4942, //
    4857, 1140, 2075, 1147, 4269, 3360, 1507, 1542, 1537, 1528, //
    1518, 1511, 3742, 3751, 3756, 3721, 3725, 3732, 5708, 5695, //
    2081, 0, 4275, 6200, 6213, 6346, 6461, 5518, 5957, 5841, //
    5702, 5711, 5533, 6216, 6207, 6470, 5517, 5966,
];

/// The geometry parts of the light model, in vertex order.
pub fn light_model_parts() -> Vec<Part> {
    LIGHT_MODEL_PARTS
        .iter()
        .map(|(name, vertices, polygons)| Part {
            name: (*name).to_string(),
            vertices: vertices.clone(),
            polygons: polygons.clone(),
        })
        .collect()
}

/// Imports the upstream OBJ folder; `path` is the `FaceXModel` folder or its parent.
///
/// Identity OBJs are optional: `identity_count` is the number of files found contiguously
/// from `identity000.obj`, so a partial download still gives a usable template.
pub fn import_ict_folder(path: &Path) -> Result<Template> {
    let folder = locate_folder(path)?;
    let neutral_path = folder.join(NEUTRAL_FILE);
    let neutral = parse_obj(&read_text(&neutral_path)?, &neutral_path, Content::Full)?;
    let vertex_count = neutral.positions.len() / 3;
    if vertex_count == 0 || neutral.triangles.is_empty() {
        return Err(malformed(
            &neutral_path,
            "no vertices or no faces (truncated file?)".into(),
        ));
    }

    if vertex_count != LIGHT_MODEL_VERTICES
        || neutral.polygon_count as usize != LIGHT_MODEL_POLYGONS
    {
        return Err(malformed(
            &neutral_path,
            format!(
                "has {vertex_count} vertices and {} polygons, but the part table and landmarks \
                 are known only for the ICT FaceKit light model ({LIGHT_MODEL_VERTICES} \
                 vertices, {LIGHT_MODEL_POLYGONS} polygons)",
                neutral.polygon_count
            ),
        ));
    }
    let parts = light_model_parts();
    check_parts_fit_topology(&parts, &neutral, &neutral_path)?;
    let landmarks_68 = read_landmarks(&folder)?.unwrap_or_else(|| LANDMARKS_68.to_vec());

    let mut expression_deltas = Vec::with_capacity(ICT_NAMES.len() * vertex_count * 3);
    for name in ICT_NAMES {
        let shape_path = folder.join(format!("{name}.obj"));
        if !shape_path.is_file() {
            return Err(malformed(
                &shape_path,
                format!("the expression `{name}` (one of the 53 ICT blendshapes) is missing"),
            ));
        }
        push_shape_delta(&mut expression_deltas, &shape_path, &neutral.positions)?;
    }

    let mut identity_deltas = Vec::new();
    let mut identity_count = 0;
    loop {
        let identity_path = folder.join(format!("identity{identity_count:03}.obj"));
        if !identity_path.is_file() {
            break;
        }
        push_shape_delta(&mut identity_deltas, &identity_path, &neutral.positions)?;
        identity_count += 1;
    }

    let raw = RawTemplate {
        neutral: neutral.positions.iter().map(|&x| x as f32).collect(),
        expression_names: ICT_NAMES.iter().map(|n| (*n).to_string()).collect(),
        expression_deltas,
        identity_deltas,
        identity_count,
        uvs: neutral.uvs,
        triangles: neutral.triangles,
        triangle_uvs: neutral.triangle_uvs,
        triangle_polygon: neutral.triangle_polygon,
        parts,
        materials: neutral.materials,
        landmarks_68,
    };
    raw.validate(&folder)
}

/// Writes `template` as an upstream-style folder (neutral, the 53 expression OBJs, one OBJ
/// per identity component, `vertex_indices.json` and a material library), so that it can be
/// opened in any DCC tool or read back with [`import_ict_folder`].
///
/// Polygons are rebuilt from the triangles that share a `triangle_polygon`, which is only
/// possible for consecutive fan-split polygons numbered in order (as the import produces).
pub fn export_ict_folder(template: &Template, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|source| FaceError::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let topology = topology_text(template)?;
    let v = template.vertex_count();
    write_file(&dir.join(NEUTRAL_FILE), |out| {
        write_positions_obj(out, template.neutral.iter().copied(), &topology)
    })?;
    for (i, name) in ICT_NAMES.iter().enumerate() {
        let delta = shape_slice(&template.expression_deltas, v, "expression", i)?;
        write_file(&dir.join(format!("{name}.obj")), |out| {
            let positions = template.neutral.iter().zip(delta).map(|(&n, &d)| n + d);
            write_positions_obj(out, positions, &topology)
        })?;
    }
    for k in 0..template.identity_count {
        let delta = shape_slice(&template.identity_deltas, v, "identity component", k)?;
        write_file(&dir.join(format!("identity{k:03}.obj")), |out| {
            let positions = template.neutral.iter().zip(delta).map(|(&n, &d)| n + d);
            write_positions_obj(out, positions, &topology)
        })?;
    }

    let indices = serde_json::json!({
        "expressions": ICT_NAMES.as_slice(),
        "idx_to_landmark_verts": template.landmarks_68.as_slice(),
    });
    write_file(&dir.join(VERTEX_INDICES_FILE), |out| {
        serde_json::to_writer_pretty(&mut *out, &indices).map_err(std::io::Error::other)?;
        writeln!(out)
    })?;
    write_file(&dir.join(MATERIAL_FILE), |out| {
        let mut seen: Vec<&str> = Vec::new();
        for run in &template.materials {
            if !seen.contains(&run.name.as_str()) {
                seen.push(&run.name);
                writeln!(out, "newmtl {}\nKd 0.8 0.8 0.8\n", run.name)?;
            }
        }
        Ok(())
    })
}

fn shape_slice<'a>(
    deltas: &'a [glam::Vec3],
    v: usize,
    what: &str,
    k: usize,
) -> Result<&'a [glam::Vec3]> {
    deltas
        .get(k * v..(k + 1) * v)
        .ok_or_else(|| FaceError::InvalidInput(format!("cannot export: {what} {k} is missing")))
}

fn malformed(path: &Path, reason: String) -> FaceError {
    FaceError::MalformedTemplate {
        path: path.to_path_buf(),
        reason,
    }
}

fn line_error(path: &Path, line: usize, reason: impl std::fmt::Display) -> FaceError {
    malformed(path, format!("line {line}: {reason}"))
}

/// Accepts the `FaceXModel` folder itself or the repository root holding it, because users
/// naturally pass either the clone or the data folder.
fn locate_folder(path: &Path) -> Result<PathBuf> {
    if path.join(NEUTRAL_FILE).is_file() {
        return Ok(path.to_path_buf());
    }
    let nested = path.join(FACEX_FOLDER);
    if nested.join(NEUTRAL_FILE).is_file() {
        return Ok(nested);
    }
    let reason = if !path.exists() {
        "no such folder".to_string()
    } else if !path.is_dir() {
        "not a folder".to_string()
    } else {
        format!("neither it nor its `{FACEX_FOLDER}` subfolder holds `{NEUTRAL_FILE}`")
    };
    Err(FaceError::TemplateNotFound {
        path: path.to_path_buf(),
        reason,
    })
}

fn read_text(path: &Path) -> Result<String> {
    let bytes = std::fs::read(path).map_err(|source| FaceError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    String::from_utf8(bytes).map_err(|e| {
        malformed(
            path,
            format!(
                "not a text OBJ (invalid UTF-8 at byte {})",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// Parses a blendshape or identity OBJ and appends its difference to the neutral.
///
/// The difference is taken in f64 because the files hold the shapes, not the deltas: a
/// small delta on a coordinate of ~10 cm would otherwise lose most of its f32 digits.
fn push_shape_delta(out: &mut Vec<f32>, path: &Path, neutral: &[f64]) -> Result<()> {
    let shape = parse_obj(&read_text(path)?, path, Content::PositionsOnly)?;
    if shape.positions.len() != neutral.len() {
        return Err(malformed(
            path,
            format!(
                "has {} vertices but {NEUTRAL_FILE} has {} (every shape must share the \
                 neutral mesh's vertices)",
                shape.positions.len() / 3,
                neutral.len() / 3
            ),
        ));
    }
    out.extend(
        shape
            .positions
            .iter()
            .zip(neutral)
            .map(|(s, n)| (s - n) as f32),
    );
    Ok(())
}

/// Landmarks from the folder's own `vertex_indices.json` (upstream key
/// `idx_to_landmark_verts`), preferred over [`LANDMARKS_68`] because the file belongs to the
/// same vertex order as the OBJs next to it.
fn read_landmarks(folder: &Path) -> Result<Option<Vec<u32>>> {
    #[derive(serde::Deserialize)]
    struct VertexIndices {
        #[serde(default)]
        idx_to_landmark_verts: Option<Vec<u32>>,
    }
    let path = folder.join(VERTEX_INDICES_FILE);
    if !path.is_file() {
        return Ok(None);
    }
    let parsed: VertexIndices = serde_json::from_str(&read_text(&path)?)
        .map_err(|e| malformed(&path, format!("not valid JSON: {e}")))?;
    Ok(parsed.idx_to_landmark_verts)
}

/// Guards against attaching the light model's part table to a folder with another vertex
/// order (another upstream revision has the same counts): in the light model every polygon
/// of a part uses only vertices of that part or of earlier parts, and at least one of its
/// own.
fn check_parts_fit_topology(parts: &[Part], mesh: &ObjMesh, path: &Path) -> Result<()> {
    let order_hint = "this folder has a different vertex order than the ICT FaceKit light \
                      model (another upstream revision?); use the current FaceXModel folder";
    let mut has_own_vertex = vec![false; mesh.polygon_count as usize];
    for (tri, &polygon) in mesh.triangles.chunks_exact(3).zip(&mesh.triangle_polygon) {
        let Some(part) = parts.iter().find(|p| p.polygons.contains(&polygon)) else {
            return Err(malformed(
                path,
                format!("polygon {polygon} is in no part of the light model"),
            ));
        };
        if let Some(&v) = tri.iter().find(|&&v| v as u32 >= part.vertices.end) {
            return Err(malformed(
                path,
                format!(
                    "polygon {polygon} of part `{}` uses vertex {v}, beyond the part's \
                     vertices {:?}: {order_hint}",
                    part.name, part.vertices
                ),
            ));
        }
        if tri.iter().any(|&v| v as u32 >= part.vertices.start)
            && let Some(flag) = has_own_vertex.get_mut(polygon as usize)
        {
            *flag = true;
        }
    }
    if let Some(polygon) = has_own_vertex.iter().position(|&own| !own) {
        let name = parts
            .iter()
            .find(|p| p.polygons.contains(&(polygon as u32)))
            .map_or("?", |p| p.name.as_str());
        return Err(malformed(
            path,
            format!(
                "polygon {polygon} of part `{name}` uses none of the part's vertices: {order_hint}"
            ),
        ));
    }
    Ok(())
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Content {
    /// Positions, texture coordinates, faces and materials (the neutral mesh).
    Full,
    /// Positions only: shapes share the neutral's topology, and skipping the rest halves
    /// the parsing time of the ~150 shape files.
    PositionsOnly,
}

/// What the import needs from one OBJ, with indices 0-based.
#[derive(Default)]
struct ObjMesh {
    positions: Vec<f64>,
    uvs: Vec<f32>,
    triangles: Vec<i32>,
    triangle_uvs: Vec<i32>,
    triangle_polygon: Vec<u32>,
    polygon_count: u32,
    materials: Vec<MaterialRun>,
}

/// A small OBJ reader instead of `tobj`: `tobj` splits the mesh into one model per
/// material and re-indexes positions per model, and its triangulation forgets which
/// polygon each triangle came from; the template needs the file's global vertex and UV
/// numbering, the polygon index of every triangle and the `usemtl` runs by polygon.
fn parse_obj(text: &str, path: &Path, content: Content) -> Result<ObjMesh> {
    let full = content == Content::Full;
    let mut mesh = ObjMesh::default();
    let mut corners: Vec<(i32, i32)> = Vec::with_capacity(8);
    for (index, raw_line) in text.lines().enumerate() {
        let line_no = index + 1;
        let line = raw_line.split('#').next().unwrap_or("");
        let mut tokens = line.split_ascii_whitespace();
        let Some(keyword) = tokens.next() else {
            continue;
        };
        match keyword {
            "v" => {
                let xyz = parse_coords::<3>(&mut tokens, path, line_no, "v")?;
                mesh.positions.extend(xyz);
            }
            "vt" if full => {
                let uv = parse_coords::<2>(&mut tokens, path, line_no, "vt")?;
                mesh.uvs.extend(uv.map(|x| x as f32));
            }
            "f" if full => {
                corners.clear();
                let vertex_count = mesh.positions.len() / 3;
                let uv_count = mesh.uvs.len() / 2;
                for token in tokens {
                    corners.push(parse_corner(token, vertex_count, uv_count, path, line_no)?);
                }
                if corners.len() < 3 {
                    return Err(line_error(
                        path,
                        line_no,
                        format!("a face needs at least 3 corners, found {}", corners.len()),
                    ));
                }
                let polygon = mesh.polygon_count;
                for k in 1..corners.len() - 1 {
                    let (a, b, c) = (corners[0], corners[k], corners[k + 1]);
                    mesh.triangles.extend([a.0, b.0, c.0]);
                    mesh.triangle_uvs.extend([a.1, b.1, c.1]);
                    mesh.triangle_polygon.push(polygon);
                }
                mesh.polygon_count += 1;
            }
            "usemtl" if full => {
                let name = tokens
                    .next()
                    .ok_or_else(|| line_error(path, line_no, "`usemtl` without a material name"))?;
                start_material_run(&mut mesh.materials, name, mesh.polygon_count);
            }
            // mtllib, vn, o, g, s and anything else carry nothing the template uses.
            _ => {}
        }
    }
    Ok(mesh)
}

/// Records that polygons from `first_polygon` on use `name`, folding a `usemtl` that names
/// the current material again, and replacing a run that got no polygons.
fn start_material_run(runs: &mut Vec<MaterialRun>, name: &str, first_polygon: u32) {
    if runs
        .last()
        .is_some_and(|r| r.first_polygon == first_polygon)
    {
        runs.pop();
    }
    if runs.last().is_some_and(|r| r.name == name) {
        return;
    }
    runs.push(MaterialRun {
        name: name.to_string(),
        first_polygon,
    });
}

fn parse_coords<'a, const N: usize>(
    tokens: &mut impl Iterator<Item = &'a str>,
    path: &Path,
    line_no: usize,
    keyword: &str,
) -> Result<[f64; N]> {
    let mut out = [0.0; N];
    let mut found = 0;
    // Optional extras (w, or vertex colours) are checked but not kept.
    for token in tokens {
        let value: f64 = token.parse().map_err(|_| {
            line_error(
                path,
                line_no,
                format!("`{keyword}` has a non-numeric value `{token}`"),
            )
        })?;
        if !value.is_finite() {
            return Err(line_error(
                path,
                line_no,
                format!("`{keyword}` has a non-finite value `{token}`"),
            ));
        }
        if found < N {
            out[found] = value;
        }
        found += 1;
    }
    if found < N {
        return Err(line_error(
            path,
            line_no,
            format!("`{keyword}` needs {N} numbers, found {found} (truncated line?)"),
        ));
    }
    Ok(out)
}

/// One `v/vt[/vn]` face corner as 0-based (vertex, uv) indices; OBJ indices are 1-based,
/// negative ones count back from the last element defined so far.
fn parse_corner(
    token: &str,
    vertex_count: usize,
    uv_count: usize,
    path: &Path,
    line_no: usize,
) -> Result<(i32, i32)> {
    let mut fields = token.split('/');
    let vertex = fields.next().unwrap_or("");
    let uv = fields.next().unwrap_or("");
    if uv.is_empty() {
        return Err(line_error(
            path,
            line_no,
            format!("face corner `{token}` has no texture coordinate (expected v/vt)"),
        ));
    }
    let resolve = |field: &str, count: usize, what: &str| -> Result<i32> {
        let raw: i64 = field.parse().map_err(|_| {
            line_error(
                path,
                line_no,
                format!("face corner `{token}` is not v/vt numbers"),
            )
        })?;
        let index = if raw > 0 { raw - 1 } else { count as i64 + raw };
        if raw == 0 || index < 0 || index >= count as i64 {
            return Err(line_error(
                path,
                line_no,
                format!("face corner `{token}` refers to {what} {raw}, but {count} are defined"),
            ));
        }
        i32::try_from(index)
            .map_err(|_| line_error(path, line_no, format!("face corner `{token}` is too large")))
    };
    Ok((
        resolve(vertex, vertex_count, "vertex")?,
        resolve(uv, uv_count, "texture coordinate")?,
    ))
}

fn write_file(
    path: &Path,
    body: impl FnOnce(&mut BufWriter<&mut File>) -> std::io::Result<()>,
) -> Result<()> {
    Ok(files::write_atomically_with(path, |file| {
        let mut out = BufWriter::new(file);
        body(&mut out)?;
        out.flush()
    })?)
}

/// Writes positions with Rust's shortest round-trip float formatting, so a re-import
/// reads back the exact f32 values.
fn write_positions_obj(
    out: &mut impl Write,
    positions: impl Iterator<Item = glam::Vec3>,
    topology: &[u8],
) -> std::io::Result<()> {
    writeln!(out, "mtllib {MATERIAL_FILE}")?;
    for p in positions {
        writeln!(out, "v {} {} {}", p.x, p.y, p.z)?;
    }
    out.write_all(topology)
}

/// The `vt`, `usemtl` and `f` lines shared by every exported OBJ, built once.
fn topology_text(template: &Template) -> Result<Vec<u8>> {
    let invalid = |reason: String| FaceError::InvalidInput(format!("cannot export: {reason}"));
    let (tris, tri_uvs) = (&template.triangles, &template.triangle_uvs);
    if tri_uvs.len() != tris.len() || template.triangle_polygon.len() != tris.len() {
        return Err(invalid(
            "triangles, triangle_uvs and triangle_polygon differ in length".into(),
        ));
    }
    let mut out = Vec::new();
    let io = |e: std::io::Error| invalid(e.to_string());
    for uv in &template.uvs {
        writeln!(out, "vt {} {}", uv.x, uv.y).map_err(io)?;
    }
    let mut runs = template.materials.iter().peekable();
    let mut polygon = 0u32;
    let mut t = 0;
    while t < tris.len() {
        if template.triangle_polygon.get(t) != Some(&polygon) {
            return Err(invalid(format!(
                "triangle {t} belongs to polygon {:?}, expected polygon {polygon} (polygons must \
                 be numbered in triangle order)",
                template.triangle_polygon.get(t)
            )));
        }
        while let Some(run) = runs.next_if(|r| r.first_polygon <= polygon) {
            writeln!(out, "usemtl {}", run.name).map_err(io)?;
        }
        let mut corners = vec![
            (tris[t][0], tri_uvs[t][0]),
            (tris[t][1], tri_uvs[t][1]),
            (tris[t][2], tri_uvs[t][2]),
        ];
        t += 1;
        while t < tris.len() && template.triangle_polygon.get(t) == Some(&polygon) {
            let (first, last) = (corners[0], corners[corners.len() - 1]);
            if (tris[t][0], tri_uvs[t][0]) != first || (tris[t][1], tri_uvs[t][1]) != last {
                return Err(invalid(format!(
                    "triangle {t} of polygon {polygon} is not part of a fan split"
                )));
            }
            corners.push((tris[t][2], tri_uvs[t][2]));
            t += 1;
        }
        out.push(b'f');
        for (v, uv) in corners {
            write!(out, " {}/{}", v + 1, uv + 1).map_err(io)?;
        }
        out.push(b'\n');
        polygon += 1;
    }
    Ok(out)
}
