//! The personalized rig as GLB: the person's mesh (S_0 + F(dS_0)) whose 52 morph targets
//! are their personalized blendshapes (S_i - S_0 + F(A_i dS_i)) under ARKit names, with the
//! static albedo as base colour and the dynamic albedo maps as extra images.
//!
//! Layout of the file (documented for artists and tools):
//! - one node `Head` with one mesh `likeness_person`; one primitive per albedo tile of the
//!   template (face, head, gums and tongue, teeth, eyeballs; the eyelash cards are left
//!   out), each with its own material `likeness_<tile>` and base colour texture;
//! - positions in metres (the template's centimetres / 100), +y up, facing +z;
//! - 52 morph targets named as ARKit's (`mesh.extras.targetNames`), position deltas only;
//!   ICT's split `browInnerUp` and `cheekPuff` halves are summed into ARKit's symmetric
//!   shapes, and `tongueOut` (not in the template) is an all-zero target so that every ARKit
//!   rig convention finds its 52 names;
//! - the dynamic albedo A_i dR_i of each ARKit shape (split halves summed) as a 128 x 128
//!   PNG image named `dynamic_albedo_<arkitName>`, encoded `rgb = 0.5 + dR / (2 x 0.25)`
//!   (so dR in [-0.25, 0.25]); the root's `extras.likeness.dynamic_albedo` maps each ARKit
//!   name to its image index and states the encoding. These images are in the face tile's
//!   UV layout; glTF has no standard way to blend textures with morph weights, so viewers
//!   ignore them and Likeness's renderer applies them.

use std::io::Cursor;
use std::path::Path;

use face::albedo::{AlbedoLayer, MeanAlbedo, triangle_layer};
use face::names::{ARKIT_NAMES, NUM_ARKIT, arkit_sources};
use face::uv::UvMap;
use face::{PersonalizedBlendshapes, Template};
use glam::Vec3;
use serde_json::{Value, json};

use crate::error::{Result, RetargetError};
use crate::glb::{ARRAY_BUFFER, GlbBuilder};

/// Range of the dynamic albedo encoding: `rgb = 0.5 + dR / (2 x range)`.
pub const DYNAMIC_ALBEDO_RANGE: f32 = 0.25;
/// Tiles the rig draws (the eyelash cards need alpha and are left out).
pub const RIG_LAYERS: [AlbedoLayer; 5] = [
    AlbedoLayer::Face,
    AlbedoLayer::Head,
    AlbedoLayer::GumsTongue,
    AlbedoLayer::Teeth,
    AlbedoLayer::Eyeball,
];

/// Everything the rig needs, in the face crate's terms.
pub struct PersonalizedRig<'a> {
    pub template: &'a Template,
    pub blendshapes: &'a PersonalizedBlendshapes,
    /// Static albedo per tile in [`AlbedoLayer::ALL`] order: the face tile is R_0^t + dR_0
    /// (equation (3) with w = 0), the others R_0.
    pub static_albedo: Vec<UvMap>,
    /// A_i dR_i for the 53 ICT shapes (128 x 128 x 3).
    pub dynamic_albedo: Vec<UvMap>,
}

impl<'a> PersonalizedRig<'a> {
    /// From a face model and a person's corrections: `mean_face` is the trained R_0^t (or
    /// R_0 when none was trained).
    pub fn new(
        model: &'a face::FaceModel,
        blendshapes: &'a PersonalizedBlendshapes,
        corrections: &face::PersonalCorrections,
        mean: &MeanAlbedo,
        mean_face: &UvMap,
    ) -> Result<Self> {
        let neutral = face::BlendshapeWeights([0.0; face::NUM_BLENDSHAPES]);
        let face_albedo = model.albedo(mean_face, corrections, &neutral)?;
        let mut static_albedo = mean.layers.clone();
        static_albedo[AlbedoLayer::Face.index()] = face_albedo;
        let dynamic_albedo = (0..face::NUM_BLENDSHAPES)
            .map(|i| {
                let mask = model.masks.mask(i);
                let d = &corrections.dynamic_albedo[i];
                let mut out = d.clone();
                for (t, px) in out.data.chunks_exact_mut(3).enumerate() {
                    for v in px {
                        *v *= mask.data[t];
                    }
                }
                out
            })
            .collect();
        Ok(Self {
            template: &model.template,
            blendshapes,
            static_albedo,
            dynamic_albedo,
        })
    }
}

