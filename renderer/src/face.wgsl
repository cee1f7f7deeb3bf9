// Blendshape face renderer.
//
// WebGL2-compatible on purpose: no storage buffers, no compute. All per-vertex geometry
// lives in one Rgba32Float data texture read with textureLoad by vertex index, and the
// active blendshape weights arrive as a compact (index, weight) list in a uniform buffer.
//
// Ways to apply the weights (BlendPath on the Rust side; the CPU path fills blended_tex
// with an upload instead of fs_blend and draws like the pre-pass):
// - pre-pass (default): fs_blend renders the blended position and normal of every mesh
//   vertex into an Rgba32Float target (blended_tex) once per weight change, and the mesh
//   vertex shaders just load them. Blending costs O(V K) per change instead of
//   O(corners K) per mesh-drawing pass per frame.
// - per-vertex (PER_VERTEX_BLEND = true): every vertex shader invocation loops over the
//   active shapes itself. Fallback for WebGL2 without EXT_color_buffer_float, where
//   Rgba32Float cannot be rendered to.

// Set per pipeline (see create_pipelines); an override so the unused path compiles away.
override PER_VERTEX_BLEND: bool = false;

// fs_mesh specialised per pipeline: MESH_MODE fixes the view mode (255: read it from the
// frame uniform), MESH_CORRECTION whether the albedo correction can apply. A software
// rasteriser (lavapipe) runs every side of a branch under a lane mask, uniform condition
// or not, so the general shader pays for every mode's colour maths and texture reads at
// every pixel; the shaded view, drawn while a clip plays, gets its own pipelines.
const MESH_MODE_FROM_FRAME: u32 = 255u;
override MESH_MODE: u32 = 255u;
override MESH_CORRECTION: bool = true;

// Must match MAX_BLENDSHAPES / 2 on the Rust side: two (index, weight) pairs per vec4.
const WEIGHT_VEC4S: u32 = 128u;

// View modes; must match ViewMode::shader_id on the Rust side.
const MODE_SHADED: u32 = 0u;
const MODE_ALBEDO: u32 = 1u;
const MODE_NORMALS: u32 = 2u;
const MODE_WIREFRAME: u32 = 3u;
const MODE_LANDMARKS: u32 = 4u;
const MODE_MASK_HEATMAP: u32 = 5u;
const MODE_VERTEX_HEATMAP: u32 = 6u;

const FLAG_HAS_MASK: u32 = 1u;
const FLAG_HAS_SCALARS: u32 = 2u;
const FLAG_HAS_CORRECTION: u32 = 4u;

struct Frame {
    view_from_model: mat4x4<f32>,
    clip_from_view: mat4x4<f32>,
    // 27 SH coefficients [r0..r8, g0..g8, b0..b8], padded to 28.
    sh: array<vec4<f32>, 7>,
    background: vec4<f32>,
    // x: view mode, y: flags, z: data texture width, w: vertex count V
    mode: vec4<u32>,
    // x: heatmap max, y: face opacity, z: viewport width px, w: viewport height px
    params: vec4<f32>,
    // x: blendshape count K, y: scalar texture width (= data texture width),
    // z: log2 of the data texture width, w: the albedo layer correction_tex is added to
    counts: vec4<u32>,
}

