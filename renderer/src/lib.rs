//! # renderer: GPU drawing of a blendshape mesh
//!
//! Owns one thing: drawing a mesh with K blendshapes through wgpu, either offscreen
//! ([`OffscreenRenderer`], headless, e.g. Mesa lavapipe) or into a texture owned by the app
//! (for example one shown inside egui: [`FaceRenderer::render`] records passes into the
//! caller's encoder). Changing expression costs one small uniform upload
//! ([`FaceRenderer::set_weights`]) and, on the default [`BlendPath::PrePass`], one blend
//! render pass over the V mesh vertices at the next frame; frames with unchanged weights
//! skip it. Where `Rgba32Float` cannot be rendered to (WebGL2 without
//! `EXT_color_buffer_float`), [`BlendPath::PerVertex`] blends in every vertex shader
//! instead: same image, more work per frame. On a CPU adapter (lavapipe),
//! [`BlendPath::Cpu`] sums only the non-zero deltas on the CPU and uploads the pre-pass's
//! texture, and the shaded view has fragment-shader pipelines of its own, since a software
//! rasteriser pays for every branch of a general shader at every pixel.
//!
//! Gaze: a mesh may name its eyeballs ([`MeshData::eyes`]); every blend path then turns
//! them after the blend by the eyeLook weights' angles ([`face::gaze`], the mapping the
//! training data and the Live Link export use), so the studio shows where a face looks.
//!
//! It must not do anything else: no UI, no model loading, no ONNX/inference, no knowledge of
//! the face model beyond its shared SH lighting and gaze definitions. Input is plain data ([`MeshData`], [`TextureLayers`], weights); the app
//! builds it from the `face` crate. Keeping the boundary this narrow lets the renderer be
//! tested with synthetic meshes ([`synthetic`]) and reused by any crate's tests ([`golden`]).
//!
//! It must also run on WebGL2 (the web build), which shapes the design: no storage buffers
//! and no compute. All per-vertex geometry (base shape and every delta) lives in one
//! `Rgba32Float` 2D data texture read by vertex index; the weights are a compact list of
//! active `(index, weight)` pairs in a uniform buffer. The blend pre-pass is a fragment
//! shader over a full-screen triangle whose pixels are mesh vertices, the WebGL2 stand-in
//! for a compute pass.
//!
//! Cost on a software rasteriser (lavapipe) is dominated by MSAA and fragment shading once
//! blending is a pre-pass: [`RenderOptions::sample_count`] 1 is much cheaper than the
//! default 4 (see `benches/render.rs`).
//!
//! Colour is display-encoded end to end (albedo uploaded as `Rgba8Unorm`, render target
//! `Rgba8Unorm`): no sRGB conversion anywhere, so pixels match what the model predicts.

mod camera;
mod cpu_blend;
mod error;
mod eyes;
mod face_renderer;
pub mod golden;
mod mesh;
mod offscreen;
pub mod synthetic;

pub use camera::Camera;
pub use error::RenderError;
pub use face::sh::{
    directional_light as sh_directional, sh_basis, studio_light as sh_default_studio,
};
pub use face_renderer::{
    AlbedoCorrection, BlendPath, FaceRenderer, RenderOptions, blend_prepass_supported,
    msaa_sample_count,
};
pub use mesh::{MeshData, RenderVertex, TextureLayers};
pub use offscreen::{OffscreenOptions, OffscreenRenderer};

/// SH coefficients with irradiance exactly 1 in every direction (albedo shows unchanged).
pub fn sh_ambient() -> [f32; 27] {
    face::sh::constant_light(1.0)
}

/// Maximum number of blendshapes K (the size of the active-weight uniform array).
///
/// 256 pairs of `(index, weight)` take 2 KiB, well inside WebGL2's 16 KiB uniform-block limit.
pub const MAX_BLENDSHAPES: usize = 256;

/// Width of the geometry data texture in texels (rows are added as needed). 2048 is the
/// WebGL2 default maximum texture dimension, so one layout works everywhere.
pub const DATA_TEXTURE_WIDTH: u32 = 2048;

/// What the fragment shader shows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum ViewMode {
    /// Albedo times spherical-harmonics irradiance ([`FrameParams::sh_coefficients`]).
    #[default]
    Shaded,
    /// Albedo only, unlit.
    Albedo,
    /// View-space normal mapped to colour: `n * 0.5 + 0.5`.
    Normals,
    /// Flat light-grey surface with every mesh edge drawn on top.
    Wireframe,
    /// [`ViewMode::Shaded`] plus the landmark vertices as screen-space dots on top.
    Landmarks,
    /// The UV mask from [`FaceRenderer::set_uv_mask`] as a heatmap on layer 0.
    MaskHeatmap,
    /// The per-vertex scalars from [`FaceRenderer::set_vertex_scalars`] as a heatmap.
    VertexHeatmap,
}

impl ViewMode {
    /// All modes, in declaration order (handy for UI pickers and tests).
    pub const ALL: [ViewMode; 7] = [
        ViewMode::Shaded,
        ViewMode::Albedo,
        ViewMode::Normals,
        ViewMode::Wireframe,
        ViewMode::Landmarks,
        ViewMode::MaskHeatmap,
        ViewMode::VertexHeatmap,
    ];

    /// Must match the `MODE_*` constants in `face.wgsl`.
    pub(crate) fn shader_id(self) -> u32 {
        match self {
            ViewMode::Shaded => 0,
            ViewMode::Albedo => 1,
            ViewMode::Normals => 2,
            ViewMode::Wireframe => 3,
            ViewMode::Landmarks => 4,
            ViewMode::MaskHeatmap => 5,
            ViewMode::VertexHeatmap => 6,
        }
    }
}

/// Per-frame parameters of [`FaceRenderer::render`].
#[derive(Clone, Debug, PartialEq)]
pub struct FrameParams {
    pub camera: Camera,
    pub view: ViewMode,
    /// 27 SH coefficients `[r0..r8, g0..g8, b0..b8]` for the basis of [`sh_basis`].
    pub sh_coefficients: [f32; 27],
    /// Clear colour (display-encoded RGBA in 0..1).
    pub background: [f32; 4],
    /// Scalar that maps to the top of the colour map in [`ViewMode::VertexHeatmap`].
    pub heatmap_max: f32,
}

impl FrameParams {
    /// Shaded view with the default studio light and a dark grey background.
    pub fn new(camera: Camera) -> Self {
        Self {
            camera,
            view: ViewMode::Shaded,
            sh_coefficients: sh_default_studio(),
            background: [0.1, 0.1, 0.12, 1.0],
            heatmap_max: 1.0,
        }
    }
}
