//! `likeness export-fixture`: everything the Python training code must share with the Rust
//! `face` crate, written once from Rust so both sides use the same attention masks A_i,
//! sampling function F, mean albedo R_0 and parsing map T, plus reference inputs and
//! outputs of equations (2) and (3) for a parity test.
//!
//! The fixture is derived from the ICT FaceKit template, so it is written to a cache
//! folder at training time and never committed.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{Context, Result};
use face::albedo::{AlbedoLayer, MeanAlbedo, triangle_layer};
use face::parsing::ParsingMap;
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{BlendshapeWeights, FaceModel, ICT_NAMES, NUM_BLENDSHAPES, PersonalCorrections};
use safetensors::tensor::{Dtype, TensorView};

/// Version of the fixture layout; the Python loader refuses other versions.
pub const FIXTURE_VERSION: u32 = 1;
pub const FIXTURE_FILE: &str = "face_fixture.safetensors";

/// Smooth deterministic correction maps for the parity reference (any fixed values do;
/// smooth ones exercise the bilinear sampling realistically).
fn reference_map(k: f32, amplitude: f32) -> UvMap {
    UvMap::from_fn(CORRECTION_SIZE, CORRECTION_SIZE, 3, |uv| {
        vec![
            amplitude * (k * 3.1 * uv.x).sin() * (2.3 * uv.y).cos(),
            amplitude * (k * 1.7 * uv.y + 0.4).sin(),
            amplitude * (k * 2.9 * (uv.x - uv.y)).cos(),
        ]
    })
}

fn reference_corrections() -> PersonalCorrections {
    PersonalCorrections {
        identity_shape: reference_map(0.5, 0.3),
        expression_shapes: (0..NUM_BLENDSHAPES)
            .map(|i| reference_map(1.0 + i as f32 * 0.13, 0.2))
            .collect(),
        static_albedo: reference_map(0.7, 0.05),
        dynamic_albedo: (0..NUM_BLENDSHAPES)
            .map(|i| reference_map(2.0 + i as f32 * 0.07, 0.1))
            .collect(),
    }
}

fn reference_weights() -> BlendshapeWeights {
    BlendshapeWeights(std::array::from_fn(|i| {
        if i % 4 == 0 {
            0.1 + 0.8 * ((i * 37) % 11) as f32 / 11.0
        } else {
            0.0
        }
    }))
}

