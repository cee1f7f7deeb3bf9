use crate::mesh::{MeshCounts, data_texel_count, mip_chain};
use crate::{
    DATA_TEXTURE_WIDTH, FrameParams, MAX_BLENDSHAPES, MeshData, RenderError, TextureLayers,
};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use wgpu::util::DeviceExt;

const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// Format of the blend pre-pass target: the data texture's, so blended values are exact f32.
const BLENDED_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Float;
const FLAG_HAS_MASK: u32 = 1;
const FLAG_HAS_SCALARS: u32 = 2;
const FLAG_HAS_CORRECTION: u32 = 4;

/// Mirrors `Frame` in `face.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct FrameUniform {
    view_from_model: [[f32; 4]; 4],
    clip_from_view: [[f32; 4]; 4],
    sh: [[f32; 4]; 7],
    background: [f32; 4],
    mode: [u32; 4],
    params: [f32; 4],
    counts: [u32; 4],
}

/// Mirrors `Weights` in `face.wgsl`: a count, the eyes' turn (`EyePose::uniform`), then
/// (index, weight) pairs, two per vec4.
#[repr(C)]
#[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
struct WeightsUniform {
    count: [u32; 4],
    eye_ranges: [u32; 4],
    eye_frames: [[f32; 4]; 8],
    pairs: [[f32; 4]; MAX_BLENDSHAPES / 2],
}

/// Bytes of [`WeightsUniform`] before `pairs`.
const WEIGHTS_HEADER_BYTES: usize = std::mem::offset_of!(WeightsUniform, pairs);

/// Depth (and MSAA colour) attachments, recreated when the render size changes.
struct Attachments {
    size: (u32, u32),
    depth: wgpu::TextureView,
    msaa_color: Option<wgpu::TextureView>,
}

/// Resources of [`BlendPath::PrePass`].
struct BlendPrepass {
    /// Render target: blended positions then unit normals, `data_width` texels per row.
    view: wgpu::TextureView,
    pipeline: wgpu::RenderPipeline,
    /// Frame uniform, weights and data texture only: the main bind group also holds the
    /// blended texture, which cannot be sampled in the pass that renders to it.
    bind_group: wgpu::BindGroup,
}

struct Pipelines {
    background: wgpu::RenderPipeline,
    depth_prepass: wgpu::RenderPipeline,
    /// Any view mode, read from the frame uniform.
    mesh: wgpu::RenderPipeline,
    /// The shaded view only, without and with the albedo correction (`MESH_MODE` in
    /// face.wgsl): the same pixels as `mesh` in that mode, at a fraction of the shading cost
    /// on a software rasteriser.
    mesh_shaded: wgpu::RenderPipeline,
    mesh_shaded_corrected: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    landmarks: wgpu::RenderPipeline,
}

/// Where the blendshape weights are applied. Both paths draw the same image (up to float
/// rounding); they differ in cost and in what the device must support.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum BlendPath {
    /// When the weights or the mesh changed, one render pass blends every mesh vertex into
    /// an `Rgba32Float` texture; every mesh-drawing pass then reads 2 texels per vertex.
    /// Needs `Rgba32Float` as a render target (always on Vulkan, Metal, DX12 and WebGPU; on
    /// WebGL2 only with `EXT_color_buffer_float`). See [`blend_prepass_supported`].
    PrePass,
    /// Every vertex shader invocation (per render corner, per pass) blends the active
    /// shapes itself: 2 texel reads per active shape. Slower, works everywhere.
    PerVertex,
    /// When the weights or the mesh changed, the CPU sums only the non-zero deltas of the
    /// active shapes and uploads the blended texture that [`Self::PrePass`] would render
    /// (`cpu_blend.rs`). The choice on a CPU adapter (lavapipe), where the pre-pass shader
    /// reads every delta of every active shape at every vertex and costs tens of
    /// milliseconds; the mesh passes are the pre-pass's.
    Cpu,
}

/// Construction choices of [`FaceRenderer::with_options`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct RenderOptions {
    /// MSAA sample count, 1 or 4. 4 smooths edges (goldens use it); 1 is markedly cheaper
    /// on a software rasteriser such as lavapipe.
    pub sample_count: u32,
    pub blend_path: BlendPath,
    /// Skip triangles facing away from the camera (counter-clockwise is the front). Only
    /// for meshes wound consistently outwards, such as the ICT template (tested against
    /// the unculled pictures); off for arbitrary puppets, whose materials may be
    /// double-sided. On a software rasteriser it saves about a quarter of a face frame.
    pub cull_back_faces: bool,
}

impl RenderOptions {
    /// The best this adapter supports for `format`: [`msaa_sample_count`]; the CPU blend on
    /// a CPU adapter, else the pre-pass if [`blend_prepass_supported`].
    pub fn for_adapter(adapter: &wgpu::Adapter, format: wgpu::TextureFormat) -> Self {
        Self {
            sample_count: msaa_sample_count(adapter, format),
            blend_path: if adapter.get_info().device_type == wgpu::DeviceType::Cpu {
                BlendPath::Cpu
            } else if blend_prepass_supported(adapter) {
                BlendPath::PrePass
            } else {
                BlendPath::PerVertex
            },
            cull_back_faces: false,
        }
    }
}

/// Whether [`BlendPath::PrePass`] works on this adapter: it renders into `Rgba32Float`,
/// which WebGL2 only allows with `EXT_color_buffer_float` (wgpu reports that here).
pub fn blend_prepass_supported(adapter: &wgpu::Adapter) -> bool {
    adapter
        .get_texture_format_features(BLENDED_FORMAT)
        .allowed_usages
        .contains(wgpu::TextureUsages::RENDER_ATTACHMENT)
}

/// Sample count to use for `format`: 4 if the adapter can multisample both it and the depth
/// format at 4x, otherwise 1.
pub fn msaa_sample_count(adapter: &wgpu::Adapter, format: wgpu::TextureFormat) -> u32 {
    let ok = |f| {
        adapter
            .get_texture_format_features(f)
            .flags
            .sample_count_supported(4)
    };
    if ok(format) && ok(DEPTH_FORMAT) { 4 } else { 1 }
}

/// Draws one blendshape mesh. See the crate docs for the design.
///
/// Create it once per mesh and target format; per frame call [`Self::set_weights`] (if the
/// expression changed) and [`Self::render`].
///
/// Inside egui: render into an app-owned texture (e.g. `Rgba8Unorm`, usage
/// `RENDER_ATTACHMENT | TEXTURE_BINDING`) from a paint callback's `prepare` step or the
/// app's own encoder, and show it with `egui_wgpu::Renderer::register_native_texture`.
/// [`Self::render`] begins its own render pass, so it cannot draw inside egui's pass.
pub struct FaceRenderer {
    /// Kept so the `set_*` methods can recreate textures whose size changes.
    device: wgpu::Device,
    target_format: wgpu::TextureFormat,
    sample_count: u32,
    blend_path: BlendPath,
    counts: MeshCounts,
    data_width: u32,
    data_rows: u32,
    scalar_width: u32,