struct Weights {
    // x: number of active (index, weight) pairs
    count: vec4<u32>,
    // Eyeballs turned by the gaze after the blend (EyePose on the Rust side): vertices
    // [x, y) turn as the first eye, [z, w) as the second; empty for an eye that does not turn.
    eye_ranges: vec4<u32>,
    // Per eye: the three rows of its rotation, then the centre it turns about (xyz).
    eye_frames: array<vec4<f32>, 8>,
    pairs: array<vec4<f32>, WEIGHT_VEC4S>,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> weights: Weights;
@group(0) @binding(2) var data_tex: texture_2d<f32>;
@group(0) @binding(3) var scalar_tex: texture_2d<f32>;
@group(0) @binding(4) var albedo_tex: texture_2d_array<f32>;
@group(0) @binding(5) var mask_tex: texture_2d<f32>;
@group(0) @binding(6) var overlay_tex: texture_2d<f32>;
@group(0) @binding(7) var lin_sampler: sampler;
// Output of fs_blend: texel v is the blended position of vertex v, texel V + v its unit
// normal (same width as data_tex). A 1x1 dummy on the per-vertex path.
@group(0) @binding(8) var blended_tex: texture_2d<f32>;
// RGB added to the albedo of layer frame.counts.w (a person's dynamic albedo, equation 3,
// without re-uploading the whole albedo); 1x1 and unused without FLAG_HAS_CORRECTION.
@group(0) @binding(9) var correction_tex: texture_2d<f32>;

// Texel coordinates of linear index i in the data, blended and scalar textures, which share
// one power-of-two width. Shift and mask, not % and /: software rasterisers (lavapipe) run
// shaders as SIMD, which has no vector integer division, and this is in every inner loop.
fn texel_coord(i: u32) -> vec2<i32> {
    let shift = frame.counts.z;
    return vec2<i32>(i32(i & ((1u << shift) - 1u)), i32(i >> shift));
}

fn data_texel(i: u32) -> vec4<f32> {
    return textureLoad(data_tex, texel_coord(i), 0);
}

struct Blended {
    pos: vec3<f32>,
    nrm: vec3<f32>,
}

// Data texture layout (texel index): [0, V) base positions, [V, 2V) base normals,
// [(2 + k) V + v] position delta of shape k, [(2 + K + k) V + v] normal delta of shape k.
// Shape-major so that neighbouring vertices read neighbouring texels in every iteration.
//
// Sum of the base texel `base` and the active shapes' deltas at `delta0 + s V` (shape s).
// The single definition of the blend used by both paths, so they round identically.
fn blend_texels(base: u32, delta0: u32) -> vec3<f32> {
    let nv = frame.mode.w;
    var acc = data_texel(base).xyz;
    let count = weights.count.x;
    for (var i = 0u; i < count; i++) {
        let pair = weights.pairs[i / 2u];
        let iw = select(pair.xy, pair.zw, (i & 1u) == 1u);
        let s = u32(iw.x);
        acc += iw.y * data_texel(delta0 + s * nv).xyz;
    }
    return acc;
}

// Blended normals are renormalised; a degenerate sum falls back to "towards camera".
fn unit_normal(n: vec3<f32>) -> vec3<f32> {
    let len = length(n);
    return select(vec3<f32>(0.0, 0.0, 1.0), n / max(len, 1e-20), len > 1e-12);
}

// Which eye turns vertex v: 0, 1, or 2 for none.
fn eye_of(v: u32) -> u32 {
    let r = weights.eye_ranges;
    if v >= r.x && v < r.y {
        return 0u;
    }
    if v >= r.z && v < r.w {
        return 1u;
    }
    return 2u;
}

// R d for eye e, a dot product per row (EyePose::turn computes it the same way).
fn eye_turn(e: u32, d: vec3<f32>) -> vec3<f32> {
    let f = 4u * e;
    return vec3<f32>(
        dot(weights.eye_frames[f].xyz, d),
        dot(weights.eye_frames[f + 1u].xyz, d),
        dot(weights.eye_frames[f + 2u].xyz, d),
    );
}

// The blended position or unit normal of vertex v with its eyeball turned, if it is one.
fn turned(v: u32, x: vec3<f32>, is_normal: bool) -> vec3<f32> {
    let e = eye_of(v);
    if e > 1u {
        return x;
    }
    if is_normal {
        return eye_turn(e, x);
    }
    let c = weights.eye_frames[4u * e + 3u].xyz;
    return c + eye_turn(e, x - c);
}

fn blend_vertex(v: u32) -> Blended {
    let nv = frame.mode.w;
    let k_total = frame.counts.x;
    let p = blend_texels(v, 2u * nv + v);
    let n = blend_texels(nv + v, (2u + k_total) * nv + v);
    return Blended(turned(v, p, false), turned(v, unit_normal(n), true));
}

fn blended_texel(i: u32) -> vec4<f32> {
    return textureLoad(blended_tex, texel_coord(i), 0);
}

// Blended geometry of mesh vertex v on either path.
fn vertex_geometry(v: u32) -> Blended {
    if PER_VERTEX_BLEND {
        return blend_vertex(v);
    }
    return Blended(blended_texel(v).xyz, blended_texel(frame.mode.w + v).xyz);
}

fn view_normal(n: vec3<f32>) -> vec3<f32> {
    // view_from_model is a rigid transform (possibly uniformly scaled), so its upper 3x3
    // maps normals correctly up to length.
    return normalize((frame.view_from_model * vec4<f32>(n, 0.0)).xyz);
}

fn scalar_at(v: u32) -> f32 {
    return textureLoad(scalar_tex, texel_coord(v), 0).x;
}

// ---------------------------------------------------------------------------------------
// Mesh (filled triangles)

struct MeshOut {
    // Invariant so the depth pre-pass and the colour pass produce bit-identical depth.
    @invariant @builtin(position) clip: vec4<f32>,
    @location(0) normal_view: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) @interpolate(flat) layer: u32,
    @location(3) scalar: f32,
}

