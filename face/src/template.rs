//! The template face (ICT FaceKit light model): neutral mesh S_0, expression blendshapes S_i
//! (stored as deltas S_i - S_0), identity basis, UVs, parts and landmarks.
//!
//! Loaded from the project's safetensors conversion or imported from the upstream OBJ
//! folder (see [`crate::ict_import`]); both give the same [`Template`].

use std::collections::HashMap;
use std::ops::Range;
use std::path::{Path, PathBuf};

use glam::{Vec2, Vec3};
use safetensors::{Dtype, SafeTensors};
use serde::Deserialize;

use crate::error::{FaceError, Result};
use crate::names::{ICT_NAMES, NUM_BLENDSHAPES};

/// Env var that names the template location when no CLI flag is given.
pub const FACEMODEL_ENV: &str = "LIKENESS_FACEMODEL";
/// File name of the converted template.
pub const SAFETENSORS_FILE: &str = "ict_face_model.safetensors";
/// Number of facial landmarks (Multi-PIE / iBUG 68-point layout).
pub const NUM_LANDMARKS: usize = 68;

/// A named range of vertices and polygons of the upstream mesh (face, head_and_neck, ...).
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
pub struct Part {
    pub name: String,
    pub vertices: Range<u32>,
    pub polygons: Range<u32>,
}

/// A run of polygons sharing an upstream material, starting at `first_polygon`.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
pub struct MaterialRun {
    pub name: String,
    pub first_polygon: u32,
}

/// The template face. Units are centimetres, +y up, +z towards the viewer; `_L` shapes move
/// the subject's left side (+x).
#[derive(Clone, Debug)]
pub struct Template {
    /// S_0, one position per vertex.
    pub neutral: Vec<Vec3>,
    /// S_i - S_0 for the 53 expressions in [`ICT_NAMES`] order, blendshape-major
    /// (`expression_deltas[i * V + v]`).
    pub expression_deltas: Vec<Vec3>,
    /// Identity principal components minus the neutral, component-major.
    pub identity_deltas: Vec<Vec3>,
    pub identity_count: usize,
    /// Texture coordinates, origin bottom-left (OBJ convention). The upstream layout uses
    /// UDIM-like tiles: the face skin lives in u in [0, 1], other parts in further tiles.
    pub uvs: Vec<Vec2>,
    /// Vertex indices per triangle (quads fan-split).
    pub triangles: Vec<[u32; 3]>,
    /// Indices into `uvs` for the same corners.
    pub triangle_uvs: Vec<[u32; 3]>,
    /// The upstream polygon each triangle came from.
    pub triangle_polygon: Vec<u32>,
    pub parts: Vec<Part>,
    pub materials: Vec<MaterialRun>,
    /// Vertex index of each of the 68 landmarks.
    pub landmarks_68: [u32; NUM_LANDMARKS],
    /// Where the template was read from, for messages.
    pub source: PathBuf,
}

#[derive(Deserialize)]
struct Metadata {
    expression_names: Vec<String>,
    #[serde(default)]
    identity_names: Vec<String>,
    parts: Vec<Part>,
    #[serde(default)]
    materials: Vec<MaterialRun>,
    landmarks_68: Vec<u32>,
}

/// Where to find the template: `cli` if given, else `$LIKENESS_FACEMODEL`, else
/// `../shared/facemodel/ict_face_model.safetensors` relative to the repository.
pub fn resolve_template_path(cli: Option<&Path>) -> PathBuf {
    if let Some(path) = cli {
        return path.to_path_buf();
    }
    if let Some(env) = std::env::var_os(FACEMODEL_ENV).filter(|v| !v.is_empty()) {
        return PathBuf::from(env);
    }
    default_template_path()
}

/// `../shared/facemodel/ict_face_model.safetensors` beside the repository this crate was
/// built from.
pub fn default_template_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("..")
        .join("..")
        .join("shared")
        .join("facemodel")
        .join(SAFETENSORS_FILE)
}

/// The real template for unit tests, which fail loudly (never skip) when it is missing.
#[cfg(test)]
pub(crate) fn test_template() -> Template {
    let path = default_template_path();
    match Template::load_safetensors(&path) {
        Ok(t) => t,
        Err(e) => panic!("these tests need the real template at {path:?}: {e}"),
    }
}

