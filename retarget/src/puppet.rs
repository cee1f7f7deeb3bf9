//! Loading puppets: `.gltf` (external or data-URI buffers), `.glb` and `.vrm` (0.x, 1.0)
//! through the `gltf` crate, checked so that no malformed file can panic the reader.
//!
//! What is read: the node tree with rest transforms, meshes with all their triangle
//! primitives (positions, normals, UVs, indices, joints and weights for skins, material),
//! morph targets (position and normal deltas) named by `mesh.extras.targetNames`, else by
//! the accessor names of the first primitive's targets, else `target<k>`; skins; base
//! colour factors and textures; the VRM extension (expressions, humanoid head).
//!
//! The `gltf` crate parses and validates the JSON; everything it would assume beyond that
//! is checked here first: the accessors a primitive names exist (its validation indexes
//! them unchecked), accessor data is read by [`crate::accessor`] (type, count and every
//! byte range checked; the crate's reader panics on unexpected component types), buffers
//! and images are read by [`crate::uri`] (only inside the puppet's folder, bounded), and
//! images are decoded with bounded dimensions. Positions and transforms must be finite;
//! the node tree must be a forest.

use std::borrow::Cow;
use std::path::{Path, PathBuf};

use glam::{Mat4, Quat, Vec3};
use gltf::accessor::{DataType, Dimensions};
use serde_json::Value;

use crate::accessor::{self, Budget};
use crate::error::{Result, RetargetError, io_error};
use crate::uri::{self, MAX_IMAGE_BYTES, PuppetFolder};
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
        // The `gltf` crate subtracts the header's size from the declared length unchecked.
        let declared = bytes
            .get(8..12)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .ok_or_else(|| bad("broken GLB container: the 12-byte header is cut".into()))?;
        if declared < 20 {
            return Err(bad(format!(
                "broken GLB container: the header declares {declared} bytes, less than a header and a chunk header"
            )));
        }
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

