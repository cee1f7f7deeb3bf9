//! Maps in UV space and the sampling function F of equation (2).
//!
//! Texel convention (shared with the Python training code): a `width x height` map stores
//! row 0 at the top of the texture (v = 1) and texel (x, y) has its centre at
//! u = (x + 0.5) / width, v = 1 - (y + 0.5) / height, so a map saved as PNG looks like the
//! upstream UV layout. Bilinear sampling clamps to the edge; this equals PyTorch's
//! `grid_sample(align_corners=False, padding_mode="border")` with grid y = 1 - 2v.

use glam::Vec2;

/// Side of the square correction maps Delta^S_i, Delta^R_i and attention masks A_i
/// (the paper's 128 x 128).
pub const CORRECTION_SIZE: usize = 128;

/// A dense map in UV space with `channels` floats per texel, row-major, row 0 at v = 1.
#[derive(Clone, Debug, PartialEq)]
pub struct UvMap {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    pub data: Vec<f32>,
}

impl UvMap {
    pub fn zeros(width: usize, height: usize, channels: usize) -> Self {
        Self {
            width,
            height,
            channels,
            data: vec![0.0; width * height * channels],
        }
    }

    /// A map filled by `f(u, v)` evaluated at every texel centre.
    pub fn from_fn(
        width: usize,
        height: usize,
        channels: usize,
        mut f: impl FnMut(Vec2) -> Vec<f32>,
    ) -> Self {
        let mut map = Self::zeros(width, height, channels);
        for y in 0..height {
            for x in 0..width {
                let value = f(texel_center_uv(x, y, width, height));
                let start = (y * width + x) * channels;
                for (c, v) in value.into_iter().take(channels).enumerate() {
                    map.data[start + c] = v;
                }
            }
        }
        map
    }

    pub fn texel(&self, x: usize, y: usize) -> &[f32] {
        let start = (y * self.width + x) * self.channels;
        &self.data[start..start + self.channels]
    }

    pub fn texel_mut(&mut self, x: usize, y: usize) -> &mut [f32] {
        let start = (y * self.width + x) * self.channels;
        &mut self.data[start..start + self.channels]
    }

    /// The bilinear taps at `uv` (see [`bilinear_taps`]).
    pub fn taps(&self, uv: Vec2) -> [(u32, f32); 4] {
        bilinear_taps(uv, self.width, self.height)
    }

    /// Bilinear sample at `uv`, clamped to the edge.
    pub fn sample(&self, uv: Vec2) -> Vec<f32> {
        let mut out = vec![0.0; self.channels];
        for (texel, weight) in self.taps(uv) {
            let start = texel as usize * self.channels;
            for (c, o) in out.iter_mut().enumerate() {
                *o += weight * self.data[start + c];
            }
        }
        out
    }

    /// True when every value is finite.
    pub fn is_finite(&self) -> bool {
        self.data.iter().all(|x| x.is_finite())
    }

    /// Largest absolute value over all texels and channels.
    pub fn max_abs(&self) -> f32 {
        self.data.iter().fold(0.0f32, |m, x| m.max(x.abs()))
    }
}

/// Centre of texel (x, y) in UV coordinates.
pub fn texel_center_uv(x: usize, y: usize, width: usize, height: usize) -> Vec2 {
    Vec2::new(
        (x as f32 + 0.5) / width as f32,
        1.0 - (y as f32 + 0.5) / height as f32,
    )
}

/// The four texels (row-major index) and weights a bilinear sample at `uv` reads.
pub fn bilinear_taps(uv: Vec2, width: usize, height: usize) -> [(u32, f32); 4] {
    let fx = (uv.x * width as f32 - 0.5).clamp(0.0, (width - 1) as f32);
    let fy = ((1.0 - uv.y) * height as f32 - 0.5).clamp(0.0, (height - 1) as f32);
    let x0 = fx.floor() as usize;
    let y0 = fy.floor() as usize;
    let x1 = (x0 + 1).min(width - 1);
    let y1 = (y0 + 1).min(height - 1);
    let ax = fx - x0 as f32;
    let ay = fy - y0 as f32;
    let idx = |x: usize, y: usize| (y * width + x) as u32;
    [
        (idx(x0, y0), (1.0 - ax) * (1.0 - ay)),
        (idx(x1, y0), ax * (1.0 - ay)),
        (idx(x0, y1), (1.0 - ax) * ay),
        (idx(x1, y1), ax * ay),
    ]
}

