//! Spherical-harmonics shading with 27 coefficients gamma (9 per colour channel), the
//! illumination model of FML that the paper follows: colour = albedo * sum_k gamma_ck Y_k(n)
//! for a Lambertian surface with the cosine lobe folded into the basis constants.
//! Coefficient order: [r_0..r_8, g_0..g_8, b_0..b_8]. The renderer's WGSL uses exactly
//! these constants.

use glam::Vec3;
use std::f32::consts::PI;

pub const SH_COEFFICIENTS: usize = 27;

const A0: f32 = PI;
fn a1() -> f32 {
    2.0 * PI / 3f32.sqrt()
}
fn a2() -> f32 {
    2.0 * PI / 8f32.sqrt()
}
fn c0() -> f32 {
    1.0 / (4.0 * PI).sqrt()
}
fn c1() -> f32 {
    3f32.sqrt() / (4.0 * PI).sqrt()
}
fn c2() -> f32 {
    3.0 * 5f32.sqrt() / (12.0 * PI).sqrt()
}

/// The 9 basis values (constants included) at unit normal `n`.
pub fn sh_basis(n: Vec3) -> [f32; 9] {
    let (a1c1, a2c2) = (a1() * c1(), a2() * c2());
    [
        A0 * c0(),
        -a1c1 * n.y,
        a1c1 * n.z,
        -a1c1 * n.x,
        a2c2 * n.x * n.y,
        -a2c2 * n.y * n.z,
        a2c2 * 0.5 / 3f32.sqrt() * (3.0 * n.z * n.z - 1.0),
        -a2c2 * n.x * n.z,
        a2c2 * 0.5 * (n.x * n.x - n.y * n.y),
    ]
}

/// d(basis)/dn: row k is the gradient of Y_k.
pub fn sh_basis_gradient(n: Vec3) -> [Vec3; 9] {
    let (a1c1, a2c2) = (a1() * c1(), a2() * c2());
    [
        Vec3::ZERO,
        Vec3::new(0.0, -a1c1, 0.0),
        Vec3::new(0.0, 0.0, a1c1),
        Vec3::new(-a1c1, 0.0, 0.0),
        a2c2 * Vec3::new(n.y, n.x, 0.0),
        -a2c2 * Vec3::new(0.0, n.z, n.y),
        Vec3::new(0.0, 0.0, a2c2 * 0.5 / 3f32.sqrt() * 6.0 * n.z),
        -a2c2 * Vec3::new(n.z, 0.0, n.x),
        a2c2 * Vec3::new(n.x, -n.y, 0.0),
    ]
}

/// Irradiance per colour channel at normal `n`.
pub fn irradiance(n: Vec3, gamma: &[f32; SH_COEFFICIENTS]) -> Vec3 {
    let y = sh_basis(n);
    let channel = |c: usize| (0..9).map(|k| gamma[c * 9 + k] * y[k]).sum::<f32>();
    Vec3::new(channel(0), channel(1), channel(2))
}

/// Shaded colour: albedo * irradiance.
pub fn shade(albedo: Vec3, n: Vec3, gamma: &[f32; SH_COEFFICIENTS]) -> Vec3 {
    albedo * irradiance(n, gamma)
}

/// Lighting with irradiance exactly `level` in every direction (only the constant band).
pub fn constant_light(level: f32) -> [f32; SH_COEFFICIENTS] {
    let mut gamma = [0.0; SH_COEFFICIENTS];
    for c in 0..3 {
        gamma[c * 9] = level / (A0 * c0());
    }
    gamma
}

/// Order-2 SH approximation of a distant light: irradiance `rgb * max(0, n . direction)`,
/// `direction` pointing from the surface towards the light.
///
/// Each basis function is Y_k = ±a_l R_k with R_k the orthonormal real SH, and the clamped
/// cosine has SH transfer factors (pi, 2pi/3, pi/4) per band, so
/// gamma_k = factor_l Y_k(d) / a_l^2.
pub fn directional_light(direction: Vec3, rgb: [f32; 3]) -> [f32; SH_COEFFICIENTS] {
    let d = direction.normalize_or(Vec3::Z);
    let y = sh_basis(d);
    let band_factor = |k: usize| -> f32 {
        match k {
            0 => PI / (A0 * A0),
            1..=3 => (2.0 * PI / 3.0) / (a1() * a1()),
            _ => (PI / 4.0) / (a2() * a2()),
        }
    };
    let mut gamma = [0.0; SH_COEFFICIENTS];
    for (c, intensity) in rgb.iter().enumerate() {
        for (k, yk) in y.iter().enumerate() {
            gamma[c * 9 + k] = intensity * band_factor(k) * yk;
        }
    }
    gamma
}

/// A pleasant neutral studio light: soft ambient plus a slightly warm key light from the
/// upper front left as the camera sees it.
pub fn studio_light() -> [f32; SH_COEFFICIENTS] {
    let key = directional_light(KEY_LIGHT_DIRECTION, [0.52, 0.5, 0.47]);
    let ambient_level = [0.56, 0.57, 0.6];
    let mut gamma = [0.0; SH_COEFFICIENTS];
    for (i, g) in gamma.iter_mut().enumerate() {
        *g = constant_light(ambient_level[i / 9])[i] + key[i];
    }
    gamma
}

/// Direction towards the key light of [`studio_light`].
pub const KEY_LIGHT_DIRECTION: Vec3 = Vec3::new(-0.5, 0.55, 0.75);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directional_light_approximates_the_clamped_cosine() {
        let d = Vec3::new(-0.5, 0.5, 0.7).normalize();
        let gamma = directional_light(d, [1.0; 3]);
        // Order-2 SH reproduces the clamped cosine to within ~0.1 everywhere.
        assert!((irradiance(d, &gamma).x - 1.0).abs() < 0.1);
        assert!(irradiance(-d, &gamma).x.abs() < 0.1);
        assert!(irradiance(Vec3::Y, &gamma).x > irradiance(Vec3::NEG_Y, &gamma).x + 0.3);
    }
}