    frame_buffer: wgpu::Buffer,
    weights_buffer: wgpu::Buffer,
    data_texture: wgpu::Texture,
    scalar_texture: wgpu::Texture,
    has_scalars: bool,
    albedo_texture: wgpu::Texture,
    mask_texture: wgpu::Texture,
    has_mask: bool,
    /// See [`FaceRenderer::set_albedo_correction`]; `Rgba16Float`.
    correction_texture: wgpu::Texture,
    /// The albedo layer the correction is added to, when there is one.
    correction_layer: Option<u32>,
    overlay_texture: wgpu::Texture,
    has_overlay: bool,
    overlay_opacity: f32,
    sampler: wgpu::Sampler,
    /// Blend pre-pass output (or upload on [`BlendPath::Cpu`]), or a 1x1 placeholder on
    /// [`BlendPath::PerVertex`] (the bind group layout is shared by all paths).
    blended_texture: wgpu::Texture,
    blend_prepass: Option<BlendPrepass>,
    /// The sparse mesh data of [`BlendPath::Cpu`].
    cpu_blend: Option<crate::cpu_blend::CpuBlend>,
    /// Set when the weights or the geometry changed since the last recorded blend pass.
    /// Atomic because [`FaceRenderer::render`] takes `&self` (egui callbacks share it).
    blend_dirty: AtomicBool,
    /// The K weights last uploaded, so that re-setting the same values (a UI calling
    /// [`FaceRenderer::set_weights`] every frame) neither uploads nor re-blends.
    weights: Vec<f32>,
    /// The mesh's eyeballs ([`MeshData::eyes`]), turned by the weights' gaze.
    eyes: Option<face::gaze::Eyes>,
    bind_group_layout: wgpu::BindGroupLayout,
    bind_group: wgpu::BindGroup,

    corner_buffer: wgpu::Buffer,
    index_buffer: wgpu::Buffer,
    edge_buffer: wgpu::Buffer,
    edge_index_count: u32,
    landmark_buffer: wgpu::Buffer,

    pipelines: Pipelines,
    attachments: Mutex<Option<Attachments>>,
    /// See [`FaceRenderer::content_stamp`].
    content_stamp: u64,
}

/// An RGB map in the UV space of one albedo layer, for
/// [`FaceRenderer::set_albedo_correction`].
#[derive(Clone, Copy, Debug)]
pub struct AlbedoCorrection<'a> {
    /// `width * height` RGB triples, rows top-first (as the albedo layers).
    pub rgb: &'a [f32],
    pub width: u32,
    pub height: u32,
    /// The albedo layer it is added to.
    pub layer: u32,
}

/// Source of [`FaceRenderer::content_stamp`] values, shared by all renderers so that a
/// stamp also tells two renderers apart.
static NEXT_CONTENT_STAMP: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);

fn new_content_stamp() -> u64 {
    NEXT_CONTENT_STAMP.fetch_add(1, Ordering::Relaxed)
}

fn check_texture_fits(
    device: &wgpu::Device,
    what: &'static str,
    width: u32,
    height: u32,
    layers: u32,
) -> Result<(), RenderError> {
    let limits = device.limits();
    let max_dim = limits.max_texture_dimension_2d;
    let max_layers = limits.max_texture_array_layers;
    if width > max_dim || height > max_dim || layers > max_layers {
        return Err(RenderError::TextureTooLarge {
            what,
            width,
            height,
            layers,
            max_dim,
            max_layers,
        });
    }
    Ok(())
}

/// Row-major single-channel `R32Float` texture of `values` with `width` columns.
fn scalar_texels(values: Option<&[f32]>, width: u32, rows: u32) -> Vec<f32> {
    let mut texels = values.map(<[f32]>::to_vec).unwrap_or_default();
    texels.resize((width * rows) as usize, 0.0);
    texels
}

