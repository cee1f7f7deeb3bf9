//! Loading puppets: `.gltf` (external or data-URI buffers), `.glb` and `.vrm` (0.x, 1.0)
//! through the `gltf` crate, checked so that no malformed file can panic the reader.
//!
//! What is read: the node tree with rest transforms, meshes with all their triangle
//! primitives (positions, normals, UVs, indices, joints and weights for skins, material),
//! morph targets (position and normal deltas) named by `mesh.extras.targetNames`, else by
//! the accessor names of the first primitive's targets, else `target<k>`; skins; base
//! colour factors and textures; the VRM extension (expressions, humanoid head).
//!
//! The `gltf` crate reads accessors by slicing buffers without checking every range, so
//! every accessor (including sparse ones) is checked against its buffer view and buffer
//! before any is read, and positions are checked for NaN.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};
use serde_json::Value;

use crate::error::{Result, RetargetError, io_error};
use crate::vrm::{VrmInfo, read_vrm};

/// Required extensions the loader honours (others are refused by name, as the glTF
/// specification asks).
pub const SUPPORTED_REQUIRED_EXTENSIONS: &[&str] = &["KHR_materials_unlit"];

/// More morph targets than this on one mesh is refused: GPU blending uploads one weight per
/// target per frame and the largest real rigs (ARKit + visemes + VRM clips) have ~150.
pub const MAX_MORPH_TARGETS: usize = 1024;

/// Files larger than this are refused before reading (a puppet, not a scene).
pub const MAX_FILE_BYTES: u64 = 1 << 30;