/// Calls `f(x, y, barycentrics)` for every texel of a `width x height` map whose centre lies
/// inside the triangle `uv` (tile [0, 1]^2, origin bottom-left). Edges are inclusive so
/// neighbouring triangles leave no gaps.
///
/// Written by hand: the only rasterizers on crates.io draw into images with colours, not
/// barycentrics over an arbitrary callback.
pub fn rasterize_uv_triangle(
    uv: [Vec2; 3],
    width: usize,
    height: usize,
    mut f: impl FnMut(usize, usize, [f32; 3]),
) {
    // To continuous texel space, where texel (x, y) has its centre at (x + 0.5, y + 0.5).
    let p = uv.map(|t| Vec2::new(t.x * width as f32, (1.0 - t.y) * height as f32));
    let area = (p[1] - p[0]).perp_dot(p[2] - p[0]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let min = p[0].min(p[1]).min(p[2]);
    let max = p[0].max(p[1]).max(p[2]);
    let x_start = (min.x - 0.5).ceil().max(0.0) as usize;
    let y_start = (min.y - 0.5).ceil().max(0.0) as usize;
    let x_end = ((max.x - 0.5).floor() as isize).min(width as isize - 1);
    let y_end = ((max.y - 0.5).floor() as isize).min(height as isize - 1);
    if x_end < 0 || y_end < 0 {
        return;
    }
    const EPS: f32 = -1e-6;
    for y in y_start..=y_end as usize {
        for x in x_start..=x_end as usize {
            let c = Vec2::new(x as f32 + 0.5, y as f32 + 0.5);
            let b0 = (p[1] - c).perp_dot(p[2] - c) / area;
            let b1 = (p[2] - c).perp_dot(p[0] - c) / area;
            let b2 = 1.0 - b0 - b1;
            if b0 >= EPS && b1 >= EPS && b2 >= EPS {
                f(x, y, [b0, b1, b2]);
            }
        }
    }
}

/// Separable Gaussian blur of every channel with standard deviation `sigma` texels,
/// clamped at the borders.
pub fn gaussian_blur(map: &UvMap, sigma: f32) -> UvMap {
    if sigma <= 0.0 {
        return map.clone();
    }
    let radius = (3.0 * sigma).ceil() as isize;
    let kernel: Vec<f32> = (-radius..=radius)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let norm: f32 = kernel.iter().sum();
    let kernel: Vec<f32> = kernel.iter().map(|k| k / norm).collect();
    let (w, h, ch) = (map.width as isize, map.height as isize, map.channels);
    let mut tmp = UvMap::zeros(map.width, map.height, ch);
    for y in 0..h {
        for x in 0..w {
            let out = tmp.texel_mut(x as usize, y as usize);
            for (k, kv) in kernel.iter().enumerate() {
                let sx = (x + k as isize - radius).clamp(0, w - 1) as usize;
                let src = map.texel(sx, y as usize);
                for c in 0..ch {
                    out[c] += kv * src[c];
                }
            }
        }
    }
    let mut result = UvMap::zeros(map.width, map.height, ch);
    for y in 0..h {
        for x in 0..w {
            let mut acc = vec![0.0f32; ch];
            for (k, kv) in kernel.iter().enumerate() {
                let sy = (y + k as isize - radius).clamp(0, h - 1) as usize;
                let src = tmp.texel(x as usize, sy);
                for c in 0..ch {
                    acc[c] += kv * src[c];
                }
            }
            result
                .texel_mut(x as usize, y as usize)
                .copy_from_slice(&acc);
        }
    }
    result
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bilinear_sample_of_a_linear_ramp_is_exact() {
        // f(u, v) = 2u + 3v is reproduced exactly by bilinear interpolation away from edges.
        let map = UvMap::from_fn(16, 8, 1, |uv| vec![2.0 * uv.x + 3.0 * uv.y]);
        for &(u, v) in &[(0.3, 0.4), (0.51, 0.77), (0.2, 0.2)] {
            let s = map.sample(Vec2::new(u, v))[0];
            assert!((s - (2.0 * u + 3.0 * v)).abs() < 1e-5, "{s} at {u},{v}");
        }
    }

    #[test]
    fn taps_sum_to_one_and_clamp() {
        for &(u, v) in &[(0.0, 0.0), (1.0, 1.0), (-3.0, 7.0), (0.5, 0.5)] {
            let taps = bilinear_taps(Vec2::new(u, v), 128, 128);
            let sum: f32 = taps.iter().map(|t| t.1).sum();
            assert!((sum - 1.0).abs() < 1e-6);
            assert!(taps.iter().all(|t| (t.0 as usize) < 128 * 128));
        }
    }

    #[test]
    fn two_triangles_of_a_square_cover_it_once() {
        let mut count = vec![0u32; 32 * 32];
        let a = Vec2::new(0.0, 0.0);
        let b = Vec2::new(1.0, 0.0);
        let c = Vec2::new(1.0, 1.0);
        let d = Vec2::new(0.0, 1.0);
        for tri in [[a, b, c], [a, c, d]] {
            rasterize_uv_triangle(tri, 32, 32, |x, y, bary| {
                assert!((bary.iter().sum::<f32>() - 1.0).abs() < 1e-5);
                count[y * 32 + x] += 1;
            });
        }
        // Every texel covered; only the diagonal may be hit twice (inclusive edges).
        assert!(count.iter().all(|&c| c >= 1));
        assert!(count.iter().filter(|&&c| c > 1).count() <= 32);
    }

    #[test]
    fn blur_preserves_a_constant_and_the_mass_of_an_impulse() {
        let constant = UvMap::from_fn(20, 20, 2, |_| vec![0.7, -1.0]);
        let blurred = gaussian_blur(&constant, 1.5);
        assert!(
            blurred
                .data
                .iter()
                .zip(&constant.data)
                .all(|(a, b)| (a - b).abs() < 1e-5)
        );
        let mut impulse = UvMap::zeros(21, 21, 1);
        impulse.texel_mut(10, 10)[0] = 1.0;
        let spread = gaussian_blur(&impulse, 1.0);
        let mass: f32 = spread.data.iter().sum();
        assert!((mass - 1.0).abs() < 1e-5);
        assert!(spread.texel(10, 10)[0] < 1.0 && spread.texel(11, 10)[0] > 0.0);
    }
}