impl FaceRenderer {
    /// Uploads the mesh and albedo and builds the pipelines for `target_format`.
    ///
    /// The MSAA sample count is chosen from what the format guarantees on this device (4x
    /// for every renderable format in WebGPU/WebGL2). With access to the adapter, prefer
    /// [`Self::with_sample_count`] and [`msaa_sample_count`].
    pub fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        target_format: wgpu::TextureFormat,
        mesh: &MeshData,
        albedo: &TextureLayers,
    ) -> Result<Self, RenderError> {
        let guaranteed = |f: wgpu::TextureFormat| {
            f.guaranteed_format_features(device.features())
                .flags
                .sample_count_supported(4)
        };
        let samples = if guaranteed(target_format) && guaranteed(DEPTH_FORMAT) {
            4
        } else {
            1
        };
        Self::with_sample_count(device, queue, target_format, samples, mesh, albedo)
    }

    /// Like [`Self::new`] with an explicit MSAA sample count (1 or 4).
    ///
    /// The blend path is [`BlendPath::PrePass`] except on the GL backend (WebGL2), where
    /// rendering to `Rgba32Float` is an optional extension that cannot be queried without
    /// the adapter; there [`Self::with_options`] with [`RenderOptions::for_adapter`] can
    /// still enable it.
    pub fn with_sample_count(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        target_format: wgpu::TextureFormat,
        sample_count: u32,
        mesh: &MeshData,
        albedo: &TextureLayers,
    ) -> Result<Self, RenderError> {
        let blend_path = if device.adapter_info().backend == wgpu::Backend::Gl {
            BlendPath::PerVertex
        } else {
            BlendPath::PrePass
        };
        let options = RenderOptions {
            sample_count,
            blend_path,
            cull_back_faces: false,
        };
        Self::with_options(device, queue, target_format, options, mesh, albedo)
    }

    /// Like [`Self::new`] with explicit options; [`RenderOptions::for_adapter`] picks the
    /// fastest the adapter supports. [`BlendPath::PrePass`] on a device that cannot render
    /// to `Rgba32Float` is a wgpu validation error.
    pub fn with_options(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        target_format: wgpu::TextureFormat,
        options: RenderOptions,
        mesh: &MeshData,
        albedo: &TextureLayers,
    ) -> Result<Self, RenderError> {
        let RenderOptions {
            sample_count,
            blend_path,
            cull_back_faces,
        } = options;
        if sample_count != 1 && sample_count != 4 {
            return Err(RenderError::InvalidInput(format!(
                "sample count {sample_count} (use 1 or 4)"
            )));
        }
        let counts = mesh.counts()?;
        albedo.validate()?;
        if (albedo.layers.len() as u32) < counts.layers_used {
            return Err(RenderError::InvalidTexture(format!(
                "the mesh uses {} layers but the albedo has {}",
                counts.layers_used,
                albedo.layers.len()
            )));
        }

        let max_dim = device.limits().max_texture_dimension_2d;
        // A power of two, so the shaders address texels with shifts (see `texel_coord`).
        let max_pow2 = 1u32 << (31 - max_dim.max(1).leading_zeros());
        let data_width = DATA_TEXTURE_WIDTH.min(max_pow2);
        let data_rows = data_texel_count(&counts).div_ceil(data_width as u64);
        let data_rows = u32::try_from(data_rows).unwrap_or(u32::MAX).max(1);
        check_texture_fits(
            device,
            "mesh geometry (positions, normals, deltas)",
            data_width,
            data_rows,
            1,
        )?;
        check_texture_fits(
            device,
            "albedo",
            albedo.width,
            albedo.height,
            albedo_texture_layers(albedo),
        )?;
        let scalar_width = data_width;
        let scalar_rows = counts.vertices.div_ceil(scalar_width);

        let data_texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("face geometry data"),
            size: wgpu::Extent3d {
                width: data_width,
                height: data_rows,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::Rgba32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        let scalar_texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("face vertex scalars"),
            size: wgpu::Extent3d {
                width: scalar_width,
                height: scalar_rows,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: wgpu::TextureFormat::R32Float,
            usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
            view_formats: &[],
        });
        write_r32f(
            queue,
            &scalar_texture,
            &scalar_texels(None, scalar_width, scalar_rows),
            scalar_width,
            scalar_rows,
        );
        let albedo_texture = create_albedo_texture(device, queue, albedo);
        let mask_texture = create_mask_texture(device, queue, &[0], 1, 1);
        let correction_texture = create_correction_texture(device, queue, &[[0; 4]], 1, 1);
        let overlay_texture =
            create_rgba_texture(device, queue, "face overlay", &[0, 0, 0, 255], 1, 1);

        let frame_buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("face frame uniform"),
            size: size_of::<FrameUniform>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let weights_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face active weights"),
            contents: bytemuck::bytes_of(&WeightsUniform::zeroed()),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let sampler = device.create_sampler(&wgpu::SamplerDescriptor {
            label: Some("face linear sampler"),
            address_mode_u: wgpu::AddressMode::ClampToEdge,
            address_mode_v: wgpu::AddressMode::ClampToEdge,
            address_mode_w: wgpu::AddressMode::ClampToEdge,
            mag_filter: wgpu::FilterMode::Linear,
            min_filter: wgpu::FilterMode::Linear,
            mipmap_filter: wgpu::MipmapFilterMode::Linear,
            ..Default::default()
        });

        // Blended positions and normals: 2V texels in the data texture's row width, so the
        // shader addresses both textures the same way.
        let blended_rows = (2 * counts.vertices as u64).div_ceil(data_width as u64);
        let blended_rows = u32::try_from(blended_rows).unwrap_or(u32::MAX);
        let blended_texture = match blend_path {
            BlendPath::PrePass | BlendPath::Cpu => {
                check_texture_fits(device, "blended geometry", data_width, blended_rows, 1)?;
                device.create_texture(&wgpu::TextureDescriptor {
                    label: Some("face blended geometry"),
                    size: wgpu::Extent3d {
                        width: data_width,
                        height: blended_rows,
                        depth_or_array_layers: 1,
                    },
                    mip_level_count: 1,
                    sample_count: 1,
                    dimension: wgpu::TextureDimension::D2,
                    format: BLENDED_FORMAT,
                    usage: if blend_path == BlendPath::Cpu {
                        wgpu::TextureUsages::COPY_DST | wgpu::TextureUsages::TEXTURE_BINDING
                    } else {
                        wgpu::TextureUsages::RENDER_ATTACHMENT
                            | wgpu::TextureUsages::TEXTURE_BINDING
                    },
                    view_formats: &[],
                })
            }
            BlendPath::PerVertex => create_2d(
                device,
                "face blended geometry (unused)",
                BLENDED_FORMAT,
                1,
                1,
            ),
        };

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("face.wgsl"),
            source: wgpu::ShaderSource::Wgsl(include_str!("face.wgsl").into()),
        });
        let bind_group_layout = create_bind_group_layout(device);
        let pipelines = create_pipelines(
            device,
            &module,
            &bind_group_layout,
            target_format,
            sample_count,
            blend_path,
            cull_back_faces,
        );
        let blend_prepass = (blend_path == BlendPath::PrePass).then(|| {
            create_blend_prepass(
                device,
                &module,
                &blended_texture,
                &frame_buffer,
                &weights_buffer,
                &data_texture,
            )
        });

        let corner_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face corners"),
            contents: bytemuck::cast_slice(&mesh.corners),
            usage: wgpu::BufferUsages::VERTEX,
        });
        // Buffers are padded to at least one element: zero-sized buffers cannot be bound.
        let padded = |v: Vec<u32>| if v.is_empty() { vec![0] } else { v };
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face triangle indices"),
            contents: bytemuck::cast_slice(&padded(mesh.indices.clone())),
            usage: wgpu::BufferUsages::INDEX,
        });
        let edges = mesh.unique_edges();
        let edge_index_count = edges.len() as u32;
        let edge_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face wireframe edges"),
            contents: bytemuck::cast_slice(&padded(edges)),
            usage: wgpu::BufferUsages::INDEX,
        });
        let landmark_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face landmark vertices"),
            contents: bytemuck::cast_slice(&padded(mesh.landmark_vertices.clone())),
            usage: wgpu::BufferUsages::VERTEX,
        });

        let bind_group = create_bind_group(
            device,
            &bind_group_layout,
            [&frame_buffer, &weights_buffer],
            [
                &data_texture,
                &scalar_texture,
                &albedo_texture,
                &mask_texture,
                &overlay_texture,
                &correction_texture,
            ],
            &sampler,
            &blended_texture,
        );

        let renderer = Self {
            device: device.clone(),
            target_format,
            sample_count,
            blend_path,
            counts,
            data_width,
            data_rows,
            scalar_width,
            frame_buffer,
            weights_buffer,
            data_texture,
            scalar_texture,
            has_scalars: false,
            albedo_texture,
            mask_texture,
            has_mask: false,
            correction_texture,
            correction_layer: None,
            overlay_texture,
            has_overlay: false,
            overlay_opacity: 1.0,
            sampler,
            blended_texture,
            blend_prepass,
            cpu_blend: None,
            blend_dirty: AtomicBool::new(true),
            // Matches the zeroed weights buffer: no active shape.
            weights: vec![0.0; counts.shapes as usize],
            eyes: mesh.eyes.clone(),
            bind_group_layout,
            bind_group,
            corner_buffer,
            index_buffer,
            edge_buffer,
            edge_index_count,
            landmark_buffer,
            pipelines,
            attachments: Mutex::new(None),
            content_stamp: new_content_stamp(),
        };
        let mut renderer = renderer;
        renderer.upload_geometry(queue, mesh);
        tracing::debug!(
            vertices = counts.vertices,
            shapes = counts.shapes,
            data_rows,
            sample_count,
            ?blend_path,
            "face renderer created"
        );
        Ok(renderer)
    }

    /// Format the pipelines were built for; [`Self::render`]'s target must have it.
    pub fn target_format(&self) -> wgpu::TextureFormat {
        self.target_format
    }

    /// MSAA sample count in use (1 or 4).
    pub fn sample_count(&self) -> u32 {
        self.sample_count
    }

    /// Where the blendshape weights are applied.
    pub fn blend_path(&self) -> BlendPath {
        self.blend_path
    }

    /// Whether the next [`Self::render`] records the blend pre-pass (weights or geometry
    /// changed since the last one). Always false on [`BlendPath::PerVertex`].
    pub fn blend_pending(&self) -> bool {
        self.blend_prepass.is_some() && self.blend_dirty.load(Ordering::Acquire)
    }

    /// Number of mesh vertices V.
    pub fn vertex_count(&self) -> usize {
        self.counts.vertices as usize
    }

    /// Number of blendshapes K.
    pub fn shape_count(&self) -> usize {
        self.counts.shapes as usize
    }

    fn upload_geometry(&mut self, queue: &wgpu::Queue, mesh: &MeshData) {
        let texels = mesh.data_texels(self.data_width, self.data_rows);
        write_rgba32f(queue, &self.data_texture, &texels);
        self.blend_dirty.store(true, Ordering::Release);
        if self.blend_path == BlendPath::Cpu {
            self.cpu_blend = Some(crate::cpu_blend::CpuBlend::new(mesh));
            self.upload_cpu_blend(queue);
        }
    }

    /// [`BlendPath::Cpu`]: blends the current weights and uploads the blended texture.
    fn upload_cpu_blend(&self, queue: &wgpu::Queue) {
        let Some(blend) = &self.cpu_blend else {
            return;
        };
        let size = self.blended_texture.size();
        let texels = blend.texels(&self.weights, (size.width * size.height) as usize);
        write_rgba32f(queue, &self.blended_texture, &texels);
    }

    fn rebuild_bind_group(&mut self) {
        self.bind_group = create_bind_group(
            &self.device,
            &self.bind_group_layout,
            [&self.frame_buffer, &self.weights_buffer],
            [
                &self.data_texture,
                &self.scalar_texture,
                &self.albedo_texture,
                &self.mask_texture,
                &self.overlay_texture,
                &self.correction_texture,
            ],
            &self.sampler,
            &self.blended_texture,
        );
    }

    /// Sets the K blendshape weights. Only the non-zero ones are uploaded, as a compact
    /// `(index, weight)` list, so the blend loops over active shapes only.
    /// Takes effect at the next queue submission; on [`BlendPath::PrePass`] the next
    /// [`Self::render`] records the blend pass (skipped while the weights stay unchanged).
    pub fn set_weights(&mut self, queue: &wgpu::Queue, weights: &[f32]) -> Result<(), RenderError> {
        let k = self.counts.shapes as usize;
        if weights.len() != k {
            return Err(RenderError::InvalidWeights(format!(
                "got {} weights, the mesh has {k} blendshapes",
                weights.len()
            )));
        }
        if let Some(i) = weights.iter().position(|w| !w.is_finite()) {
            return Err(RenderError::InvalidWeights(format!(
                "weight {i} is {}",
                weights[i]
            )));
        }
        if self.weights == weights {
            return Ok(());
        }
        self.weights.copy_from_slice(weights);
        self.upload_weights(queue);
        self.upload_cpu_blend(queue);
        self.content_stamp = new_content_stamp();
        Ok(())
    }

    /// Uploads the active weights and the eyes' turn for them, and marks the blend dirty.
    fn upload_weights(&self, queue: &wgpu::Queue) {
        let mut uniform = WeightsUniform::zeroed();
        (uniform.eye_ranges, uniform.eye_frames) =
            crate::eyes::EyePose::new(self.eyes.as_ref(), &self.weights).uniform();
        let mut n = 0usize;
        for (i, &w) in self.weights.iter().enumerate() {
            if w != 0.0 {
                // Indices <= 255 are exact in f32.
                uniform.pairs[n / 2][(n % 2) * 2] = i as f32;
                uniform.pairs[n / 2][(n % 2) * 2 + 1] = w;
                n += 1;
            }
        }
        uniform.count[0] = n as u32;
        // Only the used part of the array goes over the bus.
        let used = WEIGHTS_HEADER_BYTES + n.div_ceil(2) * 16;
        queue.write_buffer(
            &self.weights_buffer,
            0,
            &bytemuck::bytes_of(&uniform)[..used],
        );
        self.blend_dirty.store(true, Ordering::Release);
    }

    /// Changes whenever anything that [`Self::render`] draws changes (weights, geometry,
    /// textures, mask, scalars, overlay) and differs between renderers: a caller that keeps
    /// the last frame can skip rendering while the stamp, the [`FrameParams`] and the size
    /// stay the same. (Re-setting unchanged weights keeps the stamp.)
    pub fn content_stamp(&self) -> u64 {
        self.content_stamp
    }

    /// Replaces the albedo texture array (same or different size).
    pub fn set_albedo(
        &mut self,
        queue: &wgpu::Queue,
        albedo: &TextureLayers,
    ) -> Result<(), RenderError> {
        albedo.validate()?;
        if (albedo.layers.len() as u32) < self.counts.layers_used {
            return Err(RenderError::InvalidTexture(format!(
                "the mesh uses {} layers but the albedo has {}",
                self.counts.layers_used,
                albedo.layers.len()
            )));
        }
        check_texture_fits(
            &self.device,
            "albedo",
            albedo.width,
            albedo.height,
            albedo_texture_layers(albedo),
        )?;
        let size = self.albedo_texture.size();
        if size.width == albedo.width
            && size.height == albedo.height
            && size.depth_or_array_layers == albedo_texture_layers(albedo)
        {
            write_albedo(queue, &self.albedo_texture, albedo);
        } else {
            self.albedo_texture = create_albedo_texture(&self.device, queue, albedo);
            self.rebuild_bind_group();
        }
        self.content_stamp = new_content_stamp();
        Ok(())
    }

    /// Replaces one layer of the albedo texture array with `texels` (RGBA, row by row, the
    /// array's size): a clip whose face albedo changes every frame (equation 3's dynamic
    /// albedo) uploads that layer alone, not the whole array through [`Self::set_albedo`].
    pub fn set_albedo_layer(
        &mut self,
        queue: &wgpu::Queue,
        layer: u32,
        texels: &[[u8; 4]],
    ) -> Result<(), RenderError> {
        let size = self.albedo_texture.size();
        if layer >= size.depth_or_array_layers {
            return Err(RenderError::InvalidTexture(format!(
                "albedo layer {layer} does not exist (the array has {})",
                size.depth_or_array_layers
            )));
        }
        let expected = size.width as usize * size.height as usize;
        if texels.len() != expected {
            return Err(RenderError::InvalidTexture(format!(
                "albedo layer {layer} has {} texels, the {}x{} array needs {expected}",
                texels.len(),
                size.width,
                size.height
            )));
        }
        write_albedo_layer(
            queue,
            &self.albedo_texture,
            (size.width, size.height),
            layer,
            texels,
        );
        self.content_stamp = new_content_stamp();
        Ok(())
    }

    /// Re-uploads positions, normals and deltas (e.g. new personal corrections). The
    /// topology (V, K, corners, indices, landmarks) must be unchanged.
    pub fn set_mesh_deltas(
        &mut self,
        queue: &wgpu::Queue,
        mesh: &MeshData,
    ) -> Result<(), RenderError> {
        let counts = mesh.counts()?;
        if (counts.vertices, counts.shapes) != (self.counts.vertices, self.counts.shapes) {
            return Err(RenderError::InvalidMesh(format!(
                "set_mesh_deltas: mesh has V = {}, K = {}, the renderer was built for V = {}, K = {}",
                counts.vertices, counts.shapes, self.counts.vertices, self.counts.shapes
            )));
        }
        self.upload_geometry(queue, mesh);
        if self.eyes != mesh.eyes {
            // New centres (another identity) or eyes added or removed: the turn changes too.
            self.eyes = mesh.eyes.clone();
            self.upload_weights(queue);
        }
        self.content_stamp = new_content_stamp();
        Ok(())
    }

    /// A `width x height` single-channel map (values 0..1, rows top-first) in the UV space of
    /// layer 0, shown in [`crate::ViewMode::MaskHeatmap`]; `None` clears it.
    ///
    /// Stored as `R8Unorm` so it can be filtered on every backend (1/255 steps are plenty
    /// for a colour map).
    pub fn set_uv_mask(
        &mut self,
        queue: &wgpu::Queue,
        mask: Option<(&[f32], u32, u32)>,
    ) -> Result<(), RenderError> {
        self.content_stamp = new_content_stamp();
        let Some((values, width, height)) = mask else {
            self.has_mask = false;
            return Ok(());
        };
        if width == 0 || height == 0 || values.len() != width as usize * height as usize {
            return Err(RenderError::InvalidInput(format!(
                "uv mask has {} values for {width}x{height}",
                values.len()
            )));
        }
        check_texture_fits(&self.device, "uv mask", width, height, 1)?;
        // NaN maps to 0 (as casts saturate), values are clamped to 0..1.
        let bytes: Vec<u8> = values
            .iter()
            .map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8)
            .collect();
        let size = self.mask_texture.size();
        if (size.width, size.height) == (width, height) {
            write_r8(queue, &self.mask_texture, &bytes, width, height);
        } else {
            self.mask_texture = create_mask_texture(&self.device, queue, &bytes, width, height);
            self.rebuild_bind_group();
        }
        self.has_mask = true;
        Ok(())
    }

    /// An RGB map added to albedo layer `layer` where the mesh samples it (bilinear, clamped
    /// to the edge, the sum clamped to 0..1), so a person's albedo can change per frame
    /// (equation 3's dR_0 + sum_i w_i A_i dR_i over the mean albedo R_0^t) by uploading a
    /// small map instead of the whole albedo. `None` removes it.
    ///
    /// Stored as `Rgba16Float`, which every backend can filter (WebGL2 included); half
    /// precision is ~1e-4 on these values, far below an 8-bit colour step.
    pub fn set_albedo_correction(
        &mut self,
        queue: &wgpu::Queue,
        correction: Option<AlbedoCorrection<'_>>,
    ) -> Result<(), RenderError> {
        self.content_stamp = new_content_stamp();
        let Some(c) = correction else {
            self.correction_layer = None;
            return Ok(());
        };
        let (w, h) = (c.width, c.height);
        if w == 0 || h == 0 || c.rgb.len() != 3 * w as usize * h as usize {
            return Err(RenderError::InvalidInput(format!(
                "albedo correction has {} values for {w}x{h} RGB",
                c.rgb.len()
            )));
        }
        if c.layer >= self.albedo_texture.size().depth_or_array_layers {
            return Err(RenderError::InvalidInput(format!(
                "albedo correction for layer {} of {}",
                c.layer,
                self.albedo_texture.size().depth_or_array_layers
            )));
        }
        if let Some(i) = c.rgb.iter().position(|v| !v.is_finite()) {
            return Err(RenderError::InvalidInput(format!(
                "albedo correction value {i} is {}",
                c.rgb[i]
            )));
        }
        check_texture_fits(&self.device, "albedo correction", w, h, 1)?;
        let texels: Vec<[u16; 4]> = c
            .rgb
            .chunks_exact(3)
            .map(|t| {
                let f = |x: f32| half::f16::from_f32(x).to_bits();
                [f(t[0]), f(t[1]), f(t[2]), 0]
            })
            .collect();
        let size = self.correction_texture.size();
        if (size.width, size.height) == (w, h) {
            write_2d(
                queue,
                &self.correction_texture,
                bytemuck::cast_slice(&texels),
                8,
                w,
                h,
            );
        } else {
            self.correction_texture = create_correction_texture(&self.device, queue, &texels, w, h);
            self.rebuild_bind_group();
        }
        self.correction_layer = Some(c.layer);
        Ok(())
    }

    /// V per-vertex values shown (divided by [`FrameParams::heatmap_max`]) in
    /// [`crate::ViewMode::VertexHeatmap`]; `None` clears them.
    pub fn set_vertex_scalars(
        &mut self,
        queue: &wgpu::Queue,
        scalars: Option<&[f32]>,
    ) -> Result<(), RenderError> {
        self.content_stamp = new_content_stamp();
        let Some(values) = scalars else {
            self.has_scalars = false;
            return Ok(());
        };
        if values.len() != self.counts.vertices as usize {
            return Err(RenderError::InvalidInput(format!(
                "{} vertex scalars for {} vertices",
                values.len(),
                self.counts.vertices
            )));
        }
        let rows = self.scalar_texture.height();
        let texels = scalar_texels(Some(values), self.scalar_width, rows);
        write_r32f(
            queue,
            &self.scalar_texture,
            &texels,
            self.scalar_width,
            rows,
        );
        self.has_scalars = true;
        Ok(())
    }

    /// When `image` is set, it fills the background (stretched to the render size) and the
    /// face is composited over it with `opacity` (clamped to 0..1). `None` removes it.
    pub fn set_overlay_image(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        image: Option<&image::RgbaImage>,
        opacity: f32,
    ) -> Result<(), RenderError> {
        self.content_stamp = new_content_stamp();
        self.overlay_opacity = if opacity.is_finite() {
            opacity.clamp(0.0, 1.0)
        } else {
            1.0
        };
        let Some(image) = image else {
            self.has_overlay = false;
            return Ok(());
        };
        let (w, h) = image.dimensions();
        if w == 0 || h == 0 {
            return Err(RenderError::InvalidInput("overlay image is empty".into()));
        }
        check_texture_fits(device, "overlay image", w, h, 1)?;
        let size = self.overlay_texture.size();
        if (size.width, size.height) == (w, h) {
            write_rgba(queue, &self.overlay_texture, image.as_raw(), w, h);
        } else {
            self.overlay_texture =
                create_rgba_texture(device, queue, "face overlay", image.as_raw(), w, h);
            self.rebuild_bind_group();
        }
        self.has_overlay = true;
        Ok(())
    }

    fn attachments_for(&self, size: (u32, u32)) -> std::sync::MutexGuard<'_, Option<Attachments>> {
        // A poisoned lock only means another thread panicked mid-render; the attachments
        // are recreated below if needed, so the data is still usable.
        let mut guard = self.attachments.lock().unwrap_or_else(|e| e.into_inner());
        if guard.as_ref().is_none_or(|a| a.size != size) {
            let extent = wgpu::Extent3d {
                width: size.0,
                height: size.1,
                depth_or_array_layers: 1,
            };
            let make = |label, format| {
                self.device
                    .create_texture(&wgpu::TextureDescriptor {
                        label: Some(label),
                        size: extent,
                        mip_level_count: 1,
                        sample_count: self.sample_count,
                        dimension: wgpu::TextureDimension::D2,
                        format,
                        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
                        view_formats: &[],
                    })
                    .create_view(&wgpu::TextureViewDescriptor::default())
            };
            *guard = Some(Attachments {
                size,
                depth: make("face depth", DEPTH_FORMAT),
                msaa_color: (self.sample_count > 1)
                    .then(|| make("face msaa colour", self.target_format)),
            });
        }
        guard
    }

    /// Records the frame into `encoder`: clears `target` (which must have
    /// [`Self::target_format`] and be `size` pixels) to the background, draws the overlay
    /// image if any, then the face and the view mode's decorations.
    ///
    /// The frame uniform is copied inside `encoder`, so several `render` calls with
    /// different `params` may share one encoder. Weights and textures set through the
    /// `set_*` methods are queue writes and apply to the next submission as a whole.
    pub fn render(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        size: (u32, u32),
        params: &FrameParams,
    ) {
        // The queue is not needed: uploading through the encoder keeps per-call params.
        let _ = queue;
        if size.0 == 0 || size.1 == 0 {
            return;
        }
        let max_dim = device.limits().max_texture_dimension_2d;
        if size.0 > max_dim || size.1 > max_dim {
            tracing::error!(
                ?size,
                max_dim,
                "render size exceeds the device limit; nothing drawn"
            );
            return;
        }
        let opacity = if self.has_overlay {
            self.overlay_opacity
        } else {
            1.0
        };
        let mut sh = [[0.0f32; 4]; 7];
        for (i, c) in params.sh_coefficients.iter().enumerate() {
            sh[i / 4][i % 4] = if c.is_finite() { *c } else { 0.0 };
        }
        let flags = if self.has_mask { FLAG_HAS_MASK } else { 0 }
            | if self.correction_layer.is_some() {
                FLAG_HAS_CORRECTION
            } else {
                0
            }
            | if self.has_scalars {
                FLAG_HAS_SCALARS
            } else {
                0
            };
        let uniform = FrameUniform {
            view_from_model: params.camera.view_from_model.to_cols_array_2d(),
            clip_from_view: params.camera.clip_from_view.to_cols_array_2d(),
            sh,
            background: params.background,
            mode: [
                params.view.shader_id(),
                flags,
                self.data_width,
                self.counts.vertices,
            ],
            params: [params.heatmap_max, opacity, size.0 as f32, size.1 as f32],
            counts: [
                self.counts.shapes,
                self.scalar_width,
                self.data_width.trailing_zeros(),
                self.correction_layer.unwrap_or(u32::MAX),
            ],
        };
        let staging = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("face frame staging"),
            contents: bytemuck::bytes_of(&uniform),
            usage: wgpu::BufferUsages::COPY_SRC,
        });
        encoder.copy_buffer_to_buffer(
            &staging,
            0,
            &self.frame_buffer,
            0,
            size_of::<FrameUniform>() as u64,
        );

        // After the frame-uniform copy: the blend pass reads V, K and the texture width from
        // it. Later render calls (in this encoder or the next) reuse the blended texture.
        if let Some(blend) = &self.blend_prepass
            && self.blend_dirty.swap(false, Ordering::AcqRel)
        {
            let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("face blend pre-pass"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &blend.view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        // Every texel is written by the full-screen triangle.
                        load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            pass.set_pipeline(&blend.pipeline);
            pass.set_bind_group(0, &blend.bind_group, &[]);
            pass.draw(0..3, 0..1);
        }

        let attachments = self.attachments_for(size);
        let Some(att) = attachments.as_ref() else {
            return;
        };
        let [r, g, b, a] = params.background.map(f64::from);
        let (view, resolve_target) = match &att.msaa_color {
            Some(msaa) => (msaa, Some(target)),
            None => (target, None),
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("face"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a }),
                    // The MSAA texture is only needed until it is resolved.
                    store: if resolve_target.is_some() {
                        wgpu::StoreOp::Discard
                    } else {
                        wgpu::StoreOp::Store
                    },
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &att.depth,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        pass.set_bind_group(0, &self.bind_group, &[]);
        if self.has_overlay {
            pass.set_pipeline(&self.pipelines.background);
            pass.draw(0..3, 0..1);
        }
        if self.counts.indices > 0 {
            pass.set_vertex_buffer(0, self.corner_buffer.slice(..));
            pass.set_index_buffer(self.index_buffer.slice(..), wgpu::IndexFormat::Uint32);
            // The depth pre-pass only stops hidden layers showing through a translucent face.
            // Opaque faces need none, and at opacity 0 the colour pass changes no colour
            // whichever fragments win (while still writing the same depth for the lines).
            if opacity < 1.0 && opacity > 0.0 {
                pass.set_pipeline(&self.pipelines.depth_prepass);
                pass.draw_indexed(0..self.counts.indices, 0, 0..1);
            }
            pass.set_pipeline(match params.view {
                crate::ViewMode::Shaded if self.correction_layer.is_some() => {
                    &self.pipelines.mesh_shaded_corrected
                }
                crate::ViewMode::Shaded => &self.pipelines.mesh_shaded,
                _ => &self.pipelines.mesh,
            });
            pass.draw_indexed(0..self.counts.indices, 0, 0..1);
        }
        if params.view == crate::ViewMode::Wireframe && self.edge_index_count > 0 {
            pass.set_pipeline(&self.pipelines.lines);
            pass.set_vertex_buffer(0, self.corner_buffer.slice(..));
            pass.set_index_buffer(self.edge_buffer.slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..self.edge_index_count, 0, 0..1);
        }
        if params.view == crate::ViewMode::Landmarks && self.counts.landmarks > 0 {
            pass.set_pipeline(&self.pipelines.landmarks);
            pass.set_vertex_buffer(0, self.landmark_buffer.slice(..));
            pass.draw(0..6, 0..self.counts.landmarks);
        }
    }
}