#[derive(Clone, Debug, PartialEq)]
pub struct MorphTarget {
    pub positions: Vec<[f32; 3]>,
    /// Empty when the target has no normal deltas.
    pub normals: Vec<[f32; 3]>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Primitive {
    pub positions: Vec<[f32; 3]>,
    /// Empty when the file has none (the renderer computes flat-shaded ones).
    pub normals: Vec<[f32; 3]>,
    pub uvs: Vec<[f32; 2]>,
    pub indices: Vec<u32>,
    pub joints: Vec<[u16; 4]>,
    pub weights: Vec<[f32; 4]>,
    pub material: Option<usize>,
    /// One per morph target of the mesh, in the mesh's target order.
    pub targets: Vec<MorphTarget>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Mesh {
    pub name: String,
    pub target_names: Vec<String>,
    /// `mesh.weights`: the default morph weights (0 when absent).
    pub default_weights: Vec<f32>,
    pub primitives: Vec<Primitive>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Node {
    pub name: String,
    pub parent: Option<usize>,
    pub children: Vec<usize>,
    pub mesh: Option<usize>,
    pub skin: Option<usize>,
    pub translation: Vec3,
    pub rotation: Quat,
    pub scale: Vec3,
}

impl Node {
    pub fn local_matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Skin {
    pub joints: Vec<usize>,
    pub inverse_bind_matrices: Vec<Mat4>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Material {
    pub name: String,
    pub base_color_factor: [f32; 4],
    /// Index into [`Puppet::images`].
    pub base_color_image: Option<usize>,
    /// glTF `doubleSided`: back faces are drawn too. When false (the default) a viewer
    /// culls them.
    pub double_sided: bool,
}

/// A decoded image, RGBA8.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbaImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

#[derive(Clone, Debug, PartialEq)]
pub struct Puppet {
    pub path: PathBuf,
    pub meshes: Vec<Mesh>,
    pub nodes: Vec<Node>,
    pub skins: Vec<Skin>,
    pub materials: Vec<Material>,
    pub images: Vec<RgbaImage>,
    /// Root nodes of the default scene (all parentless nodes without one).
    pub roots: Vec<usize>,
    pub vrm: Option<VrmInfo>,
    pub extensions_used: Vec<String>,
}

/// The raw parts of a glTF file: its JSON and its binary chunk (GLB) or none.
pub struct RawGltf<'a> {
    pub json: Value,
    pub json_bytes: Cow<'a, [u8]>,
    pub bin: Option<Cow<'a, [u8]>>,
}

/// Splits a file into its JSON and binary chunk with clear errors for the usual breakage
/// (empty, wrong magic, truncated, a JSON chunk that is not JSON).
pub fn split_gltf<'a>(bytes: &'a [u8], path: &Path) -> Result<RawGltf<'a>> {
    let bad = |reason: String| RetargetError::InvalidPuppet {
        path: path.to_owned(),
        reason,
    };
    if bytes.is_empty() {
        return Err(bad("the file is empty (0 bytes)".into()));
    }
    let (json_bytes, bin) = if bytes.starts_with(b"glTF") {
        let glb =
            gltf::Glb::from_slice(bytes).map_err(|e| bad(format!("broken GLB container: {e}")))?;
        (glb.json, glb.bin)
    } else if bytes.iter().find(|b| !b.is_ascii_whitespace()) == Some(&b'{') {
        (Cow::Borrowed(bytes), None)
    } else {
        let magic: String = bytes
            .iter()
            .take(4)
            .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
            .collect();
        return Err(bad(format!(
            "not a glTF file: a GLB starts with the magic `glTF` and a .gltf with `{{`, this starts with `{magic}`"
        )));
    };
    let json: Value = serde_json::from_slice(&json_bytes)
        .map_err(|e| bad(format!("the JSON chunk is not JSON: {e}")))?;
    if !json.is_object() {
        return Err(bad("the JSON chunk is not a JSON object".into()));
    }
    Ok(RawGltf {
        json,
        json_bytes,
        bin,
    })
}

/// Required extensions this loader does not honour, by name.
pub fn unsupported_required_extensions(json: &Value) -> Vec<String> {
    json.get("extensionsRequired")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .filter(|name| !SUPPORTED_REQUIRED_EXTENSIONS.contains(name))
        .map(str::to_owned)
        .collect()
}

impl Puppet {
    /// Loads a `.gltf`, `.glb` or `.vrm` file (the format is taken from the content, not the
    /// extension). External buffers and images are resolved beside the file.
    pub fn load(path: &Path) -> Result<Self> {
        let size = std::fs::metadata(path).map_err(io_error(path))?.len();
        if size > MAX_FILE_BYTES {
            return Err(RetargetError::InvalidPuppet {
                path: path.to_owned(),
                reason: format!("{size} bytes is more than the {MAX_FILE_BYTES} a puppet may have"),
            });
        }
        let bytes = std::fs::read(path).map_err(io_error(path))?;
        Self::from_slice(&bytes, path, path.parent())
    }

    /// Loads from bytes; `base` is where relative URIs point (none: only embedded data).
    pub fn from_slice(bytes: &[u8], path: &Path, base: Option<&Path>) -> Result<Self> {
        let bad = |reason: String| RetargetError::InvalidPuppet {
            path: path.to_owned(),
            reason,
        };
        let raw = split_gltf(bytes, path)?;
        let unsupported = unsupported_required_extensions(&raw.json);
        if !unsupported.is_empty() {
            return Err(RetargetError::UnsupportedExtension {
                path: path.to_owned(),
                extensions: unsupported,
            });
        }
        let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| bad(format!("invalid glTF: {e}")))?;
        let document = gltf.document;
        let buffers = import_buffers(&document, base, gltf.blob, path)?;
        check_accessors(&document, &buffers).map_err(bad)?;

        let node_mesh: Vec<Option<usize>> = document
            .nodes()
            .map(|n| n.mesh().map(|m| m.index()))
            .collect();
        let vrm = read_vrm(raw.json.get("extensions"), &node_mesh);

        let mut meshes = Vec::new();
        for mesh in document.meshes() {
            meshes.push(read_mesh(&mesh, &buffers).map_err(bad)?);
        }
        let nodes = read_nodes(&document);
        if let Some(cycle) = find_cycle(&nodes) {
            return Err(bad(format!(
                "node {cycle} is its own ancestor (the node tree has a cycle)"
            )));
        }
        let mut skins = Vec::new();
        for skin in document.skins() {
            let reader = skin.reader(|b| buffers.get(b.index()).map(|d| &d[..]));
            let inverse_bind_matrices: Vec<Mat4> = match reader.read_inverse_bind_matrices() {
                Some(m) => m.map(|c| Mat4::from_cols_array_2d(&c)).collect(),
                None => vec![Mat4::IDENTITY; skin.joints().count()],
            };
            skins.push(Skin {
                joints: skin.joints().map(|j| j.index()).collect(),
                inverse_bind_matrices,
            });
        }
        let images = import_images(&document, base, &buffers, path);
        let materials = document
            .materials()
            .map(|m| {
                let pbr = m.pbr_metallic_roughness();
                Material {
                    name: m.name().unwrap_or_default().to_owned(),
                    base_color_factor: pbr.base_color_factor(),
                    base_color_image: pbr
                        .base_color_texture()
                        .map(|t| t.texture().source().index())
                        .filter(|&i| i < images.len()),
                    double_sided: m.double_sided(),
                }
            })
            .collect();
        let roots = match document
            .default_scene()
            .or_else(|| document.scenes().next())
        {
            Some(scene) => scene.nodes().map(|n| n.index()).collect(),
            None => (0..nodes.len())
                .filter(|&i| nodes[i].parent.is_none())
                .collect(),
        };
        let puppet = Puppet {
            path: path.to_owned(),
            meshes,
            nodes,
            skins,
            materials,
            images,
            roots,
            vrm,
            extensions_used: document.extensions_used().map(str::to_owned).collect(),
        };
        puppet.check_vrm_binds().map_err(bad)?;
        Ok(puppet)
    }

    fn check_vrm_binds(&self) -> std::result::Result<(), String> {
        let Some(vrm) = &self.vrm else { return Ok(()) };
        for e in &vrm.expressions {
            for b in &e.binds {
                let Some(mesh) = self.meshes.get(b.mesh) else {
                    return Err(format!(
                        "VRM expression `{}` binds mesh {}, which does not exist",
                        e.name, b.mesh
                    ));
                };
                if b.target >= mesh.target_names.len() {
                    return Err(format!(
                        "VRM expression `{}` binds morph target {} of mesh `{}`, which has {}",
                        e.name,
                        b.target,
                        mesh.name,
                        mesh.target_names.len()
                    ));
                }
            }
        }
        for (what, node) in [("head", vrm.head_node), ("neck", vrm.neck_node)] {
            if let Some(n) = node.filter(|&n| n >= self.nodes.len()) {
                return Err(format!(
                    "the VRM humanoid {what} bone is node {n}, which does not exist"
                ));
            }
        }
        Ok(())
    }

    /// World matrices of every node at rest (or with `local_override` replacing some nodes'
    /// local rotation, for head pose).
    pub fn world_matrices(&self, rotation_override: &[(usize, Quat)]) -> Vec<Mat4> {
        let mut world = vec![Mat4::IDENTITY; self.nodes.len()];
        let mut stack: Vec<(usize, Mat4)> =
            self.roots.iter().map(|&r| (r, Mat4::IDENTITY)).collect();
        let mut visited = vec![false; self.nodes.len()];
        while let Some((i, parent)) = stack.pop() {
            if i >= self.nodes.len() || std::mem::replace(&mut visited[i], true) {
                continue;
            }
            let node = &self.nodes[i];
            let rotation = rotation_override
                .iter()
                .find(|(n, _)| *n == i)
                .map_or(node.rotation, |(_, q)| *q);
            world[i] = parent
                * Mat4::from_scale_rotation_translation(node.scale, rotation, node.translation);
            stack.extend(node.children.iter().map(|&c| (c, world[i])));
        }
        world
    }

    /// Every (mesh, target) pair with its name, in document order.
    pub fn morph_targets(&self) -> impl Iterator<Item = (usize, usize, &str)> {
        self.meshes.iter().enumerate().flat_map(|(m, mesh)| {
            mesh.target_names
                .iter()
                .enumerate()
                .map(move |(t, n)| (m, t, n.as_str()))
        })
    }

    pub fn morph_target_count(&self) -> usize {
        self.meshes.iter().map(|m| m.target_names.len()).sum()
    }

    /// The node head rotation drives: `preferred` by name, else the VRM humanoid head, else a
    /// node named `head` (after an exporter prefix), else one ending in `head`, else the same
    /// for `neck`.
    pub fn head_node(&self, preferred: Option<&str>) -> Option<usize> {
        if let Some(name) = preferred {
            return self.nodes.iter().position(|n| n.name == name).or_else(|| {
                self.nodes
                    .iter()
                    .position(|n| n.name.eq_ignore_ascii_case(name))
            });
        }
        if let Some(vrm) = &self.vrm
            && let Some(h) = vrm.head_node.or(vrm.neck_node)
        {
            return Some(h);
        }
        let base = |n: &Node| {
            n.name
                .rsplit([':', '|', '.'])
                .next()
                .unwrap_or_default()
                .to_ascii_lowercase()
        };
        for word in ["head", "neck"] {
            if let Some(i) = self.nodes.iter().position(|n| base(n) == word) {
                return Some(i);
            }
            // `J_Bip_C_Head`, `mixamorig_Head`, but not `HeadTop_End` or `head_end`.
            if let Some(i) = self.nodes.iter().position(|n| {
                let b = base(n);
                b.ends_with(word) && !b.contains("end") && !b.contains("top")
            }) {
                return Some(i);
            }
        }
        None
    }
}

fn import_buffers(
    document: &gltf::Document,
    base: Option<&Path>,
    blob: Option<Vec<u8>>,
    path: &Path,
) -> Result<Vec<gltf::buffer::Data>> {
    let bad = |reason: String| RetargetError::InvalidPuppet {
        path: path.to_owned(),
        reason,
    };
    for buffer in document.buffers() {
        if let gltf::buffer::Source::Uri(uri) = buffer.source()
            && !uri.starts_with("data:")
            && base.is_none()
        {
            return Err(bad(format!(
                "buffer {} refers to the external file `{uri}`, but the puppet was not loaded from a folder",
                buffer.index()
            )));
        }
    }
    let buffers = gltf::import_buffers(document, base, blob)
        .map_err(|e| bad(format!("cannot read its buffers: {e}")))?;
    for (buffer, data) in document.buffers().zip(&buffers) {
        if data.len() < buffer.length() {
            return Err(bad(format!(
                "buffer {} declares {} bytes but holds {}",
                buffer.index(),
                buffer.length(),
                data.len()
            )));
        }
    }
    Ok(buffers)
}

/// Decodes the images; one that cannot be decoded is replaced by white (with a warning), as
/// a missing texture should not make the puppet unusable.
fn import_images(
    document: &gltf::Document,
    base: Option<&Path>,
    buffers: &[gltf::buffer::Data],
    path: &Path,
) -> Vec<RgbaImage> {
    document
        .images()
        .map(|image| {
            let decoded = gltf::image::Data::from_source(image.source(), base, buffers);
            match decoded {
                Ok(data) => to_rgba(&data).unwrap_or_else(|| {
                    tracing::warn!(
                        "{}: image {} has an unsupported pixel format; drawn white",
                        path.display(),
                        image.index()
                    );
                    white()
                }),
                Err(e) => {
                    tracing::warn!(
                        "{}: image {} cannot be read ({e}); drawn white",
                        path.display(),
                        image.index()
                    );
                    white()
                }
            }
        })
        .collect()
}

fn white() -> RgbaImage {
    RgbaImage {
        width: 1,
        height: 1,
        pixels: vec![255; 4],
    }
}

fn to_rgba(data: &gltf::image::Data) -> Option<RgbaImage> {
    use gltf::image::Format;
    let p = &data.pixels;
    let pixels: Vec<u8> = match data.format {
        Format::R8G8B8A8 => p.clone(),
        Format::R8G8B8 => p
            .chunks_exact(3)
            .flat_map(|c| [c[0], c[1], c[2], 255])
            .collect(),
        Format::R8G8 => p
            .chunks_exact(2)
            .flat_map(|c| [c[0], c[0], c[0], c[1]])
            .collect(),
        Format::R8 => p.iter().flat_map(|&v| [v, v, v, 255]).collect(),
        Format::R16G16B16A16 => p.chunks_exact(2).map(|c| c[1]).collect(),
        Format::R16G16B16 => p
            .chunks_exact(6)
            .flat_map(|c| [c[1], c[3], c[5], 255])
            .collect(),
        _ => return None,
    };
    (pixels.len() == data.width as usize * data.height as usize * 4).then_some(RgbaImage {
        width: data.width,
        height: data.height,
        pixels,
    })
}

/// Every accessor's bytes lie inside its buffer view, and every view inside its buffer.
fn check_accessors(
    document: &gltf::Document,
    buffers: &[gltf::buffer::Data],
) -> std::result::Result<(), String> {
    let view_range = |view: &gltf::buffer::View| -> std::result::Result<(), String> {
        let data = buffers
            .get(view.buffer().index())
            .ok_or_else(|| format!("buffer view {} refers to a missing buffer", view.index()))?;
        let end = view
            .offset()
            .checked_add(view.length())
            .ok_or("buffer view range overflows")?;
        if end > data.len() {
            return Err(format!(
                "buffer view {} (bytes {}..{end}) runs past the end of buffer {} ({} bytes)",
                view.index(),
                view.offset(),
                view.buffer().index(),
                data.len()
            ));
        }
        Ok(())
    };
    for view in document.views() {
        view_range(&view)?;
    }
    for accessor in document.accessors() {
        let element = accessor.size();
        let count = accessor.count();
        if let Some(view) = accessor.view() {
            let stride = view.stride().unwrap_or(element);
            if stride < element {
                return Err(format!(
                    "accessor {}: stride {stride} is smaller than its element ({element} bytes)",
                    accessor.index()
                ));
            }
            if count > 0 {
                let needed = (count - 1)
                    .checked_mul(stride)
                    .and_then(|v| v.checked_add(element))
                    .and_then(|v| v.checked_add(accessor.offset()))
                    .ok_or_else(|| format!("accessor {}: size overflows", accessor.index()))?;
                if needed > view.length() {
                    return Err(format!(
                        "accessor {} needs {needed} bytes of buffer view {}, which has {}",
                        accessor.index(),
                        view.index(),
                        view.length()
                    ));
                }
            }
        }
        if let Some(sparse) = accessor.sparse() {
            let n = sparse.count();
            if n > count {
                return Err(format!(
                    "accessor {}: {n} sparse values for {count} elements",
                    accessor.index()
                ));
            }
            let indices = sparse.indices();
            let index_size = match indices.index_type() {
                gltf::accessor::sparse::IndexType::U8 => 1,
                gltf::accessor::sparse::IndexType::U16 => 2,
                gltf::accessor::sparse::IndexType::U32 => 4,
            };
            for (what, view, offset, size) in [
                ("indices", indices.view(), indices.offset(), index_size),
                (
                    "values",
                    sparse.values().view(),
                    sparse.values().offset(),
                    element,
                ),
            ] {
                let needed = n
                    .checked_mul(size)
                    .and_then(|v| v.checked_add(offset))
                    .ok_or_else(|| {
                        format!("accessor {}: sparse size overflows", accessor.index())
                    })?;
                if needed > view.length() {
                    return Err(format!(
                        "accessor {}: sparse {what} need {needed} bytes of buffer view {}, which has {}",
                        accessor.index(),
                        view.index(),
                        view.length()
                    ));
                }
            }
            // Sparse indices must address elements of the accessor.
            let data = &buffers[indices.view().buffer().index()];
            let start = indices.view().offset() + indices.offset();
            for k in 0..n {
                let at = start + k * index_size;
                let b = &data[at..at + index_size];
                let i = match index_size {
                    1 => b[0] as usize,
                    2 => u16::from_le_bytes([b[0], b[1]]) as usize,
                    _ => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize,
                };
                if i >= count {
                    return Err(format!(
                        "accessor {}: sparse index {i} is past its {count} elements",
                        accessor.index()
                    ));
                }
            }
        }
    }
    Ok(())
}

fn expect_vec3_f32(accessor: &gltf::Accessor, what: &str) -> std::result::Result<(), String> {
    if accessor.data_type() != gltf::accessor::DataType::F32
        || accessor.dimensions() != gltf::accessor::Dimensions::Vec3
    {
        return Err(format!(
            "{what} (accessor {}) is {:?} {:?}; float VEC3 is required",
            accessor.index(),
            accessor.data_type(),
            accessor.dimensions()
        ));
    }
    Ok(())
}

fn read_mesh(
    mesh: &gltf::Mesh,
    buffers: &[gltf::buffer::Data],
) -> std::result::Result<Mesh, String> {
    let name = mesh
        .name()
        .map_or_else(|| format!("mesh{}", mesh.index()), str::to_owned);
    let target_count = mesh
        .primitives()
        .map(|p| p.morph_targets().count())
        .max()
        .unwrap_or(0);
    if target_count > MAX_MORPH_TARGETS {
        return Err(format!(
            "mesh `{name}` has {target_count} morph targets; at most {MAX_MORPH_TARGETS} are supported"
        ));
    }
    let mut primitives = Vec::new();
    for primitive in mesh.primitives() {
        let at = format!("mesh `{name}` primitive {}", primitive.index());
        if primitive.mode() != gltf::mesh::Mode::Triangles {
            tracing::warn!("{at}: {:?} primitives are not drawn", primitive.mode());
            continue;
        }
        if primitive.morph_targets().count() != target_count {
            return Err(format!(
                "{at} has {} morph targets, another primitive of the mesh {target_count}",
                primitive.morph_targets().count()
            ));
        }
        let position_accessor = primitive
            .get(&gltf::Semantic::Positions)
            .ok_or_else(|| format!("{at} has no POSITION"))?;
        expect_vec3_f32(&position_accessor, &format!("{at} POSITION"))?;
        let vertex_count = position_accessor.count();
        for (semantic, what) in [(gltf::Semantic::Normals, "NORMAL")] {
            if let Some(a) = primitive.get(&semantic) {
                expect_vec3_f32(&a, &format!("{at} {what}"))?;
                if a.count() != vertex_count {
                    return Err(format!(
                        "{at}: {what} has {} elements for {vertex_count} positions",
                        a.count()
                    ));
                }
            }
        }
        for (k, target) in primitive.morph_targets().enumerate() {
            for (accessor, what) in [
                (target.positions(), "POSITION"),
                (target.normals(), "NORMAL"),
            ] {
                if let Some(a) = accessor {
                    expect_vec3_f32(&a, &format!("{at} morph target {k} {what}"))?;
                    if a.count() != vertex_count {
                        return Err(format!(
                            "{at}: morph target {k} {what} has {} elements for {vertex_count} vertices",
                            a.count()
                        ));
                    }
                }
            }
        }
        let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d[..]));
        let positions: Vec<[f32; 3]> = reader
            .read_positions()
            .ok_or_else(|| format!("{at}: POSITION cannot be read"))?
            .collect();
        if let Some(k) = positions
            .iter()
            .position(|p| p.iter().any(|v| !v.is_finite()))
        {
            return Err(format!(
                "{at}: position {k} is not finite ({:?})",
                positions[k]
            ));
        }
        let normals: Vec<[f32; 3]> = reader
            .read_normals()
            .map(|n| n.collect())
            .unwrap_or_default();
        let uvs: Vec<[f32; 2]> = reader
            .read_tex_coords(0)
            .map(|t| t.into_f32().collect())
            .unwrap_or_default();
        let indices: Vec<u32> = match reader.read_indices() {
            Some(i) => i.into_u32().collect(),
            None => (0..vertex_count as u32).collect(),
        };
        if let Some(&i) = indices.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(format!(
                "{at}: index {i} is past its {vertex_count} vertices"
            ));
        }
        let joints: Vec<[u16; 4]> = reader
            .read_joints(0)
            .map(|j| j.into_u16().collect())
            .unwrap_or_default();
        let weights: Vec<[f32; 4]> = reader
            .read_weights(0)
            .map(|w| w.into_f32().collect())
            .unwrap_or_default();
        let mut targets = Vec::with_capacity(target_count);
        for (k, (p, n, _)) in reader.read_morph_targets().enumerate() {
            let positions: Vec<[f32; 3]> = p
                .map(|p| p.collect())
                .unwrap_or_else(|| vec![[0.0; 3]; vertex_count]);
            if let Some(v) = positions
                .iter()
                .position(|p| p.iter().any(|v| !v.is_finite()))
            {
                return Err(format!(
                    "{at}: morph target {k} moves vertex {v} by a non-finite amount"
                ));
            }
            let normals: Vec<[f32; 3]> = n.map(|n| n.collect()).unwrap_or_default();
            targets.push(MorphTarget { positions, normals });
        }
        primitives.push(Primitive {
            positions,
            normals,
            uvs,
            indices: indices[..indices.len() / 3 * 3].to_vec(),
            joints,
            weights,
            material: primitive.material().index(),
            targets,
        });
    }
    let target_names = target_names(mesh, target_count);
    let mut default_weights = mesh.weights().map(<[f32]>::to_vec).unwrap_or_default();
    default_weights.resize(target_count, 0.0);
    Ok(Mesh {
        name,
        target_names,
        default_weights,
        primitives,
    })
}

