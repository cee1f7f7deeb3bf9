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

/// A pleasant default: soft ambient plus a key light from the upper front left of the
/// subject (the viewer's upper right is the subject's left, +x).
pub fn studio_light() -> [f32; SH_COEFFICIENTS] {
    let mut gamma = constant_light(0.8);
    let (a1c1,) = (a1() * c1(),);
    // A first-order lobe towards direction d adds s * (d . n) to the irradiance.
    let d = Vec3::new(0.35, 0.45, 0.82).normalize();
    let s = 0.35 / a1c1;
    for c in 0..3 {
        gamma[c * 9 + 1] = -s * d.y;
        gamma[c * 9 + 2] = s * d.z;
        gamma[c * 9 + 3] = -s * d.x;
    }
    gamma
}