impl Template {
    /// A template of one quad (four vertices in the face's UV tile, 0.1..0.9), each
    /// blendshape a small offset of its own and no identity components: for tests and
    /// fuzzing of readers that need a model, not the ICT FaceKit's 26k vertices.
    pub fn one_quad(source: &str) -> Self {
        let corners = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]];
        Self {
            neutral: corners.iter().map(|&[x, y]| Vec3::new(x, y, 0.0)).collect(),
            expression_deltas: (0..NUM_BLENDSHAPES * 4)
                .map(|k| Vec3::new(0.0, 0.01 * ((k / 4 + k % 4) % 3) as f32, 0.0))
                .collect(),
            identity_deltas: Vec::new(),
            identity_count: 0,
            uvs: corners
                .iter()
                .map(|&[x, y]| Vec2::new(0.5 + 0.4 * x, 0.5 + 0.4 * y))
                .collect(),
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            triangle_uvs: vec![[0, 1, 2], [0, 2, 3]],
            triangle_polygon: vec![0, 0],
            parts: vec![Part {
                name: "face".into(),
                vertices: 0..4,
                polygons: 0..1,
            }],
            materials: Vec::new(),
            landmarks_68: [0; NUM_LANDMARKS],
            source: source.into(),
        }
    }

    /// Number of vertices V.
    pub fn vertex_count(&self) -> usize {
        self.neutral.len()
    }

    /// S_i - S_0 for blendshape `i` (0-based, [`ICT_NAMES`] order).
    pub fn expression_delta(&self, i: usize) -> &[Vec3] {
        let v = self.vertex_count();
        &self.expression_deltas[i * v..(i + 1) * v]
    }

    /// Identity component `k` minus the neutral.
    pub fn identity_delta(&self, k: usize) -> &[Vec3] {
        let v = self.vertex_count();
        &self.identity_deltas[k * v..(k + 1) * v]
    }

    /// The part named `name`, if the template has one.
    pub fn part(&self, name: &str) -> Option<&Part> {
        self.parts.iter().find(|p| p.name == name)
    }

    /// Vertices of the "face" part: the region the paper's template covers, and the domain
    /// of the UV corrections.
    pub fn face_vertices(&self) -> Range<u32> {
        self.part("face")
            .map(|p| p.vertices.clone())
            .unwrap_or(0..self.vertex_count() as u32)
    }

    /// Triangles of the face part (material `M_Face`, UV tile [0, 1]^2): the triangles that
    /// cover the correction UV space.
    pub fn face_triangles(&self) -> impl Iterator<Item = usize> + '_ {
        let face = self.face_vertices();
        (0..self.triangles.len()).filter(move |&t| {
            self.triangles[t].iter().all(|v| face.contains(v))
                && self.triangle_uvs[t]
                    .iter()
                    .all(|&k| (0.0..=1.0).contains(&self.uvs[k as usize].x))
        })
    }

    /// One UV per face-part vertex in tile [0, 1]^2 (`None` for other vertices).
    ///
    /// A vertex on a UV seam has several texture coordinates; it takes the one with the
    /// smallest `uv` index, so every sampling of a UV map at that vertex (the paper's F) gives
    /// one consistent value instead of a crack along the seam.
    pub fn face_vertex_uvs(&self) -> Vec<Option<Vec2>> {
        let mut best: Vec<Option<u32>> = vec![None; self.vertex_count()];
        for t in self.face_triangles() {
            for k in 0..3 {
                let v = self.triangles[t][k] as usize;
                let uv = self.triangle_uvs[t][k];
                best[v] = Some(best[v].map_or(uv, |b| b.min(uv)));
            }
        }
        best.into_iter()
            .map(|b| b.map(|k| self.uvs[k as usize]))
            .collect()
    }

    /// Material name of a triangle, from the upstream material runs.
    pub fn triangle_material(&self, triangle: usize) -> Option<&str> {
        let polygon = *self.triangle_polygon.get(triangle)?;
        self.materials
            .iter()
            .rev()
            .find(|m| m.first_polygon <= polygon)
            .map(|m| m.name.as_str())
    }

    /// Part name of a vertex.
    pub fn vertex_part(&self, vertex: u32) -> Option<&str> {
        self.parts
            .iter()
            .find(|p| p.vertices.contains(&vertex))
            .map(|p| p.name.as_str())
    }

    /// Loads the template from `path`: a safetensors file, a folder holding one, or an
    /// upstream ICT FaceKit folder (`FaceXModel/` or its parent).
    pub fn load(path: &Path) -> Result<Self> {
        if path.is_dir() {
            let converted = path.join(SAFETENSORS_FILE);
            if converted.is_file() {
                return Self::load_safetensors(&converted);
            }
            return crate::ict_import::import_ict_folder(path);
        }
        Self::load_safetensors(path)
    }

    /// Loads the template from the default location chain (see [`resolve_template_path`]).
    pub fn load_default(cli: Option<&Path>) -> Result<Self> {
        Self::load(&resolve_template_path(cli))
    }

    /// Reads the project's safetensors conversion.
    pub fn load_safetensors(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| {
            if source.kind() == std::io::ErrorKind::NotFound {
                FaceError::TemplateNotFound {
                    path: path.to_path_buf(),
                    reason: "no such file".into(),
                }
            } else {
                FaceError::Io {
                    path: path.to_path_buf(),
                    source,
                }
            }
        })?;
        Self::from_safetensors_bytes(&bytes, path)
    }

    /// Parses safetensors bytes; `path` is only used in messages.
    pub fn from_safetensors_bytes(bytes: &[u8], path: &Path) -> Result<Self> {
        let malformed = |reason: String| FaceError::MalformedTemplate {
            path: path.to_path_buf(),
            reason,
        };
        let (_, header) = SafeTensors::read_metadata(bytes)
            .map_err(|e| malformed(format!("not a safetensors file ({e})")))?;
        let tensors = SafeTensors::deserialize(bytes)
            .map_err(|e| malformed(format!("not a safetensors file ({e})")))?;
        let meta_json = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("ict_facekit"))
            .ok_or_else(|| malformed("header metadata has no `ict_facekit` entry".into()))?;
        let meta: Metadata = serde_json::from_str(meta_json)
            .map_err(|e| malformed(format!("`ict_facekit` metadata: {e}")))?;

        let f32_tensor = |name: &str, shape_tail: &[usize]| -> Result<(Vec<f32>, Vec<usize>)> {
            let view = tensors
                .tensor(name)
                .map_err(|_| malformed(format!("missing tensor `{name}`")))?;
            if view.dtype() != Dtype::F32 {
                return Err(malformed(format!(
                    "tensor `{name}` is {:?}, expected F32",
                    view.dtype()
                )));
            }
            let shape = view.shape().to_vec();
            if shape.len() < shape_tail.len() || !shape.ends_with(shape_tail) {
                return Err(malformed(format!(
                    "tensor `{name}` has shape {shape:?}, expected [.., {shape_tail:?}]"
                )));
            }
            let data = view
                .data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            Ok((data, shape))
        };
        let i32_tensor = |name: &str, shape_tail: &[usize]| -> Result<(Vec<i32>, Vec<usize>)> {
            let view = tensors
                .tensor(name)
                .map_err(|_| malformed(format!("missing tensor `{name}`")))?;
            if view.dtype() != Dtype::I32 {
                return Err(malformed(format!(
                    "tensor `{name}` is {:?}, expected I32",
                    view.dtype()
                )));
            }
            let shape = view.shape().to_vec();
            if shape.len() < shape_tail.len() || !shape.ends_with(shape_tail) {
                return Err(malformed(format!(
                    "tensor `{name}` has shape {shape:?}, expected [.., {shape_tail:?}]"
                )));
            }
            let data = view
                .data()
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect();
            Ok((data, shape))
        };

        let (neutral, _) = f32_tensor("neutral", &[3])?;
        let vertex_count = neutral.len() / 3;
        let (expr, expr_shape) = f32_tensor("expression_deltas", &[vertex_count, 3])?;
        if expr_shape.len() != 3 || expr_shape[0] != meta.expression_names.len() {
            return Err(malformed(format!(
                "expression_deltas has shape {expr_shape:?} but metadata names {} expressions",
                meta.expression_names.len()
            )));
        }
        let (identity, id_shape) = match f32_tensor("identity_deltas", &[vertex_count, 3]) {
            Ok(t) => t,
            Err(_) => (Vec::new(), vec![0, vertex_count, 3]),
        };
        let (uv, _) = f32_tensor("uv", &[2])?;
        let (tri, tri_shape) = i32_tensor("triangles", &[3])?;
        let (tri_uv, tri_uv_shape) = i32_tensor("triangle_uvs", &[3])?;
        if tri_shape != tri_uv_shape {
            return Err(malformed(format!(
                "triangles {tri_shape:?} and triangle_uvs {tri_uv_shape:?} differ in shape"
            )));
        }
        let triangle_polygon = match i32_tensor("triangle_polygon", &[]) {
            Ok((p, _)) => p.into_iter().map(|x| x.max(0) as u32).collect(),
            Err(_) => (0..tri_shape[0] as u32).collect(),
        };

        let raw = RawTemplate {
            neutral,
            expression_names: meta.expression_names,
            expression_deltas: expr,
            identity_deltas: identity,
            identity_count: id_shape[0],
            uvs: uv,
            triangles: tri,
            triangle_uvs: tri_uv,
            triangle_polygon,
            parts: meta.parts,
            materials: meta.materials,
            landmarks_68: meta.landmarks_68,
        };
        let _ = meta.identity_names;
        raw.validate(path)
    }
}