use bytemuck::Zeroable;

fn create_bind_group_layout(device: &wgpu::Device) -> wgpu::BindGroupLayout {
    let vf = wgpu::ShaderStages::VERTEX_FRAGMENT;
    let uniform = |binding| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: vf,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    };
    let texture = |binding, filterable, dim| wgpu::BindGroupLayoutEntry {
        binding,
        visibility: vf,
        ty: wgpu::BindingType::Texture {
            sample_type: wgpu::TextureSampleType::Float { filterable },
            view_dimension: dim,
            multisampled: false,
        },
        count: None,
    };
    use wgpu::TextureViewDimension::{D2, D2Array};
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("face"),
        entries: &[
            uniform(0),
            uniform(1),
            texture(2, false, D2),
            texture(3, false, D2),
            texture(4, true, D2Array),
            texture(5, true, D2),
            texture(6, true, D2),
            wgpu::BindGroupLayoutEntry {
                binding: 7,
                visibility: vf,
                ty: wgpu::BindingType::Sampler(wgpu::SamplerBindingType::Filtering),
                count: None,
            },
            texture(8, false, D2),
            texture(9, true, D2),
        ],
    })
}

fn create_bind_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    buffers: [&wgpu::Buffer; 2],
    // data, scalars, albedo (array), mask, overlay, albedo correction
    textures: [&wgpu::Texture; 6],
    sampler: &wgpu::Sampler,
    blended: &wgpu::Texture,
) -> wgpu::BindGroup {
    let blended_view = blended.create_view(&Default::default());
    let views: Vec<wgpu::TextureView> = textures
        .iter()
        .enumerate()
        .map(|(i, t)| {
            t.create_view(&wgpu::TextureViewDescriptor {
                // The albedo is an array even with one layer.
                dimension: Some(if i == 2 {
                    wgpu::TextureViewDimension::D2Array
                } else {
                    wgpu::TextureViewDimension::D2
                }),
                ..Default::default()
            })
        })
        .collect();
    let mut entries: Vec<wgpu::BindGroupEntry> = buffers
        .iter()
        .enumerate()
        .map(|(i, b)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource: b.as_entire_binding(),
        })
        .collect();
    // Bindings 2..=6, then 7 is the sampler and 8 the blended geometry.
    entries.extend(views.iter().enumerate().map(|(i, v)| wgpu::BindGroupEntry {
        binding: if i < 5 { 2 + i as u32 } else { 9 },
        resource: wgpu::BindingResource::TextureView(v),
    }));
    entries.push(wgpu::BindGroupEntry {
        binding: 7,
        resource: wgpu::BindingResource::Sampler(sampler),
    });
    entries.push(wgpu::BindGroupEntry {
        binding: 8,
        resource: wgpu::BindingResource::TextureView(&blended_view),
    });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("face"),
        layout,
        entries: &entries,
    })
}