@vertex
fn vs_mesh(
    @location(0) vertex: u32,
    @location(1) layer: u32,
    @location(2) uv: vec2<f32>,
) -> MeshOut {
    let b = vertex_geometry(vertex);
    var out: MeshOut;
    out.clip = frame.clip_from_view * (frame.view_from_model * vec4<f32>(b.pos, 1.0));
    out.normal_view = view_normal(b.nrm);
    out.uv = uv;
    out.layer = layer;
    out.scalar = scalar_at(vertex);
    return out;
}

fn sh_irradiance(n: vec3<f32>) -> vec3<f32> {
    let pi = 3.14159265358979;
    let a0 = pi;
    let a1 = 2.0 * pi / sqrt(3.0);
    let a2 = 2.0 * pi / sqrt(8.0);
    let c0 = 1.0 / sqrt(4.0 * pi);
    let c1 = sqrt(3.0) / sqrt(4.0 * pi);
    let c2 = 3.0 * sqrt(5.0) / sqrt(12.0 * pi);
    var y: array<f32, 9>;
    y[0] = a0 * c0;
    y[1] = -a1 * c1 * n.y;
    y[2] = a1 * c1 * n.z;
    y[3] = -a1 * c1 * n.x;
    y[4] = a2 * c2 * n.x * n.y;
    y[5] = -a2 * c2 * n.y * n.z;
    y[6] = a2 * c2 * 0.5 / sqrt(3.0) * (3.0 * n.z * n.z - 1.0);
    y[7] = -a2 * c2 * n.x * n.z;
    y[8] = a2 * c2 * 0.5 * (n.x * n.x - n.y * n.y);
    var e = vec3<f32>(0.0);
    for (var k = 0u; k < 9u; k++) {
        e += y[k] * vec3<f32>(sh_coef(k), sh_coef(9u + k), sh_coef(18u + k));
    }
    return e;
}

fn sh_coef(i: u32) -> f32 {
    return frame.sh[i / 4u][i % 4u];
}

// Fixed soft light used by the diagnostic views, independent of the SH coefficients so that
// the shape stays readable even under flat ambient lighting.
fn diagnostic_shade(n: vec3<f32>) -> f32 {
    let l = normalize(vec3<f32>(-0.35, 0.45, 1.0));
    return 0.45 + 0.55 * max(dot(n, l), 0.0);
}