fn png(map: &UvMap, encode: impl Fn(f32) -> f32) -> std::result::Result<Vec<u8>, String> {
    // UvMap rows start at v = 1 (face::uv), which is glTF's top row: no flip.
    let mut img = image::RgbImage::new(map.width as u32, map.height as u32);
    for y in 0..map.height {
        for x in 0..map.width {
            let t = map.texel(x, y);
            let c = |k: usize| {
                (encode(t[k.min(map.channels - 1)]).clamp(0.0, 1.0) * 255.0).round() as u8
            };
            img.put_pixel(x as u32, y as u32, image::Rgb([c(0), c(1), c(2)]));
        }
    }
    let mut bytes = Vec::new();
    img.write_to(&mut Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| e.to_string())?;
    Ok(bytes)
}

/// Writes the rig; the file is replaced atomically.
pub fn write_rig_glb(rig: &PersonalizedRig, out: &Path) -> Result<()> {
    Ok(files::write_atomically(out, &rig_glb_bytes(rig, out)?)?)
}

/// [`write_rig_glb`]'s file as bytes (a download in the browser); `out` names it in
/// messages.
pub fn rig_glb_bytes(rig: &PersonalizedRig, out: &Path) -> Result<Vec<u8>> {
    let err = |reason: String| RetargetError::Write {
        path: out.to_owned(),
        reason,
    };
    let t = rig.template;
    let v_count = t.vertex_count();
    let b = rig.blendshapes;
    if b.vertex_count != v_count
        || b.base.len() != v_count
        || b.deltas.len() != v_count * face::NUM_BLENDSHAPES
    {
        return Err(err(format!(
            "the blendshapes have {} vertices, the template {v_count}",
            b.vertex_count
        )));
    }
    if rig.static_albedo.len() != AlbedoLayer::ALL.len()
        || rig.dynamic_albedo.len() != face::NUM_BLENDSHAPES
    {
        return Err(err(
            "expected one static albedo per tile and 53 dynamic albedo maps".into(),
        ));
    }
    if b.base.iter().chain(&b.deltas).any(|p| !p.is_finite()) {
        return Err(err(
            "the personalized blendshapes contain NaN or infinite positions".into(),
        ));
    }
    // ARKit deltas: the sum of their ICT sources (split halves summed, tongueOut zero).
    let arkit_delta = |a: usize, v: usize| -> Vec3 {
        arkit_sources(a)
            .iter()
            .map(|&i| b.deltas[i * v_count + v])
            .sum()
    };
    let normals = face::geometry::vertex_normals(&b.base, &t.triangles);

    let mut doc = GlbBuilder::new(
        json!({"asset": {"version": "2.0", "generator": concat!("Likeness ", env!("CARGO_PKG_VERSION"))}}),
        Vec::new(),
    );
    let mut primitives = Vec::new();
    for layer in RIG_LAYERS {
        // Corners are (vertex, uv) pairs: the same vertex has different UVs across seams.
        let mut corner_index = std::collections::HashMap::<(u32, u32), u32>::new();
        let mut corners: Vec<(u32, u32)> = Vec::new();
        let mut indices = Vec::new();
        for (tri, (verts, uvs)) in t.triangles.iter().zip(&t.triangle_uvs).enumerate() {
            if triangle_layer(t, tri) != Some(layer) {
                continue;
            }
            for k in 0..3 {
                let key = (verts[k], uvs[k]);
                let next = corners.len() as u32;
                let idx = *corner_index.entry(key).or_insert_with(|| {
                    corners.push(key);
                    next
                });
                indices.push(idx);
            }
        }
        if indices.is_empty() {
            continue;
        }
        let positions: Vec<f32> = corners
            .iter()
            .flat_map(|&(v, _)| (b.base[v as usize] * 0.01).to_array())
            .collect();
        let normal_values: Vec<f32> = corners
            .iter()
            .flat_map(|&(v, _)| normals[v as usize].to_array())
            .collect();
        let uv_values: Vec<f32> = corners
            .iter()
            .flat_map(|&(_, u)| {
                let uv = t.uvs[u as usize];
                [uv.x - layer.uv_offset(), 1.0 - uv.y]
            })
            .collect();
        let position = doc.float_accessor(&positions, "VEC3", Some(ARRAY_BUFFER), true);
        let normal = doc.float_accessor(&normal_values, "VEC3", Some(ARRAY_BUFFER), false);
        let texcoord = doc.float_accessor(&uv_values, "VEC2", Some(ARRAY_BUFFER), false);
        let index = doc.index_accessor(&indices);
        let targets: Vec<Value> = (0..NUM_ARKIT)
            .map(|a| {
                let d: Vec<f32> = corners
                    .iter()
                    .flat_map(|&(v, _)| (arkit_delta(a, v as usize) * 0.01).to_array())
                    .collect();
                json!({"POSITION": doc.float_accessor(&d, "VEC3", Some(ARRAY_BUFFER), true)})
            })
            .collect();
        let albedo = png(&rig.static_albedo[layer.index()], |v| v).map_err(err)?;
        let image = doc.image(
            &format!("static_albedo_{}", layer.name()),
            &albedo,
            "image/png",
        );
        let sampler = doc.push(
            "samplers",
            json!({"magFilter": 9729, "minFilter": 9987, "wrapS": 33071, "wrapT": 33071}),
        );
        let texture = doc.push("textures", json!({"source": image, "sampler": sampler}));
        let material = doc.push(
            "materials",
            json!({"name": format!("likeness_{}", layer.name()), "pbrMetallicRoughness": {"baseColorTexture": {"index": texture}, "metallicFactor": 0.0, "roughnessFactor": 0.6}}),
        );
        primitives.push(json!({"attributes": {"POSITION": position, "NORMAL": normal, "TEXCOORD_0": texcoord}, "indices": index, "material": material, "targets": targets}));
    }
    let mut dynamic = serde_json::Map::new();
    for (a, name) in ARKIT_NAMES.iter().enumerate() {
        let sources = arkit_sources(a);
        if sources.is_empty() {
            continue;
        }
        let mut sum = rig.dynamic_albedo[sources[0]].clone();
        for &i in &sources[1..] {
            for (s, d) in sum.data.iter_mut().zip(&rig.dynamic_albedo[i].data) {
                *s += d;
            }
        }
        let encoded = png(&sum, |d| 0.5 + d / (2.0 * DYNAMIC_ALBEDO_RANGE)).map_err(err)?;
        let image = doc.image(&format!("dynamic_albedo_{name}"), &encoded, "image/png");
        dynamic.insert((*name).to_owned(), json!(image));
    }
    let mesh = doc.push("meshes", json!({"name": "likeness_person", "primitives": primitives, "weights": vec![0.0; NUM_ARKIT], "extras": {"targetNames": ARKIT_NAMES.to_vec()}}));
    let node = doc.push("nodes", json!({"name": "Head", "mesh": mesh}));
    doc.json["scenes"] = json!([{"nodes": [node]}]);
    doc.json["scene"] = json!(0);
    doc.json["extras"] = json!({"likeness": {"dynamic_albedo": {
        "images": dynamic,
        "encoding": format!("rgb = 0.5 + dR / (2 x {DYNAMIC_ALBEDO_RANGE}); A_i dR_i in the face tile's UV layout, added to the base colour with the shape's weight"),
        "size": rig.dynamic_albedo.first().map_or(0, |m| m.width),
    }}});
    doc.finish().map_err(err)
}

/// Decodes one dynamic albedo texel back to dR (for readers and tests).
pub fn decode_dynamic_albedo(byte: u8) -> f32 {
    (f32::from(byte) / 255.0 - 0.5) * 2.0 * DYNAMIC_ALBEDO_RANGE
}