/// Pipeline and bind group of the blend pre-pass (see `fs_blend` in `face.wgsl`).
fn create_blend_prepass(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    target: &wgpu::Texture,
    frame: &wgpu::Buffer,
    weights: &wgpu::Buffer,
    data: &wgpu::Texture,
) -> BlendPrepass {
    let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some("face blend pre-pass"),
        entries: &[
            wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 1,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            },
            wgpu::BindGroupLayoutEntry {
                binding: 2,
                visibility: wgpu::ShaderStages::FRAGMENT,
                ty: wgpu::BindingType::Texture {
                    sample_type: wgpu::TextureSampleType::Float { filterable: false },
                    view_dimension: wgpu::TextureViewDimension::D2,
                    multisampled: false,
                },
                count: None,
            },
        ],
    });
    let data_view = data.create_view(&Default::default());
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("face blend pre-pass"),
        layout: &layout,
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: frame.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: weights.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: wgpu::BindingResource::TextureView(&data_view),
            },
        ],
    });
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("face blend pre-pass"),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("face blend pre-pass"),
        layout: Some(&pipeline_layout),
        vertex: wgpu::VertexState {
            module,
            entry_point: Some("vs_background"),
            compilation_options: Default::default(),
            buffers: &[],
        },
        primitive: Default::default(),
        depth_stencil: None,
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module,
            entry_point: Some("fs_blend"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::ColorTargetState {
                format: BLENDED_FORMAT,
                // Float32 targets are not blendable without a feature; none is needed.
                blend: None,
                write_mask: wgpu::ColorWrites::ALL,
            })],
        }),
        multiview_mask: None,
        cache: None,
    });
    BlendPrepass {
        view: target.create_view(&Default::default()),
        pipeline,
        bind_group,
    }
}