/// `mesh.extras.targetNames` when it has one name per target, else the accessor names of
/// the first primitive's targets, else `target<k>`.
fn target_names(mesh: &gltf::Mesh, count: usize) -> Vec<String> {
    if let Some(extras) = mesh.extras()
        && let Ok(value) = serde_json::from_str::<Value>(extras.get())
        && let Some(names) = value.get("targetNames").and_then(Value::as_array)
    {
        let names: Vec<String> = names
            .iter()
            .filter_map(Value::as_str)
            .map(str::to_owned)
            .collect();
        if names.len() == count {
            return names;
        }
        tracing::warn!(
            "mesh {:?}: extras.targetNames has {} names for {count} targets; ignored",
            mesh.name(),
            names.len()
        );
    }
    let from_accessors: Vec<Option<String>> = mesh
        .primitives()
        .next()
        .map(|p| {
            p.morph_targets()
                .map(|t| t.positions().and_then(|a| a.name().map(str::to_owned)))
                .collect()
        })
        .unwrap_or_default();
    (0..count)
        .map(|k| {
            from_accessors
                .get(k)
                .cloned()
                .flatten()
                .unwrap_or_else(|| format!("target{k}"))
        })
        .collect()
}

fn read_nodes(document: &gltf::Document) -> Vec<Node> {
    let mut nodes: Vec<Node> = document
        .nodes()
        .map(|n| {
            let (t, r, s) = n.transform().decomposed();
            Node {
                name: n
                    .name()
                    .map_or_else(|| format!("node{}", n.index()), str::to_owned),
                parent: None,
                children: n.children().map(|c| c.index()).collect(),
                mesh: n.mesh().map(|m| m.index()),
                skin: n.skin().map(|s| s.index()),
                translation: Vec3::from(t),
                rotation: Quat::from_array(r).normalize(),
                scale: Vec3::from(s),
            }
        })
        .collect();
    for i in 0..nodes.len() {
        for c in nodes[i].children.clone() {
            if let Some(child) = nodes.get_mut(c) {
                child.parent = Some(i);
            }
        }
    }
    nodes
}

fn find_cycle(nodes: &[Node]) -> Option<usize> {
    (0..nodes.len()).find(|&start| {
        let mut at = nodes[start].parent;
        let mut steps = 0;
        while let Some(p) = at {
            if p == start || steps > nodes.len() {
                return true;
            }
            at = nodes[p].parent;
            steps += 1;
        }
        false
    })
}
