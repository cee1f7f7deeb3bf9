//! Synthetic meshes and textures for tests and benchmarks (here and in other crates), so
//! that renderer tests do not depend on the face model's data files.

use crate::{MeshData, RenderVertex, TextureLayers};
use glam::Vec3;
use std::collections::HashMap;

/// A unit UV sphere (y up, longitude 0 facing +z) with `shapes` blendshapes and two albedo
/// layers: corners on the +x half (longitude 0..pi) use layer 0, the rest layer 1, each with
/// its own `[0,1]^2` tile (v = 1 at the north pole), so seams duplicate corners.
///
/// Blendshape 0 bulges the top (y > 0.4) outwards; blendshape 1 moves a patch on the
/// front-right outwards and sideways; further shapes are smooth bumps spread over the sphere.
/// Normal deltas are the exact difference of recomputed vertex normals. About
/// `(rings - 1) * segments + 2` vertices; `segments` is rounded up to even, `rings >= 2`.
pub fn uv_sphere(rings: u32, segments: u32, shapes: usize) -> MeshData {
    let rings = rings.max(2);
    let segments = (segments.max(4) + 1) & !1;
    let half = segments / 2;
    // Vertex ids: north pole, interior rings (i = 1..rings-1) x segments, south pole.
    let vid = |i: u32, j: u32| -> u32 {
        if i == 0 {
            0
        } else if i == rings {
            1 + (rings - 1) * segments
        } else {
            1 + (i - 1) * segments + j % segments
        }
    };
    let v_count = (2 + (rings - 1) * segments) as usize;
    let mut base = vec![Vec3::ZERO; v_count];
    for i in 0..=rings {
        for j in 0..segments {
            let theta = std::f32::consts::PI * i as f32 / rings as f32;
            let phi = std::f32::consts::TAU * j as f32 / segments as f32;
            base[vid(i, j) as usize] = Vec3::new(
                theta.sin() * phi.sin(),
                theta.cos(),
                theta.sin() * phi.cos(),
            );
        }
    }

    let mut corners = Vec::new();
    let mut corner_ids: HashMap<(u32, u32, [u32; 2]), u32> = HashMap::new();
    let mut corner = |i: u32, j: u32, layer: u32, u_mid: Option<f32>| -> u32 {
        let v = vid(i, j);
        let u = u_mid.unwrap_or(j as f32);
        let uv = [
            (u - (layer * half) as f32) / half as f32,
            1.0 - i as f32 / rings as f32,
        ];
        *corner_ids
            .entry((v, layer, uv.map(f32::to_bits)))
            .or_insert_with(|| {
                corners.push(RenderVertex {
                    vertex: v,
                    layer,
                    uv,
                });
                corners.len() as u32 - 1
            })
    };
    let mut indices = Vec::new();
    let mut triangles = Vec::new(); // in mesh-vertex ids, for normals
    for i in 0..rings {
        for j in 0..segments {
            let layer = if j < half { 0 } else { 1 };
            // Pole corners take the cell's mid longitude so the texture does not swirl.
            let mid = Some(j as f32 + 0.5);
            let a = (i, j, if i == 0 { mid } else { None });
            let b = (i + 1, j, if i + 1 == rings { mid } else { None });
            let c = (i + 1, j + 1, if i + 1 == rings { mid } else { None });
            let d = (i, j + 1, if i == 0 { mid } else { None });
            // Counter-clockwise seen from outside.
            let tris: &[[(u32, u32, Option<f32>); 3]] = if i == 0 {
                &[[a, b, c]]
            } else if i + 1 == rings {
                &[[a, b, d]]
            } else {
                &[[a, b, c], [a, c, d]]
            };
            for tri in tris {
                let mut vs = [0; 3];
                for (k, &(ci, cj, cu)) in tri.iter().enumerate() {
                    indices.push(corner(ci, cj, layer, cu));
                    vs[k] = vid(ci, cj);
                }
                triangles.push(vs);
            }
        }
    }

    let base_normals = vertex_normals(&base, &triangles);
    let mut blend_deltas = Vec::with_capacity(shapes * v_count);
    let mut normal_deltas = Vec::with_capacity(shapes * v_count);
    for k in 0..shapes {
        let deltas: Vec<Vec3> = base.iter().map(|&p| shape_delta(k, p)).collect();
        let moved: Vec<Vec3> = base.iter().zip(&deltas).map(|(p, d)| *p + *d).collect();
        let normals = vertex_normals(&moved, &triangles);
        blend_deltas.extend(deltas.iter().map(|d| d.to_array()));
        normal_deltas.extend(
            normals
                .iter()
                .zip(&base_normals)
                .map(|(n, b)| (*n - *b).to_array()),
        );
    }

    // Landmarks: a few points spread over the front, like facial landmarks.
    let landmark_vertices = [
        (-0.5, 0.3),
        (0.0, 0.35),
        (0.5, 0.3),
        (-0.6, -0.1),
        (0.0, 0.0),
        (0.6, -0.1),
        (-0.4, -0.5),
        (0.0, -0.55),
        (0.4, -0.5),
    ]
    .iter()
    .map(|&(x, y): &(f32, f32)| {
        let z = (1.0 - x * x - y * y).max(0.0).sqrt();
        nearest_vertex(&base, Vec3::new(x, y, z))
    })
    .collect();

    MeshData {
        base_positions: base.iter().map(|p| p.to_array()).collect(),
        base_normals: base_normals.iter().map(|n| n.to_array()).collect(),
        blend_deltas,
        normal_deltas,
        corners,
        indices,
        landmark_vertices,
        eyes: None,
    }
}