fn create_pipelines(
    device: &wgpu::Device,
    module: &wgpu::ShaderModule,
    layout: &wgpu::BindGroupLayout,
    format: wgpu::TextureFormat,
    sample_count: u32,
    blend_path: BlendPath,
    cull_back_faces: bool,
) -> Pipelines {
    // Selects the vertex shaders' blending path (see `vertex_geometry` in face.wgsl).
    let per_vertex = [(
        "PER_VERTEX_BLEND",
        if blend_path == BlendPath::PerVertex {
            1.0
        } else {
            0.0
        },
    )];
    let vertex_options = wgpu::PipelineCompilationOptions {
        constants: &per_vertex,
        ..Default::default()
    };
    let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some("face"),
        bind_group_layouts: &[Some(layout)],
        immediate_size: 0,
    });
    let corner_attributes = wgpu::vertex_attr_array![0 => Uint32, 1 => Uint32, 2 => Float32x2];
    let corner_layout = wgpu::VertexBufferLayout {
        array_stride: size_of::<crate::RenderVertex>() as u64,
        step_mode: wgpu::VertexStepMode::Vertex,
        attributes: &corner_attributes,
    };
    let landmark_attributes = wgpu::vertex_attr_array![0 => Uint32];
    let landmark_layout = wgpu::VertexBufferLayout {
        array_stride: 4,
        step_mode: wgpu::VertexStepMode::Instance,
        attributes: &landmark_attributes,
    };
    let alpha_blend = wgpu::BlendState {
        color: wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::SrcAlpha,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        },
        alpha: wgpu::BlendComponent {
            src_factor: wgpu::BlendFactor::One,
            dst_factor: wgpu::BlendFactor::OneMinusSrcAlpha,
            operation: wgpu::BlendOperation::Add,
        },
    };
    struct Variant<'a> {
        label: &'a str,
        vs: &'a str,
        fs: &'a str,
        buffers: &'a [Option<wgpu::VertexBufferLayout<'a>>],
        topology: wgpu::PrimitiveTopology,
        depth_write: bool,
        depth_compare: wgpu::CompareFunction,
        blend: Option<wgpu::BlendState>,
        write_mask: wgpu::ColorWrites,
        /// Whether this pipeline draws the mesh's triangles (and may cull them).
        mesh_triangles: bool,
        /// Pipeline-overridable constants of the fragment shader.
        fs_constants: &'a [(&'a str, f64)],
    }
    let make = |v: Variant| {
        device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
            label: Some(v.label),
            layout: Some(&pipeline_layout),
            vertex: wgpu::VertexState {
                module,
                entry_point: Some(v.vs),
                compilation_options: vertex_options.clone(),
                buffers: v.buffers,
            },
            primitive: wgpu::PrimitiveState {
                topology: v.topology,
                // Culling only where the caller vouches for the winding (see
                // RenderOptions::cull_back_faces); never for the full-screen and dot quads.
                cull_mode: (v.mesh_triangles && cull_back_faces).then_some(wgpu::Face::Back),
                ..Default::default()
            },
            depth_stencil: Some(wgpu::DepthStencilState {
                format: DEPTH_FORMAT,
                depth_write_enabled: Some(v.depth_write),
                depth_compare: Some(v.depth_compare),
                stencil: Default::default(),
                bias: Default::default(),
            }),
            multisample: wgpu::MultisampleState {
                count: sample_count,
                ..Default::default()
            },
            fragment: Some(wgpu::FragmentState {
                module,
                entry_point: Some(v.fs),
                compilation_options: wgpu::PipelineCompilationOptions {
                    constants: v.fs_constants,
                    ..Default::default()
                },
                targets: &[Some(wgpu::ColorTargetState {
                    format,
                    blend: v.blend,
                    write_mask: v.write_mask,
                })],
            }),
            multiview_mask: None,
            cache: None,
        })
    };
    let corners = [Some(corner_layout)];
    let landmarks = [Some(landmark_layout)];
    use wgpu::CompareFunction::{Always, LessEqual};
    use wgpu::PrimitiveTopology::{LineList, TriangleList};
    let shaded_mode = f64::from(crate::ViewMode::Shaded.shader_id());
    let shaded = [("MESH_MODE", shaded_mode), ("MESH_CORRECTION", 0.0)];
    let shaded_corrected = [("MESH_MODE", shaded_mode), ("MESH_CORRECTION", 1.0)];
    let mesh_variant = |label, fs_constants| Variant {
        label,
        vs: "vs_mesh",
        fs: "fs_mesh",
        buffers: &corners,
        topology: TriangleList,
        depth_write: true,
        depth_compare: LessEqual,
        blend: Some(alpha_blend),
        write_mask: wgpu::ColorWrites::ALL,
        mesh_triangles: true,
        fs_constants,
    };
    Pipelines {
        background: make(Variant {
            label: "face overlay background",
            vs: "vs_background",
            fs: "fs_background",
            buffers: &[],
            topology: TriangleList,
            depth_write: false,
            depth_compare: Always,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
            mesh_triangles: false,
            fs_constants: &[],
        }),
        depth_prepass: make(Variant {
            label: "face depth pre-pass",
            vs: "vs_mesh",
            fs: "fs_depth_only",
            buffers: &corners,
            topology: TriangleList,
            depth_write: true,
            depth_compare: LessEqual,
            blend: None,
            write_mask: wgpu::ColorWrites::empty(),
            mesh_triangles: true,
            fs_constants: &[],
        }),
        // LessEqual so that after the pre-pass exactly the front-most surface passes.
        mesh: make(mesh_variant("face mesh", &[])),
        mesh_shaded: make(mesh_variant("face mesh (shaded)", &shaded)),
        mesh_shaded_corrected: make(mesh_variant(
            "face mesh (shaded, corrected albedo)",
            &shaded_corrected,
        )),
        lines: make(Variant {
            label: "face wireframe",
            vs: "vs_line",
            fs: "fs_line",
            buffers: &corners,
            topology: LineList,
            depth_write: false,
            depth_compare: LessEqual,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
            mesh_triangles: false,
            fs_constants: &[],
        }),
        // Landmarks are drawn on top of everything, occluded or not.
        landmarks: make(Variant {
            label: "face landmarks",
            vs: "vs_landmark",
            fs: "fs_landmark",
            buffers: &landmarks,
            topology: TriangleList,
            depth_write: false,
            depth_compare: Always,
            blend: None,
            write_mask: wgpu::ColorWrites::ALL,
            mesh_triangles: false,
            fs_constants: &[],
        }),
    }
}

