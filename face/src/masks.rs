//! Attention masks A_i (paper, section 3.2): where blendshape i may be corrected.
//!
//! Built as the paper says: per-vertex Euclidean distance between S_i and S_0, thresholded,
//! normalised by the maximum distance, rasterised into the 128 x 128 UV space, then smoothed
//! with a small Gaussian blur. The paper's threshold is 0.001 in its template's units
//! (metres, a face about 0.2 units wide), i.e. one millimetre; the ICT model is in
//! centimetres, so the threshold here is [`MASK_THRESHOLD_CM`] = 0.1 cm, the same
//! physical distance.

use crate::names::NUM_BLENDSHAPES;
use crate::template::Template;
use crate::uv::{CORRECTION_SIZE, UvMap, gaussian_blur, rasterize_uv_triangle};

/// One millimetre, the paper's 0.001 m threshold in the template's centimetres.
pub const MASK_THRESHOLD_CM: f32 = 0.1;
/// Standard deviation of the smoothing blur, in texels of the 128 x 128 map.
pub const MASK_BLUR_SIGMA_TEXELS: f32 = 1.0;
/// Texels the rasterised mask is grown into uncovered space before the blur, so that the
/// blur does not pull values at chart borders towards the empty background.
const EDGE_PADDING_TEXELS: usize = 2;

/// Per-vertex attention of blendshape `i` before rasterisation: |S_i - S_0| / max over the
/// face part, or 0 where the distance is at most the threshold. Values are in [0, 1].
pub fn vertex_attention(template: &Template, i: usize) -> Vec<f32> {
    let delta = template.expression_delta(i);
    let face = template.face_vertices();
    let max = delta[face.start as usize..face.end as usize]
        .iter()
        .map(|d| d.length())
        .fold(0.0f32, f32::max);
    delta
        .iter()
        .map(|d| {
            let dist = d.length();
            if dist > MASK_THRESHOLD_CM && max > 0.0 {
                (dist / max).min(1.0)
            } else {
                0.0
            }
        })
        .collect()
}

/// The 53 attention masks A_i as 1-channel UV maps, precomputed once per template.
#[derive(Clone, Debug)]
pub struct AttentionMasks {
    pub size: usize,
    pub masks: Vec<UvMap>,
}

impl AttentionMasks {
    /// Builds all masks at the paper's 128 x 128.
    pub fn build(template: &Template) -> Self {
        Self::build_with_size(template, CORRECTION_SIZE)
    }

    pub fn build_with_size(template: &Template, size: usize) -> Self {
        let face_tris: Vec<usize> = template.face_triangles().collect();
        let coverage = coverage_map(template, &face_tris, size);
        let masks = (0..NUM_BLENDSHAPES)
            .map(|i| {
                let attention = vertex_attention(template, i);
                let mut map = UvMap::zeros(size, size, 1);
                for &t in &face_tris {
                    let corners = template.triangles[t].map(|v| attention[v as usize]);
                    if corners.iter().all(|&a| a == 0.0) {
                        continue;
                    }
                    let uv = template.triangle_uvs[t].map(|k| template.uvs[k as usize]);
                    rasterize_uv_triangle(uv, size, size, |x, y, b| {
                        let value = b[0] * corners[0] + b[1] * corners[1] + b[2] * corners[2];
                        let texel = &mut map.texel_mut(x, y)[0];
                        *texel = texel.max(value);
                    });
                }
                pad_into_uncovered(&mut map, &coverage, EDGE_PADDING_TEXELS);
                let mut blurred = gaussian_blur(&map, MASK_BLUR_SIGMA_TEXELS);
                for a in &mut blurred.data {
                    *a = a.clamp(0.0, 1.0);
                }
                blurred
            })
            .collect();
        Self { size, masks }
    }

    /// A_i for blendshape `i` (0-based).
    pub fn mask(&self, i: usize) -> &UvMap {
        &self.masks[i]
    }
}

/// Which texels some face triangle covers.
fn coverage_map(template: &Template, face_tris: &[usize], size: usize) -> Vec<bool> {
    let mut covered = vec![false; size * size];
    for &t in face_tris {
        let uv = template.triangle_uvs[t].map(|k| template.uvs[k as usize]);
        rasterize_uv_triangle(uv, size, size, |x, y, _| covered[y * size + x] = true);
    }
    covered
}

/// Grows the map by `steps` texels into texels no triangle covers, each new texel taking the
/// mean of its already-filled 4-neighbours.
fn pad_into_uncovered(map: &mut UvMap, coverage: &[bool], steps: usize) {
    let (w, h) = (map.width, map.height);
    let mut filled = coverage.to_vec();
    for _ in 0..steps {
        let mut next = filled.clone();
        let snapshot = map.data.clone();
        for y in 0..h {
            for x in 0..w {
                if filled[y * w + x] {
                    continue;
                }
                let mut sum = 0.0;
                let mut n = 0;
                for (dx, dy) in [(-1i32, 0i32), (1, 0), (0, -1), (0, 1)] {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                        continue;
                    }
                    let k = ny as usize * w + nx as usize;
                    if filled[k] {
                        sum += snapshot[k];
                        n += 1;
                    }
                }
                if n > 0 {
                    map.data[y * w + x] = sum / n as f32;
                    next[y * w + x] = true;
                }
            }
        }
        filled = next;
    }
}