/// Unvalidated template arrays, as read from any source; [`RawTemplate::validate`] checks
/// every index and value and brings the expressions into [`ICT_NAMES`] order.
pub(crate) struct RawTemplate {
    pub neutral: Vec<f32>,
    pub expression_names: Vec<String>,
    pub expression_deltas: Vec<f32>,
    pub identity_deltas: Vec<f32>,
    pub identity_count: usize,
    pub uvs: Vec<f32>,
    pub triangles: Vec<i32>,
    pub triangle_uvs: Vec<i32>,
    pub triangle_polygon: Vec<u32>,
    pub parts: Vec<Part>,
    pub materials: Vec<MaterialRun>,
    pub landmarks_68: Vec<u32>,
}

fn to_vec3(flat: &[f32]) -> Vec<Vec3> {
    flat.chunks_exact(3).map(Vec3::from_slice).collect()
}

impl RawTemplate {
    pub(crate) fn validate(self, path: &Path) -> Result<Template> {
        let malformed = |reason: String| FaceError::MalformedTemplate {
            path: path.to_path_buf(),
            reason,
        };
        let v = self.neutral.len() / 3;
        if v == 0 || !self.neutral.len().is_multiple_of(3) {
            return Err(malformed("the neutral mesh has no vertices".into()));
        }
        if let Some(bad) = self.neutral.iter().position(|x| !x.is_finite()) {
            return Err(malformed(format!(
                "neutral vertex {} is not finite",
                bad / 3
            )));
        }
        // Expressions by name, so a source with another order or extra shapes still works.
        let by_name: HashMap<&str, usize> = self
            .expression_names
            .iter()
            .enumerate()
            .map(|(i, n)| (n.as_str(), i))
            .collect();
        if self.expression_deltas.len() != self.expression_names.len() * v * 3 {
            return Err(malformed(format!(
                "expression deltas hold {} values, expected {} expressions x {v} vertices x 3",
                self.expression_deltas.len(),
                self.expression_names.len()
            )));
        }
        let mut expression_deltas = Vec::with_capacity(NUM_BLENDSHAPES * v);
        for name in ICT_NAMES {
            let &src = by_name.get(name).ok_or_else(|| {
                malformed(format!(
                    "expression `{name}` (one of the 53 ICT blendshapes) is missing"
                ))
            })?;
            let block = &self.expression_deltas[src * v * 3..(src + 1) * v * 3];
            if block.iter().any(|x| !x.is_finite()) {
                return Err(malformed(format!(
                    "expression `{name}` has non-finite values"
                )));
            }
            expression_deltas.extend(to_vec3(block));
        }
        if self.identity_deltas.len() != self.identity_count * v * 3 {
            return Err(malformed(
                "identity deltas do not match the vertex count".into(),
            ));
        }
        let uvs: Vec<Vec2> = self.uvs.chunks_exact(2).map(Vec2::from_slice).collect();
        if uvs.iter().any(|u| !u.is_finite()) {
            return Err(malformed("texture coordinates are not finite".into()));
        }
        let check_indices = |what: &str, flat: &[i32], bound: usize| -> Result<Vec<[u32; 3]>> {
            if !flat.len().is_multiple_of(3) || flat.is_empty() {
                return Err(malformed(format!("{what} is empty or not a multiple of 3")));
            }
            flat.chunks_exact(3)
                .enumerate()
                .map(|(t, c)| {
                    let mut out = [0u32; 3];
                    for k in 0..3 {
                        if c[k] < 0 || c[k] as usize >= bound {
                            return Err(malformed(format!(
                                "{what}: triangle {t} refers to index {} of {bound}",
                                c[k]
                            )));
                        }
                        out[k] = c[k] as u32;
                    }
                    Ok(out)
                })
                .collect()
        };
        let triangles = check_indices("triangles", &self.triangles, v)?;
        let triangle_uvs = check_indices("triangle_uvs", &self.triangle_uvs, uvs.len())?;
        if self.triangle_polygon.len() != triangles.len() {
            return Err(malformed(
                "triangle_polygon length differs from triangles".into(),
            ));
        }
        if self.landmarks_68.len() != NUM_LANDMARKS {
            return Err(malformed(format!(
                "landmarks_68 has {} entries, expected 68",
                self.landmarks_68.len()
            )));
        }
        let mut landmarks_68 = [0u32; NUM_LANDMARKS];
        for (k, &l) in self.landmarks_68.iter().enumerate() {
            if l as usize >= v {
                return Err(malformed(format!(
                    "landmark {k} refers to vertex {l} of {v}"
                )));
            }
            landmarks_68[k] = l;
        }
        for p in &self.parts {
            if p.vertices.end as usize > v || p.vertices.start > p.vertices.end {
                return Err(malformed(format!(
                    "part `{}` has vertex range {:?}",
                    p.name, p.vertices
                )));
            }
        }
        Ok(Template {
            neutral: to_vec3(&self.neutral),
            expression_deltas,
            identity_deltas: to_vec3(&self.identity_deltas),
            identity_count: self.identity_count,
            uvs,
            triangles,
            triangle_uvs,
            triangle_polygon: self.triangle_polygon,
            parts: self.parts,
            materials: self.materials,
            landmarks_68,
            source: path.to_path_buf(),
        })
    }
}