/// Fills a whole `Rgba32Float` texture (the data and blended geometry textures) with
/// `texels`, row-major, one `[f32; 4]` per texel.
fn write_rgba32f(queue: &wgpu::Queue, texture: &wgpu::Texture, texels: &[[f32; 4]]) {
    let size = texture.size();
    queue.write_texture(
        texture.as_image_copy(),
        bytemuck::cast_slice(texels),
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(size.width * 16),
            rows_per_image: Some(size.height),
        },
        size,
    );
}

fn create_albedo_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    albedo: &TextureLayers,
) -> wgpu::Texture {
    let mip_level_count = 32 - albedo.width.max(albedo.height).leading_zeros();
    let texture = device.create_texture(&wgpu::TextureDescriptor {
        label: Some("face albedo"),
        size: wgpu::Extent3d {
            width: albedo.width,
            height: albedo.height,
            depth_or_array_layers: albedo_texture_layers(albedo),
        },
        mip_level_count,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format: wgpu::TextureFormat::Rgba8Unorm,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    });
    write_albedo(queue, &texture, albedo);
    texture
}

/// Array layers of the albedo texture: one per albedo layer, plus an unused one when the
/// texture is square and the count a multiple of six. On OpenGL (WebGL2 in browsers) wgpu
/// must choose a texture's binding target when it creates it, and takes such a texture for
/// a cube map; sampled as a 2D array it then reads black.
fn albedo_texture_layers(albedo: &TextureLayers) -> u32 {
    let layers = albedo.layers.len() as u32;
    if albedo.width == albedo.height && layers > 0 && layers.is_multiple_of(6) {
        layers + 1
    } else {
        layers
    }
}