// Turbo colour map, polynomial approximation by Anton Mikhailov (Google, Apache-2.0).
fn turbo(x_in: f32) -> vec3<f32> {
    let x = clamp(x_in, 0.0, 1.0);
    let r4 = vec4<f32>(0.13572138, 4.61539260, -42.66032258, 132.13108234);
    let g4 = vec4<f32>(0.09140261, 2.19418839, 4.84296658, -14.18503333);
    let b4 = vec4<f32>(0.10667330, 12.64194608, -60.58204836, 110.36276771);
    let r2 = vec2<f32>(-152.94239396, 59.28637943);
    let g2 = vec2<f32>(4.27729857, 2.82956604);
    let b2 = vec2<f32>(-89.90310912, 27.34824973);
    let v4 = vec4<f32>(1.0, x, x * x, x * x * x);
    let v2 = v4.zw * v4.z;
    return clamp(
        vec3<f32>(dot(v4, r4) + dot(v2, r2), dot(v4, g4) + dot(v2, g2), dot(v4, b4) + dot(v2, b2)),
        vec3<f32>(0.0),
        vec3<f32>(1.0),
    );
}

@fragment
fn fs_mesh(in: MeshOut) -> @location(0) vec4<f32> {
    let n = normalize(in.normal_view);
    // OBJ uv has its origin bottom-left; textures are stored top row first.
    let tex_uv = vec2<f32>(in.uv.x, 1.0 - in.uv.y);
    // Sampled unconditionally: implicit-derivative sampling must stay in uniform control
    // flow. The mask and the correction have one mip level, so an explicit level 0 inside
    // the branches that use them samples the same.
    var albedo = textureSample(albedo_tex, lin_sampler, tex_uv, in.layer).rgb;
    let mode = select(frame.mode.x, MESH_MODE, MESH_MODE != MESH_MODE_FROM_FRAME);
    let flags = frame.mode.y;
    if MESH_CORRECTION && (flags & FLAG_HAS_CORRECTION) != 0u && in.layer == frame.counts.w {
        let correction = textureSampleLevel(correction_tex, lin_sampler, tex_uv, 0.0).rgb;
        albedo = clamp(albedo + correction, vec3<f32>(0.0), vec3<f32>(1.0));
    }
    var rgb: vec3<f32>;
    switch mode {
        case MODE_ALBEDO: {
            rgb = albedo;
        }
        case MODE_NORMALS: {
            rgb = n * 0.5 + 0.5;
        }
        case MODE_WIREFRAME: {
            rgb = vec3<f32>(0.82) * diagnostic_shade(n);
        }
        case MODE_MASK_HEATMAP: {
            if (flags & FLAG_HAS_MASK) != 0u && in.layer == 0u {
                let mask = textureSampleLevel(mask_tex, lin_sampler, tex_uv, 0.0).r;
                rgb = turbo(mask) * diagnostic_shade(n);
            } else {
                rgb = vec3<f32>(0.6) * diagnostic_shade(n);
            }
        }
        case MODE_VERTEX_HEATMAP: {
            if (flags & FLAG_HAS_SCALARS) != 0u {
                rgb = turbo(in.scalar / max(frame.params.x, 1e-20)) * diagnostic_shade(n);
            } else {
                rgb = vec3<f32>(0.6) * diagnostic_shade(n);
            }
        }
        default: {
            // MODE_SHADED and MODE_LANDMARKS (dots are a separate draw on top).
            rgb = albedo * max(sh_irradiance(n), vec3<f32>(0.0));
        }
    }
    return vec4<f32>(clamp(rgb, vec3<f32>(0.0), vec3<f32>(1.0)), frame.params.y);
}

// Depth pre-pass (only used when the face is blended over an overlay with opacity < 1):
// writes nothing to colour, so the colour pass then shades only the front-most surface
// and hidden layers of the mesh do not show through.
@fragment
fn fs_depth_only(in: MeshOut) -> @location(0) vec4<f32> {
    return vec4<f32>(0.0);
}

// ---------------------------------------------------------------------------------------
// Wireframe edges

struct LineOut {
    @builtin(position) clip: vec4<f32>,
}