fn nearest_vertex(positions: &[Vec3], target: Vec3) -> u32 {
    let mut best = (f32::INFINITY, 0);
    for (i, p) in positions.iter().enumerate() {
        let d = p.distance_squared(target);
        if d < best.0 {
            best = (d, i as u32);
        }
    }
    best.1
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Position delta of synthetic blendshape `k` at unit-sphere point `p`.
fn shape_delta(k: usize, p: Vec3) -> Vec3 {
    match k {
        0 => p * 0.45 * smoothstep(0.4, 1.0, p.y),
        1 => {
            let centre = Vec3::new(0.5, -0.2, 0.85).normalize();
            let w = (-(p - centre).length_squared() / (0.35f32 * 0.35)).exp();
            (p * 0.25 + Vec3::new(0.2, 0.1, 0.0)) * w
        }
        _ => {
            // Fibonacci-sphere centres, alternating in/out, small radius: like local
            // expression shapes of a face.
            let n = 64.0;
            let t = (k - 2) as f32 + 0.5;
            let y = 1.0 - 2.0 * t / n;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let phi = t * 2.399_963;
            let centre = Vec3::new(r * phi.sin(), y, r * phi.cos());
            let w = (-(p - centre).length_squared() / (0.3f32 * 0.3)).exp();
            let sign = if k.is_multiple_of(2) { 1.0 } else { -1.0 };
            p * (0.15 * sign * w)
        }
    }
}

/// Area-weighted vertex normals: the face crate's definition.
pub use face::geometry::vertex_normals;

/// Two checkerboard layers of `size x size` with `checks` squares per side: layer 0 warm,
/// layer 1 cool. Layer 0 has a yellow band along its top quarter of rows (the tile's v = 1
/// edge, around the sphere's north pole), so a flipped v shows up immediately.
pub fn checker_albedo(size: u32, checks: u32) -> TextureLayers {
    let size = size.max(1);
    let cell = (size / checks.max(1)).max(1);
    let palettes = [
        [[232, 196, 168, 255], [176, 112, 92, 255]],
        [[150, 190, 226, 255], [62, 92, 146, 255]],
    ];
    let layers = palettes
        .iter()
        .enumerate()
        .map(|(l, pal)| {
            let mut texels = Vec::with_capacity((size * size) as usize);
            for y in 0..size {
                for x in 0..size {
                    let band = l == 0 && y < size / 4;
                    texels.push(if band {
                        [240, 220, 40, 255]
                    } else {
                        pal[((x / cell + y / cell) % 2) as usize]
                    });
                }
            }
            texels
        })
        .collect();
    TextureLayers {
        width: size,
        height: size,
        layers,
    }
}