fn f32_bytes(values: impl IntoIterator<Item = f32>) -> Vec<u8> {
    values.into_iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn i32_bytes(values: impl IntoIterator<Item = i32>) -> Vec<u8> {
    values.into_iter().flat_map(|v| v.to_le_bytes()).collect()
}

/// Writes the fixture to `out_dir/face_fixture.safetensors` (atomically) and returns its path.
pub fn export_fixture(model: &FaceModel, out_dir: &Path) -> Result<std::path::PathBuf> {
    let t = &model.template;
    let v = t.vertex_count();
    let albedo = MeanAlbedo::generate(t);
    let parsing = ParsingMap::generate(t);
    let corrections = reference_corrections();
    let weights = reference_weights();
    let person = model.personalize(&corrections)?;
    let shape = person.shape(&weights);
    let personalized_albedo = model.albedo(albedo.face(), &corrections, &weights)?;

    let mut tensors: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = Vec::new();
    let masks = f32_bytes(
        model
            .masks
            .masks
            .iter()
            .flat_map(|m| m.data.iter().copied()),
    );
    tensors.push((
        "attention_masks",
        Dtype::F32,
        vec![NUM_BLENDSHAPES, CORRECTION_SIZE, CORRECTION_SIZE],
        masks,
    ));
    let sites = &model.sampler.sites;
    tensors.push((
        "sample_uv",
        Dtype::F32,
        vec![v, 2],
        f32_bytes(
            sites
                .iter()
                .flat_map(|s| s.map_or([0.0, 0.0], |s| [s.uv.x, s.uv.y])),
        ),
    ));
    tensors.push((
        "sample_weight",
        Dtype::F32,
        vec![v],
        f32_bytes(sites.iter().map(|s| s.map_or(0.0, |s| s.weight))),
    ));
    let layers = AlbedoLayer::ALL.len();
    let size = albedo.face().width;
    tensors.push((
        "mean_albedo",
        Dtype::F32,
        vec![layers, size, size, 3],
        f32_bytes(
            AlbedoLayer::ALL
                .iter()
                .flat_map(|l| albedo.layer(*l).data.iter().copied()),
        ),
    ));
    tensors.push((
        "parsing_map",
        Dtype::U8,
        vec![layers, parsing.size, parsing.size],
        parsing.layers.iter().flatten().copied().collect(),
    ));
    let tri_layer: Vec<i32> = (0..t.triangles.len())
        .map(|k| triangle_layer(t, k).map_or(-1, |l| l.index() as i32))
        .collect();
    tensors.push((
        "triangle_layer",
        Dtype::I32,
        vec![t.triangles.len()],
        i32_bytes(tri_layer),
    ));
    // Per-corner UV inside the corner's albedo layer tile (the UDIM offset removed).
    let corner_uv: Vec<f32> = (0..t.triangles.len())
        .flat_map(|k| {
            let offset = triangle_layer(t, k).map_or(0.0, |l| l.uv_offset());
            t.triangle_uvs[k]
                .iter()
                .flat_map(move |&u| {
                    let uv = t.uvs[u as usize];
                    [uv.x - offset, uv.y]
                })
                .collect::<Vec<_>>()
        })
        .collect();
    tensors.push((
        "triangle_corner_uv",
        Dtype::F32,
        vec![t.triangles.len(), 3, 2],
        f32_bytes(corner_uv),
    ));
    let face_tris: Vec<i32> = t.face_triangles().map(|k| k as i32).collect();
    tensors.push((
        "face_triangle_ids",
        Dtype::I32,
        vec![face_tris.len()],
        i32_bytes(face_tris),
    ));

    // Parity reference for equations (2) and (3).
    tensors.push((
        "ref_weights",
        Dtype::F32,
        vec![NUM_BLENDSHAPES],
        f32_bytes(weights.0),
    ));
    let shape_maps =
        std::iter::once(&corrections.identity_shape).chain(&corrections.expression_shapes);
    tensors.push((
        "ref_shape_corrections",
        Dtype::F32,
        vec![NUM_BLENDSHAPES + 1, CORRECTION_SIZE, CORRECTION_SIZE, 3],
        f32_bytes(shape_maps.flat_map(|m| m.data.iter().copied())),
    ));
    let albedo_maps =
        std::iter::once(&corrections.static_albedo).chain(&corrections.dynamic_albedo);
    tensors.push((
        "ref_albedo_corrections",
        Dtype::F32,
        vec![NUM_BLENDSHAPES + 1, CORRECTION_SIZE, CORRECTION_SIZE, 3],
        f32_bytes(albedo_maps.flat_map(|m| m.data.iter().copied())),
    ));
    tensors.push((
        "ref_shape",
        Dtype::F32,
        vec![v, 3],
        f32_bytes(shape.iter().flat_map(|p| p.to_array())),
    ));
    tensors.push((
        "ref_albedo",
        Dtype::F32,
        vec![size, size, 3],
        f32_bytes(personalized_albedo.data.iter().copied()),
    ));

    let metadata = serde_json::json!({
        "version": FIXTURE_VERSION,
        "blendshape_names": ICT_NAMES.to_vec(),
        "albedo_layers": AlbedoLayer::ALL.iter().map(|l| l.name()).collect::<Vec<_>>(),
        "parsing_labels": face::parsing::ParsingLabel::ALL.iter().map(|l| l.name()).collect::<Vec<_>>(),
        "correction_size": CORRECTION_SIZE,
        "mask_threshold_cm": face::masks::MASK_THRESHOLD_CM,
        "uv_convention": "row 0 at v = 1; texel (x, y) centre at u = (x + 0.5) / W, v = 1 - (y + 0.5) / H; bilinear, clamped to the edge (grid_sample align_corners=False, padding border, grid y = 1 - 2v)",
        "template": t.source.display().to_string(),
    });
    let meta = HashMap::from([("likeness_fixture".to_owned(), metadata.to_string())]);
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(n, d, s, b)| Ok(((*n).to_owned(), TensorView::new(*d, s.clone(), b)?)))
        .collect::<Result<_, safetensors::SafeTensorError>>()
        .context("building the fixture tensors")?;
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let path = out_dir.join(FIXTURE_FILE);
    let bytes = safetensors::serialize(views, Some(meta))
        .with_context(|| format!("cannot encode {}", path.display()))?;
    files::write_atomically(&path, &bytes)?;
    Ok(path)
}