@vertex
fn vs_line(
    @location(0) vertex: u32,
    @location(1) layer: u32,
    @location(2) uv: vec2<f32>,
) -> LineOut {
    let b = vertex_geometry(vertex);
    var view = frame.view_from_model * vec4<f32>(b.pos, 1.0);
    // Pull the line slightly towards the eye (view-space origin) so it wins the depth test
    // against its own triangles. Depth bias is not allowed for line topologies in WebGPU,
    // and a relative offset works at any distance.
    view = vec4<f32>(view.xyz * (1.0 - 1.5e-3), 1.0);
    var out: LineOut;
    out.clip = frame.clip_from_view * view;
    return out;
}

@fragment
fn fs_line() -> @location(0) vec4<f32> {
    return vec4<f32>(0.12, 0.16, 0.26, 1.0);
}

// ---------------------------------------------------------------------------------------
// Landmark dots: instanced screen-space quads centred on the blended landmark vertex.

const DOT_RADIUS_PX: f32 = 3.0;

struct DotOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) local_px: vec2<f32>,
}

@vertex
fn vs_landmark(@builtin(vertex_index) corner: u32, @location(0) vertex: u32) -> DotOut {
    var offsets = array<vec2<f32>, 6>(
        vec2<f32>(-1.0, -1.0),
        vec2<f32>(1.0, -1.0),
        vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, -1.0),
        vec2<f32>(1.0, 1.0),
        vec2<f32>(-1.0, 1.0),
    );
    let o = offsets[corner];
    let b = vertex_geometry(vertex);
    var clip = frame.clip_from_view * (frame.view_from_model * vec4<f32>(b.pos, 1.0));
    // Quad half-size slightly larger than the dot so the disk is not cut by the quad edge.
    let half_px = DOT_RADIUS_PX + 1.0;
    clip = vec4<f32>(clip.xy + o * half_px * 2.0 / frame.params.zw * clip.w, clip.zw);
    var out: DotOut;
    out.clip = clip;
    out.local_px = o * half_px;
    return out;
}

@fragment
fn fs_landmark(in: DotOut) -> @location(0) vec4<f32> {
    let d = length(in.local_px);
    if d > DOT_RADIUS_PX {
        discard;
    }
    // Bright core with a dark rim so the dot reads on both light and dark albedo.
    if d > DOT_RADIUS_PX - 0.9 {
        return vec4<f32>(0.05, 0.05, 0.05, 1.0);
    }
    return vec4<f32>(0.15, 1.0, 0.3, 1.0);
}

// ---------------------------------------------------------------------------------------
// Overlay background: one full-screen triangle.

struct BgOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) uv: vec2<f32>,
}

@vertex
fn vs_background(@builtin(vertex_index) i: u32) -> BgOut {
    // uv (0,0) is the image's top-left; the triangle covers [0,2]^2 in uv.
    let uv = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    var out: BgOut;
    out.clip = vec4<f32>(uv.x * 2.0 - 1.0, 1.0 - uv.y * 2.0, 0.5, 1.0);
    out.uv = uv;
    return out;
}

@fragment
fn fs_background(in: BgOut) -> @location(0) vec4<f32> {
    return vec4<f32>(textureSampleLevel(overlay_tex, lin_sampler, in.uv, 0.0).rgb, 1.0);
}

// ---------------------------------------------------------------------------------------
// Blend pre-pass: vs_background's full-screen triangle over the blended_tex target, one
// fragment per output texel (see blended_tex for the layout).

@fragment
fn fs_blend(in: BgOut) -> @location(0) vec4<f32> {
    let nv = frame.mode.w;
    let i = (u32(in.clip.y) << frame.counts.z) + u32(in.clip.x);
    if i >= 2u * nv {
        // Padding at the end of the last row.
        return vec4<f32>(0.0);
    }
    // Texels [0, V) blend positions, [V, 2V) normals; both are "base texel i plus the
    // deltas of the matching block", the same sums blend_vertex computes.
    let is_normal = i >= nv;
    let v = select(i, i - nv, is_normal);
    let delta_block = select(2u, 2u + frame.counts.x, is_normal);
    let acc = blend_texels(i, delta_block * nv + v);
    return vec4<f32>(turned(v, select(acc, unit_normal(acc), is_normal), is_normal), 0.0);
}
