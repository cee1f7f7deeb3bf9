//! The studio's scene: the face model loaded once and turned into what the GPU draws, plus
//! the camera and view choices shared by the window and the headless screenshot path.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Context, Result, bail};
use face::albedo::{AlbedoLayer, MeanAlbedo, triangle_layer};
use face::camera::{HeadPose, Intrinsics};
use face::geometry::vertex_normals;
use face::{
    BlendshapeWeights, FaceModel, ICT_NAMES, NUM_BLENDSHAPES, PersonalizedBlendshapes, Template,
};
use glam::Vec3;
use renderer::{Camera, FrameParams, MeshData, RenderVertex, TextureLayers, ViewMode};

/// Everything loaded or derived once per template.
pub struct Scene {
    pub model: FaceModel,
    pub person: PersonalizedBlendshapes,
    pub albedo: MeanAlbedo,
    pub mesh: MeshData,
    pub textures: TextureLayers,
    /// The networks as fetched bytes (the browser, which has no files); `None` natively,
    /// where trackers load them from `assets/models` and the OpenSeeFace folder.
    pub networks: Option<std::sync::Arc<tracking::bundle::NetworkBytes>>,
}

impl Scene {
    /// Loads the template (CLI path, `$LIKENESS_FACEMODEL` or the default beside the
    /// repository) and prepares the template person (no corrections yet).
    pub fn load(facemodel: Option<&Path>) -> Result<Self> {
        let path = face::template::resolve_template_path(facemodel);
        let template = Template::load(&path)?;
        tracing::info!(path = %path.display(), vertices = template.vertex_count(), "template loaded");
        Ok(Self::from_template(template))
    }

    /// The scene of a template already read (the browser fetches its bytes).
    pub fn from_template(template: Template) -> Self {
        let model = FaceModel::new(template);
        let person = model.template_blendshapes();
        let albedo = MeanAlbedo::generate(&model.template);
        let mesh = mesh_data(&model.template, &person);
        let textures = texture_layers(&albedo);
        Self {
            model,
            person,
            albedo,
            mesh,
            textures,
            networks: None,
        }
    }

    /// The attention mask A_i as the renderer's UV mask input (rows top-first).
    pub fn mask(&self, i: usize) -> (&[f32], u32, u32) {
        let m = self.model.masks.mask(i);
        (&m.data, m.width as u32, m.height as u32)
    }
}

/// Builds the GPU mesh for a person's blendshapes: one render vertex per distinct
/// (vertex, texture coordinate, albedo layer) so UV seams keep their own texture
/// coordinates while sharing the blended position.
pub fn mesh_data(template: &Template, person: &PersonalizedBlendshapes) -> MeshData {
    // Eyelashes are cards meant for alpha coverage; drawn opaque they read as thick black
    // bands around the eyes, and the lash line is painted on the lids instead.
    let drawn: Vec<usize> = (0..template.triangles.len())
        .filter(|&t| triangle_layer(template, t).is_some_and(|l| l != AlbedoLayer::Eyelashes))
        .collect();
    let drawn_triangles: Vec<[u32; 3]> = drawn.iter().map(|&t| template.triangles[t]).collect();
    let base_normals = vertex_normals(&person.base, &drawn_triangles);
    let v = person.vertex_count;
    let mut normal_deltas = Vec::with_capacity(NUM_BLENDSHAPES * v);
    let mut shape = vec![Vec3::ZERO; v];
    for i in 0..NUM_BLENDSHAPES {
        for (s, (b, d)) in shape
            .iter_mut()
            .zip(person.base.iter().zip(person.delta(i)))
        {
            *s = *b + *d;
        }
        let normals = vertex_normals(&shape, &drawn_triangles);
        normal_deltas.extend(
            normals
                .iter()
                .zip(&base_normals)
                .map(|(n, b)| (*n - *b).to_array()),
        );
    }
    let mut corner_index: HashMap<(u32, u32, u32), u32> = HashMap::new();
    let mut corners = Vec::new();
    let mut indices = Vec::with_capacity(drawn.len() * 3);
    for &t in &drawn {
        let Some(layer) = triangle_layer(template, t) else {
            continue;
        };
        for k in 0..3 {
            let vertex = template.triangles[t][k];
            let uv_index = template.triangle_uvs[t][k];
            let key = (vertex, uv_index, layer.index() as u32);
            let id = *corner_index.entry(key).or_insert_with(|| {
                let uv = template.uvs[uv_index as usize];
                corners.push(RenderVertex {
                    vertex,
                    layer: layer.index() as u32,
                    uv: [uv.x - layer.uv_offset(), uv.y],
                });
                (corners.len() - 1) as u32
            });
            indices.push(id);
        }
    }
    MeshData {
        base_positions: person.base.iter().map(|p| p.to_array()).collect(),
        base_normals: base_normals.iter().map(|n| n.to_array()).collect(),
        blend_deltas: person.deltas.iter().map(|d| d.to_array()).collect(),
        normal_deltas,
        corners,
        indices,
        landmark_vertices: template.landmarks_68.to_vec(),
        // The studio shows the tracked gaze: the eyeballs turn about the person's eye centres.
        eyes: face::gaze::Eyes::new(template, &person.base),
    }
}