fn write_albedo(queue: &wgpu::Queue, texture: &wgpu::Texture, albedo: &TextureLayers) {
    for (layer, texels) in albedo.layers.iter().enumerate() {
        let size = (albedo.width, albedo.height);
        write_albedo_layer(queue, texture, size, layer as u32, texels);
    }
}

/// Writes `texels` (`width` x `height`) and their mip chain to array layer `layer`.
fn write_albedo_layer(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    (width, height): (u32, u32),
    layer: u32,
    texels: &[[u8; 4]],
) {
    for (level, (w, h, data)) in mip_chain(width, height, texels).into_iter().enumerate() {
        queue.write_texture(
            wgpu::TexelCopyTextureInfo {
                texture,
                mip_level: level as u32,
                origin: wgpu::Origin3d {
                    x: 0,
                    y: 0,
                    z: layer,
                },
                aspect: wgpu::TextureAspect::All,
            },
            bytemuck::cast_slice(&data),
            wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(w * 4),
                rows_per_image: Some(h),
            },
            wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
        );
    }
}

fn create_2d(
    device: &wgpu::Device,
    label: &str,
    format: wgpu::TextureFormat,
    w: u32,
    h: u32,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::TEXTURE_BINDING | wgpu::TextureUsages::COPY_DST,
        view_formats: &[],
    })
}

fn write_2d(
    queue: &wgpu::Queue,
    texture: &wgpu::Texture,
    data: &[u8],
    bytes_per_texel: u32,
    w: u32,
    h: u32,
) {
    queue.write_texture(
        texture.as_image_copy(),
        data,
        wgpu::TexelCopyBufferLayout {
            offset: 0,
            bytes_per_row: Some(w * bytes_per_texel),
            rows_per_image: Some(h),
        },
        wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        },
    );
}

fn write_r32f(queue: &wgpu::Queue, texture: &wgpu::Texture, data: &[f32], w: u32, h: u32) {
    write_2d(queue, texture, bytemuck::cast_slice(data), 4, w, h);
}

fn write_r8(queue: &wgpu::Queue, texture: &wgpu::Texture, data: &[u8], w: u32, h: u32) {
    write_2d(queue, texture, data, 1, w, h);
}

fn write_rgba(queue: &wgpu::Queue, texture: &wgpu::Texture, data: &[u8], w: u32, h: u32) {
    write_2d(queue, texture, data, 4, w, h);
}

fn create_mask_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    data: &[u8],
    w: u32,
    h: u32,
) -> wgpu::Texture {
    let t = create_2d(device, "face uv mask", wgpu::TextureFormat::R8Unorm, w, h);
    write_r8(queue, &t, data, w, h);
    t
}

fn create_correction_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    data: &[[u16; 4]],
    w: u32,
    h: u32,
) -> wgpu::Texture {
    let t = create_2d(
        device,
        "face albedo correction",
        wgpu::TextureFormat::Rgba16Float,
        w,
        h,
    );
    write_2d(queue, &t, bytemuck::cast_slice(data), 8, w, h);
    t
}

fn create_rgba_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    label: &str,
    data: &[u8],
    w: u32,
    h: u32,
) -> wgpu::Texture {
    let t = create_2d(device, label, wgpu::TextureFormat::Rgba8Unorm, w, h);
    write_rgba(queue, &t, data, w, h);
    t
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layers(width: u32, height: u32, count: usize) -> TextureLayers {
        TextureLayers {
            width,
            height,
            layers: vec![vec![[0; 4]; (width * height) as usize]; count],
        }
    }

    #[test]
    fn square_albedo_textures_never_have_a_multiple_of_six_layers() {
        // Six or twelve square layers would be a cube map (array) on OpenGL.
        assert_eq!(albedo_texture_layers(&layers(8, 8, 6)), 7);
        assert_eq!(albedo_texture_layers(&layers(8, 8, 12)), 13);
        assert_eq!(albedo_texture_layers(&layers(8, 8, 5)), 5);
        assert_eq!(albedo_texture_layers(&layers(8, 8, 7)), 7);
        // Not square: never a cube.
        assert_eq!(albedo_texture_layers(&layers(8, 4, 6)), 6);
        assert_eq!(albedo_texture_layers(&layers(8, 8, 0)), 0);
    }
}