/// The files beside the puppet at `path` that it names (external buffers and images), each
/// with what names it (`buffer 0 (mesh.bin)`): a command writing beside a puppet must not
/// overwrite them, and comparing with the puppet file alone would miss a `.gltf`'s `.bin`.
/// URIs the loader would refuse (a scheme, an absolute path, `..`) name nothing here, and a
/// file that cannot be read or split names none: loading it reports why.
pub fn external_files(path: &Path) -> Vec<(String, PathBuf)> {
    let readable = std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() <= MAX_FILE_BYTES);
    let Some(bytes) = readable.then(|| std::fs::read(path).ok()).flatten() else {
        return Vec::new();
    };
    let Ok(raw) = split_gltf(&bytes, path) else {
        return Vec::new();
    };
    let folder = path.parent().unwrap_or(Path::new(""));
    let mut files = Vec::new();
    for kind in ["buffers", "images"] {
        let entries = raw.json.get(kind).and_then(Value::as_array);
        for (index, entry) in entries.into_iter().flatten().enumerate() {
            let Some(uri) = entry.get("uri").and_then(Value::as_str) else {
                continue;
            };
            if uri.starts_with("data:") {
                continue;
            }
            if let Ok(relative) = uri::relative_path(uri) {
                let what = format!("{} {index} ({uri})", kind.trim_end_matches('s'));
                files.push((what, folder.join(relative)));
            }
        }
    }
    files
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
    /// extension). External buffers and images are read only from inside the file's folder
    /// (see [`crate::uri`]).
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

    /// Loads from bytes; `base` is the folder relative URIs point into (none: only embedded
    /// data).
    ///
    /// Never panics: what the `gltf` crate assumes is checked before it is asked. As a last
    /// resort (a case the checks miss), a panic inside the reader is caught here and
    /// returned as an error, so a file can never end the studio; the fuzz targets make such
    /// panics fatal, so that each one found gets a check of its own.
    pub fn from_slice(bytes: &[u8], path: &Path, base: Option<&Path>) -> Result<Self> {
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            Self::from_slice_checked(bytes, path, base)
        })) {
            Ok(result) => result,
            Err(panic) => {
                let message = panic
                    .downcast_ref::<&str>()
                    .map(|s| (*s).to_owned())
                    .or_else(|| panic.downcast_ref::<String>().cloned())
                    .unwrap_or_default();
                tracing::error!("{}: the glTF reader panicked: {message}", path.display());
                Err(RetargetError::InvalidPuppet {
                    path: path.to_owned(),
                    reason: format!(
                        "malformed glTF that the reader could not handle ({message}); please report this file"
                    ),
                })
            }
        }
    }

    fn from_slice_checked(bytes: &[u8], path: &Path, base: Option<&Path>) -> Result<Self> {
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
        check_json(&raw.json).map_err(bad)?;
        let gltf = gltf::Gltf::from_slice(bytes).map_err(|e| {
            bad(with_compression_hint(
                format!("invalid glTF: {e}"),
                &raw.json,
            ))
        })?;
        let document = gltf.document;
        let folder = LazyFolder::new(base);
        let buffers = load_buffers(&document, &folder, gltf.blob).map_err(bad)?;
        check_accessors(&document, &buffers).map_err(bad)?;

        let node_mesh: Vec<Option<usize>> = document
            .nodes()
            .map(|n| n.mesh().map(|m| m.index()))
            .collect();
        let vrm = read_vrm(raw.json.get("extensions"), &node_mesh);

        let mut budget = Budget::default();
        let mut meshes = Vec::new();
        for mesh in document.meshes() {
            meshes.push(
                read_mesh(&mesh, &buffers, &mut budget)
                    .map_err(|e| bad(with_compression_hint(e, &raw.json)))?,
            );
        }
        let nodes = read_nodes(&document).map_err(bad)?;
        let mut skins = Vec::new();
        for skin in document.skins() {
            let joints: Vec<usize> = skin.joints().map(|j| j.index()).collect();
            let inverse_bind_matrices: Vec<Mat4> = match skin.inverse_bind_matrices() {
                Some(a) => {
                    let what = format!("skin {} inverse bind matrices", skin.index());
                    let m = accessor::read_vectors::<16>(
                        &a,
                        &buffers,
                        &[DataType::F32],
                        &mut budget,
                        &what,
                    )
                    .map_err(bad)?;
                    if m.len() < joints.len() {
                        return Err(bad(format!(
                            "{what}: {} matrices for {} joints",
                            m.len(),
                            joints.len()
                        )));
                    }
                    m.iter().map(Mat4::from_cols_array).collect()
                }
                None => vec![Mat4::IDENTITY; joints.len()],
            };
            skins.push(Skin {
                joints,
                inverse_bind_matrices,
            });
        }
        let images = load_images(&raw.json, &folder, &buffers, path)
            .into_iter()
            .map(|image| image.unwrap_or_else(|_| white()))
            .collect::<Vec<_>>();
        let materials = document
            .materials()
            .map(|m| {
                let pbr = m.pbr_metallic_roughness();
                Material {
                    name: m.name().unwrap_or_default().to_owned(),
                    base_color_factor: pbr.base_color_factor(),
                    base_color_image: pbr
                        .base_color_texture()
                        .and_then(|t| texture_image(&raw.json, t.texture().index()))
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

/// The puppet's folder, opened (made canonical) on the first external URI only, so that a
/// file with embedded data loads wherever it is.
pub(crate) struct LazyFolder<'a> {
    base: Option<&'a Path>,
    opened: std::cell::OnceCell<std::result::Result<PuppetFolder, String>>,
}

impl<'a> LazyFolder<'a> {
    pub(crate) fn new(base: Option<&'a Path>) -> Self {
        Self {
            base,
            opened: std::cell::OnceCell::new(),
        }
    }

    /// Reads the external file `uri` (see [`PuppetFolder::read`]).
    pub(crate) fn read(
        &self,
        uri: &str,
        max_bytes: u64,
        take_prefix: bool,
        what: &str,
    ) -> std::result::Result<Vec<u8>, String> {
        let Some(base) = self.base else {
            return Err(format!(
                "{what} refers to the external file `{uri}`, but the puppet was not loaded from a folder"
            ));
        };
        match self.opened.get_or_init(|| PuppetFolder::new(base)) {
            Ok(folder) => folder.read(uri, max_bytes, take_prefix, what),
            Err(e) => Err(format!("{what}: {e}")),
        }
    }
}

/// Every buffer's bytes: the GLB's binary chunk, a `data:` URI, or a file inside the
/// puppet's folder, exactly `byteLength` long (longer sources are cut; shorter are errors).
pub(crate) fn load_buffers(
    document: &gltf::Document,
    folder: &LazyFolder,
    mut blob: Option<Vec<u8>>,
) -> std::result::Result<Vec<Vec<u8>>, String> {
    let mut buffers = Vec::new();
    for buffer in document.buffers() {
        let what = format!("buffer {}", buffer.index());
        let length = buffer.length();
        if length as u64 > MAX_FILE_BYTES {
            return Err(format!(
                "{what} declares {length} bytes, more than the {MAX_FILE_BYTES} a puppet may have"
            ));
        }
        let mut data = match buffer.source() {
            gltf::buffer::Source::Bin => blob.take().ok_or_else(|| {
                format!("{what} is the GLB binary chunk, but the file has none (or uses it twice)")
            })?,
            gltf::buffer::Source::Uri(uri) if uri.starts_with("data:") => {
                uri::decode_data_uri(uri, MAX_FILE_BYTES)
                    .map_err(|e| format!("{what}: {e}"))?
                    .0
            }
            gltf::buffer::Source::Uri(uri) => folder.read(uri, length as u64, true, &what)?,
        };
        if data.len() < length {
            return Err(format!(
                "{what} declares {length} bytes but holds {}",
                data.len()
            ));
        }
        data.truncate(length);
        buffers.push(data);
    }
    Ok(buffers)
}

/// Where an image's bytes come from, as the JSON says.
pub(crate) enum ImageSource<'j> {
    View(usize),
    DataUri(&'j str),
    File(&'j str),
}

/// Image `k`'s source, or why it has none.
pub(crate) fn image_source(image: &Value) -> std::result::Result<ImageSource<'_>, String> {
    if let Some(view) = image.get("bufferView") {
        let view = view.as_u64().ok_or("its `bufferView` is not an index")? as usize;
        if image.get("mimeType").and_then(Value::as_str).is_none() {
            return Err(
                "it has a `bufferView` but no `mimeType` (glTF requires one: image/png or image/jpeg)"
                    .into(),
            );
        }
        return Ok(ImageSource::View(view));
    }
    match image.get("uri").and_then(Value::as_str) {
        Some(uri) if uri.starts_with("data:") => Ok(ImageSource::DataUri(uri)),
        Some(uri) => Ok(ImageSource::File(uri)),
        None => Err("it has neither a `uri` nor a `bufferView`".into()),
    }
}

/// The encoded bytes of an image (not decoded).
pub(crate) fn image_bytes(
    source: &ImageSource,
    json: &Value,
    buffers: &[Vec<u8>],
    folder: &LazyFolder,
    what: &str,
) -> std::result::Result<Vec<u8>, String> {
    match *source {
        ImageSource::View(view) => {
            let v = json
                .get("bufferViews")
                .and_then(|v| v.get(view))
                .ok_or_else(|| format!("{what}: buffer view {view} does not exist"))?;
            let field = |name: &str| v.get(name).and_then(Value::as_u64).unwrap_or(0) as usize;
            let data = buffers
                .get(field("buffer"))
                .ok_or_else(|| format!("{what}: buffer view {view} has no buffer"))?;
            let start = field("byteOffset");
            let end = start.checked_add(field("byteLength"));
            end.and_then(|end| data.get(start..end))
                .map(<[u8]>::to_vec)
                .ok_or_else(|| format!("{what}: buffer view {view} runs past its buffer"))
        }
        ImageSource::DataUri(uri) => uri::decode_data_uri(uri, MAX_IMAGE_BYTES)
            .map(|(bytes, _)| bytes)
            .map_err(|e| format!("{what}: {e}")),
        ImageSource::File(uri) => folder.read(uri, MAX_IMAGE_BYTES, false, what),
    }
}

/// Largest image side decoded (larger images are drawn white): 16k is the largest texture
/// GPUs take.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// Decodes PNG or JPEG bytes with bounded dimensions and memory.
pub fn decode_image(bytes: &[u8]) -> std::result::Result<RgbaImage, String> {
    let mut reader = image::ImageReader::new(std::io::Cursor::new(bytes))
        .with_guessed_format()
        .map_err(|e| e.to_string())?;
    if !matches!(
        reader.format(),
        Some(image::ImageFormat::Png | image::ImageFormat::Jpeg)
    ) {
        return Err("not a PNG or JPEG image".into());
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(1 << 30);
    reader.limits(limits);
    let decoded = reader.decode().map_err(|e| e.to_string())?.into_rgba8();
    Ok(RgbaImage {
        width: decoded.width(),
        height: decoded.height(),
        pixels: decoded.into_raw(),
    })
}

/// Decodes every image; one that cannot be read or decoded is `Err` with the reason (and a
/// warning): a missing texture should not make the puppet unusable, so the loader draws it
/// white.
pub(crate) fn load_images(
    json: &Value,
    folder: &LazyFolder,
    buffers: &[Vec<u8>],
    path: &Path,
) -> Vec<std::result::Result<RgbaImage, String>> {
    let images = json
        .get("images")
        .and_then(Value::as_array)
        .map(Vec::as_slice)
        .unwrap_or_default();
    images
        .iter()
        .enumerate()
        .map(|(k, image)| {
            let what = format!("image {k}");
            let decoded = image_source(image)
                .map_err(|e| format!("{what}: {e}"))
                .and_then(|source| image_bytes(&source, json, buffers, folder, &what))
                .and_then(|bytes| decode_image(&bytes).map_err(|e| format!("{what}: {e}")));
            if let Err(e) = &decoded {
                tracing::warn!("{}: {e}; drawn white", path.display());
            }
            decoded
        })
        .collect()
}

/// The image texture `texture` shows (its `source`, or an extension's, e.g.
/// `KHR_texture_basisu`, when it has none).
fn texture_image(json: &Value, texture: usize) -> Option<usize> {
    let t = json.get("textures")?.get(texture)?;
    t.get("source").and_then(Value::as_u64).map(|i| i as usize)
}

fn white() -> RgbaImage {
    RgbaImage {
        width: 1,
        height: 1,
        pixels: vec![255; 4],
    }
}

/// What the `gltf` crate assumes of the JSON before its own validation (which itself
/// indexes `accessors` with a primitive's POSITION without checking it): every accessor a
/// primitive names exists.
fn check_json(json: &Value) -> std::result::Result<(), String> {
    let accessors = json
        .get("accessors")
        .and_then(Value::as_array)
        .map_or(0, Vec::len);
    let check = |at: &str, v: &Value| -> std::result::Result<(), String> {
        match v.as_u64() {
            Some(i) if (i as usize) < accessors => Ok(()),
            _ => Err(format!(
                "{at} refers to accessor {v}, but the file has {accessors} accessor(s)"
            )),
        }
    };
    let meshes = json.get("meshes").and_then(Value::as_array);
    for (m, mesh) in meshes.into_iter().flatten().enumerate() {
        let primitives = mesh.get("primitives").and_then(Value::as_array);
        for (p, primitive) in primitives.into_iter().flatten().enumerate() {
            let at = format!("mesh {m} primitive {p}");
            if let Some(attributes) = primitive.get("attributes").and_then(Value::as_object) {
                for (name, v) in attributes {
                    check(&format!("{at} attribute {name}"), v)?;
                }
            }
            if let Some(v) = primitive.get("indices") {
                check(&format!("{at} indices"), v)?;
            }
            let targets = primitive.get("targets").and_then(Value::as_array);
            for (k, target) in targets.into_iter().flatten().enumerate() {
                for (name, v) in target.as_object().into_iter().flatten() {
                    check(&format!("{at} morph target {k} {name}"), v)?;
                }
            }
        }
    }
    Ok(())
}

/// Compression extensions a file may use without requiring them (with an uncompressed
/// fallback); when the fallback is missing, the error says which extension is the reason.
const COMPRESSION_EXTENSIONS: &[&str] = &[
    "KHR_draco_mesh_compression",
    "EXT_meshopt_compression",
    "KHR_mesh_quantization",
];

fn with_compression_hint(error: String, json: &Value) -> String {
    let used: Vec<&str> = json
        .get("extensionsUsed")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
        .filter_map(Value::as_str)
        .filter(|e| COMPRESSION_EXTENSIONS.contains(e))
        .collect();
    if used.is_empty() {
        error
    } else {
        format!(
            "{error}; the file uses {} without an uncompressed fallback, which Likeness does not decode (export the puppet without compression)",
            used.join(", ")
        )
    }
}

/// Every accessor's bytes lie inside its buffer view, and every view inside its buffer.
fn check_accessors(
    document: &gltf::Document,
    buffers: &[Vec<u8>],
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
    buffers: &[Vec<u8>],
    budget: &mut Budget,
) -> std::result::Result<Mesh, String> {
    use DataType::{F32, I8, I16, U8, U16, U32};
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
        let positions = accessor::read_vectors::<3>(
            &position_accessor,
            buffers,
            &[F32],
            budget,
            &format!("{at} POSITION"),
        )?;
        // Optional attributes of the wrong length or type are errors, as a viewer that
        // used them would draw garbage.
        let attribute = |semantic: gltf::Semantic, what: &str| {
            primitive.get(&semantic).map(|a| {
                if a.count() != vertex_count {
                    Err(format!(
                        "{at}: {what} has {} elements for {vertex_count} positions",
                        a.count()
                    ))
                } else {
                    Ok((a, format!("{at} {what}")))
                }
            })
        };
        let normals: Vec<[f32; 3]> = match attribute(gltf::Semantic::Normals, "NORMAL") {
            Some(found) => {
                let (a, what) = found?;
                accessor::read_vectors::<3>(&a, buffers, &[F32], budget, &what)?
            }
            None => Vec::new(),
        };
        let uvs: Vec<[f32; 2]> = match attribute(gltf::Semantic::TexCoords(0), "TEXCOORD_0") {
            Some(found) => {
                let (a, what) = found?;
                // Integer texcoords are only valid normalised (KHR_mesh_quantization).
                accessor::read_vectors::<2>(&a, buffers, &[F32, U8, U16, I8, I16], budget, &what)?
            }
            None => Vec::new(),
        };
        let indices: Vec<u32> = match primitive.indices() {
            Some(a) => accessor::read_uints(
                &a,
                buffers,
                &[U8, U16, U32],
                Dimensions::Scalar,
                budget,
                &format!("{at} indices"),
            )?,
            None => (0..vertex_count as u32).collect(),
        };
        if let Some(&i) = indices.iter().find(|&&i| i as usize >= vertex_count) {
            return Err(format!(
                "{at}: index {i} is past its {vertex_count} vertices"
            ));
        }
        let joints: Vec<[u16; 4]> = match attribute(gltf::Semantic::Joints(0), "JOINTS_0") {
            Some(found) => {
                let (a, what) = found?;
                let flat =
                    accessor::read_uints(&a, buffers, &[U8, U16], Dimensions::Vec4, budget, &what)?;
                flat.chunks_exact(4)
                    .map(|c| [c[0] as u16, c[1] as u16, c[2] as u16, c[3] as u16])
                    .collect()
            }
            None => Vec::new(),
        };
        let weights: Vec<[f32; 4]> = match attribute(gltf::Semantic::Weights(0), "WEIGHTS_0") {
            Some(found) => {
                let (a, what) = found?;
                accessor::read_vectors::<4>(&a, buffers, &[F32, U8, U16], budget, &what)?
            }
            None => Vec::new(),
        };
        let mut targets = Vec::with_capacity(target_count);
        for (k, target) in primitive.morph_targets().enumerate() {
            let mut read_target = |accessor: Option<gltf::Accessor>, what: &str| {
                let what = format!("{at} morph target {k} {what}");
                match accessor {
                    Some(a) => {
                        expect_vec3_f32(&a, &what)?;
                        if a.count() != vertex_count {
                            return Err(format!(
                                "{what} has {} elements for {vertex_count} vertices",
                                a.count()
                            ));
                        }
                        accessor::read_vectors::<3>(&a, buffers, &[F32], budget, &what)
                    }
                    None => Ok(Vec::new()),
                }
            };
            let mut positions = read_target(target.positions(), "POSITION")?;
            let normals = read_target(target.normals(), "NORMAL")?;
            if positions.is_empty() {
                positions = vec![[0.0; 3]; vertex_count];
            }
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
    if default_weights.iter().any(|w| !w.is_finite()) {
        return Err(format!(
            "mesh `{name}`: its default `weights` are not all finite"
        ));
    }
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

/// The node tree, refused when it is not a forest (a node with two parents, a cycle) or a
/// transform is not finite.
fn read_nodes(document: &gltf::Document) -> std::result::Result<Vec<Node>, String> {
    let mut nodes = Vec::new();
    for n in document.nodes() {
        let (t, r, s) = n.transform().decomposed();
        if t.iter().chain(&r).chain(&s).any(|v| !v.is_finite()) {
            return Err(format!("node {}: its transform is not finite", n.index()));
        }
        let rotation = Quat::from_array(r);
        // A zero quaternion has no direction to normalise to.
        let rotation = if rotation.length_squared() > 1e-12 {
            rotation.normalize()
        } else {
            Quat::IDENTITY
        };
        nodes.push(Node {
            name: n
                .name()
                .map_or_else(|| format!("node{}", n.index()), str::to_owned),
            parent: None,
            children: n.children().map(|c| c.index()).collect(),
            mesh: n.mesh().map(|m| m.index()),
            skin: n.skin().map(|s| s.index()),
            translation: Vec3::from(t),
            rotation,
            scale: Vec3::from(s),
        });
    }
    for i in 0..nodes.len() {
        for c in nodes[i].children.clone() {
            let Some(child) = nodes.get_mut(c) else {
                return Err(format!("node {i} has child {c}, which does not exist"));
            };
            if let Some(p) = child.parent.filter(|&p| p != i) {
                return Err(format!(
                    "node {c} is a child of both node {p} and node {i} (glTF node trees give each node one parent)"
                ));
            }
            if c == i || child.parent == Some(i) {
                return Err(format!(
                    "node {i} lists node {c} as its child twice or is its own child (the node tree has a cycle)"
                ));
            }
            child.parent = Some(i);
        }
    }
    if let Some(cycle) = find_cycle(&nodes) {
        return Err(format!(
            "node {cycle} is its own ancestor (the node tree has a cycle)"
        ));
    }
    Ok(nodes)
}

/// With one parent per node, a cycle is a parent chain that comes back to its start.
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