/// The albedo layers as 8-bit RGBA for the GPU.
pub fn texture_layers(albedo: &MeanAlbedo) -> TextureLayers {
    let face = albedo.face();
    TextureLayers {
        width: face.width as u32,
        height: face.height as u32,
        layers: AlbedoLayer::ALL
            .iter()
            .map(|l| rgba8_texels(&albedo.layers[l.index()]))
            .collect(),
    }
}

/// An RGB albedo map (values in [0, 1]) as opaque 8-bit RGBA texels, row by row.
pub fn rgba8_texels(map: &face::uv::UvMap) -> Vec<[u8; 4]> {
    let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
    map.data
        .chunks_exact(3)
        .map(|c| [q(c[0]), q(c[1]), q(c[2]), 255])
        .collect()
}

/// What the 3D view shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StudioView {
    Shaded,
    Albedo,
    Normals,
    Wireframe,
    Landmarks,
    /// The attention mask A_i of blendshape i as a heatmap on the mesh.
    Mask(usize),
}

impl StudioView {
    /// Parses `shaded|albedo|normals|wireframe|landmarks|mask:NAME`.
    pub fn parse(text: &str) -> Result<Self> {
        let lower = text.trim().to_ascii_lowercase();
        Ok(match lower.as_str() {
            "shaded" => Self::Shaded,
            "albedo" => Self::Albedo,
            "normals" => Self::Normals,
            "wireframe" => Self::Wireframe,
            "landmarks" => Self::Landmarks,
            _ => {
                let Some(name) = text.trim().strip_prefix("mask:") else {
                    bail!(
                        "unknown view `{text}`: use shaded, albedo, normals, wireframe, landmarks or mask:NAME"
                    );
                };
                let indices = face::names::resolve_user_name(name)?;
                Self::Mask(indices[0])
            }
        })
    }

    pub fn label(&self) -> String {
        match self {
            Self::Shaded => "Shaded".into(),
            Self::Albedo => "Albedo".into(),
            Self::Normals => "Normals".into(),
            Self::Wireframe => "Wireframe".into(),
            Self::Landmarks => "Landmarks".into(),
            Self::Mask(i) => format!("Mask: {}", ICT_NAMES[*i]),
        }
    }

    pub fn mode(&self) -> ViewMode {
        match self {
            Self::Shaded => ViewMode::Shaded,
            Self::Albedo => ViewMode::Albedo,
            Self::Normals => ViewMode::Normals,
            Self::Wireframe => ViewMode::Wireframe,
            Self::Landmarks => ViewMode::Landmarks,
            Self::Mask(_) => ViewMode::MaskHeatmap,
        }
    }
}

/// An orbit camera around the head: the head turns in front of a fixed camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    pub yaw_deg: f32,
    pub pitch_deg: f32,
    pub distance_cm: f32,
}

impl Default for Orbit {
    fn default() -> Self {
        Self {
            yaw_deg: 0.0,
            pitch_deg: 0.0,
            distance_cm: 75.0,
        }
    }
}

/// Centre of the face region the orbit turns about (template centimetres).
const ORBIT_PIVOT: Vec3 = Vec3::new(0.0, -1.0, 4.0);
const FIELD_OF_VIEW_DEG: f32 = 24.0;

impl Orbit {
    pub fn pose(&self) -> HeadPose {
        self.pose_with_head([0.0; 3])
    }

    /// The orbit's pose after the head itself turned by `head_rotation_deg` ([yaw, pitch,
    /// roll], the tracker's convention): a tracked performance replayed in the orbit view.
    pub fn pose_with_head(&self, head_rotation_deg: [f32; 3]) -> HeadPose {
        let [yaw, pitch, roll] = head_rotation_deg;
        let pose =
            HeadPose::from_degrees(self.yaw_deg + yaw, self.pitch_deg + pitch, roll, Vec3::ZERO);
        // Rotate about the pivot, then move it in front of the camera.
        let translation = Vec3::new(0.0, 0.0, -self.distance_cm) - pose.rotation() * ORBIT_PIVOT;
        HeadPose {
            translation,
            ..pose
        }
    }

    pub fn intrinsics(&self, width: u32, height: u32) -> Intrinsics {
        // The field of view spans the shorter side so the head fits any aspect ratio.
        let focal_px = face::camera::focal_length_px(width.min(height), FIELD_OF_VIEW_DEG);
        Intrinsics::centered(width, height, focal_px)
    }

    pub fn camera(&self, width: u32, height: u32) -> Camera {
        self.camera_with_head([0.0; 3], width, height)
    }

    /// [`Orbit::camera`] for a head turned by `head_rotation_deg` (see
    /// [`Orbit::pose_with_head`]).
    pub fn camera_with_head(&self, head_rotation_deg: [f32; 3], width: u32, height: u32) -> Camera {
        let k = self.intrinsics(width, height);
        Camera {
            view_from_model: self.pose_with_head(head_rotation_deg).view_from_model(),
            clip_from_view: k.clip_from_view(1.0, 1000.0),
        }
    }
}

/// Frame parameters for a view.
pub fn frame_params(view: StudioView, orbit: &Orbit, width: u32, height: u32) -> FrameParams {
    let mut params = FrameParams::new(orbit.camera(width, height));
    params.view = view.mode();
    params.sh_coefficients = face::sh::studio_light();
    params.background = [0.11, 0.12, 0.14, 1.0];
    params
}

/// Parses `jawOpen=0.8,eyeBlinkLeft=1` (ICT or ARKit names, any case) into weights;
/// values outside [0, 1] are clamped and reported in the returned messages.
pub fn parse_weights(text: &str) -> Result<(BlendshapeWeights, Vec<String>)> {
    let mut values = [0.0f32; NUM_BLENDSHAPES];
    for item in text.split(',').map(str::trim).filter(|s| !s.is_empty()) {
        let (name, value) = item
            .split_once('=')
            .with_context(|| format!("`{item}` is not NAME=VALUE"))?;
        let value: f32 = value
            .trim()
            .parse()
            .with_context(|| format!("`{value}` (for {name}) is not a number"))?;
        for i in face::names::resolve_user_name(name)? {
            values[i] = value;
        }
    }
    let (weights, report) = BlendshapeWeights::from_slice_clamped(&values)?;
    let messages = report
        .clamped
        .iter()
        .map(|(name, v)| {
            format!(
                "weight {name}={v} is outside [0, 1]; clamped to {}",
                v.clamp(0.0, 1.0)
            )
        })
        .collect();
    Ok((weights, messages))
}

/// The scripted expression loop of the demo: weights at time `t_secs`.
pub fn demo_weights(t_secs: f64) -> [f32; NUM_BLENDSHAPES] {
    const KEYS: [&[(&str, f32)]; 6] = [
        &[],
        &[
            ("jawOpen", 0.7),
            ("browInnerUp_L", 0.6),
            ("browInnerUp_R", 0.6),
        ],
        &[
            ("mouthSmile_L", 0.9),
            ("mouthSmile_R", 0.9),
            ("cheekSquint_L", 0.5),
            ("cheekSquint_R", 0.5),
        ],
        &[("eyeBlink_L", 1.0), ("eyeBlink_R", 1.0)],
        &[
            ("mouthPucker", 0.8),
            ("browDown_L", 0.5),
            ("browDown_R", 0.5),
        ],
        &[("mouthSmile_L", 0.8), ("eyeBlink_R", 1.0), ("jawLeft", 0.4)],
    ];
    const SECONDS_PER_KEY: f64 = 1.5;
    let phase = (t_secs / SECONDS_PER_KEY).rem_euclid(KEYS.len() as f64);
    let from = phase.floor() as usize % KEYS.len();
    let to = (from + 1) % KEYS.len();
    let s = phase.fract() as f32;
    let ease = s * s * (3.0 - 2.0 * s);
    let mut w = [0.0f32; NUM_BLENDSHAPES];
    for (key, amount) in [(KEYS[from], 1.0 - ease), (KEYS[to], ease)] {
        for (name, value) in key {
            if let Some(i) = face::names::ict_index(name) {
                w[i] += amount * value;
            }
        }
    }
    w
}
