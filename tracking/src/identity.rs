//! The person's identity fitted to a whole clip's landmarks (issue 32, item 2: "pose and
//! per-clip identity"; the first part of issue 33's `personalize` over the footage).
//!
//! Refinement fits each frame alone on a fixed model, so whatever separates this person's
//! face from the model (a wider jaw, closer eyes) goes into that frame's pose and weights.
//! Over a clip the identity is one unknown seen in every frame: ICT's identity components
//! (PCA deltas scaled to unit standard deviation, so alpha ~ N(0, 1) is a person) fitted
//! to every frame's points with the frames' refined weights and poses held, under a
//! Gaussian prior lambda |alpha|^2:
//!
//! E(alpha) = 1/N sum_n sum_k c_nk / C_n rho(|r_nk(alpha)|) + lambda |alpha|^2,
//!
//! r_nk the refinement's landmark residual (percent of the frame's landmark box, measured
//! across and a little along contour chains, Huber rho with refinement's scale). The model
//! is linear in alpha before the projection, so a few Gauss-Newton steps solve it.
//! [`crate::pipeline::Tracker::fit_identity`] alternates this with refining the frames
//! again on the new model.

use face::{PersonalizedBlendshapes, Template};
use glam::{Vec2, Vec3};

use crate::error::{Result, TrackingError};
use crate::params::FaceParams;
use crate::refine::{
    LandmarkObservation, LandmarkObservations, RefineConfig, Refiner, cholesky_solve, huber,
};
use face::camera::Intrinsics;

/// Settings of [`fit_identity`] and [`crate::pipeline::Tracker::fit_identity`].
#[derive(Clone, Debug, PartialEq)]
pub struct IdentityConfig {
    /// How many of ICT's identity components to fit, from the first (the largest).
    pub components: usize,
    /// lambda on |alpha|^2 (alpha in the components' standard deviations). Default 0.2,
    /// chosen on the tuning clips (seed 9002, `evaluate --tune-identity`): weaker priors
    /// raised the landmark error against the truth with either detector (Face Mesh, 40
    /// components: box NME 2.34 % on the template, 2.33 / 2.40 / 2.49 / 2.65 % at prior
    /// 0.2 / 0.05 / 0.02 / 0.005), because about two thirds of a detector's squared error
    /// is an offset fixed over the clip (the `mesh_residuals` example), which a free
    /// identity absorbs as if it were the face's.
    pub prior: f32,
    /// Gauss-Newton steps per fit.
    pub iterations: usize,
    /// Fit, refine every frame again, fit again: how many fits.
    pub rounds: usize,
}

impl Default for IdentityConfig {
    fn default() -> Self {
        Self {
            components: 40,
            prior: 0.2,
            iterations: 4,
            rounds: 2,
        }
    }
}

impl IdentityConfig {
    pub fn validate(&self, available: usize) -> Result<()> {
        let bad = |what: String| Err(TrackingError::InvalidInput(what));
        if self.components == 0 || self.components > available {
            return bad(format!(
                "identity `components` is {}, must be in [1, {available}] (the template's identity components)",
                self.components
            ));
        }
        if !(self.prior.is_finite() && self.prior > 0.0) {
            return bad(format!(
                "identity `prior` is {}, must be finite and > 0",
                self.prior
            ));
        }
        if !(1..=100).contains(&self.iterations) {
            return bad(format!(
                "identity `iterations` is {}, must be in [1, 100]",
                self.iterations
            ));
        }
        if !(1..=20).contains(&self.rounds) {
            return bad(format!(
                "identity `rounds` is {}, must be in [1, 20]",
                self.rounds
            ));
        }
        Ok(())
    }
}

/// One frame of the clip: its refined parameters (held) and its detected points.
#[derive(Clone, Copy, Debug)]
pub struct ClipFrame<'a> {
    pub params: FaceParams,
    pub observations: &'a LandmarkObservations,
}

/// What [`fit_identity`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct IdentityFit {
    /// alpha_j of the first `components` identity components, on top of the model the
    /// refiner was built on.
    pub coefficients: Vec<f32>,
    /// Weighted rms point residual (pixels) over the clip before and after.
    pub rms_before_px: f32,
    pub rms_after_px: f32,
    /// Frames that had points to fit.
    pub frames: usize,
}

/// One frame's terms, prepared once per fit.
struct FrameTerms {
    rotation: glam::Mat3,
    translation: Vec3,
    scale: f32,
    /// (point, observed pixel, residual basis, weight c_k / C_n / N).
    points: Vec<(usize, Vec2, [Vec2; 2], f64)>,
    /// Each point's position under the frame's weights, identity excluded.
    positions: Vec<Vec3>,
}

/// Fits `config.components` identity coefficients on top of the model `refiner` was built
/// from (at its fitted points' vertices), starting from
/// `start` (empty: zeros). Frames without usable points are skipped; none at all is an
/// error. `refine` gives the Huber scale and the contour slide, as refinement uses them.
pub fn fit_identity(
    template: &Template,
    refiner: &Refiner,
    intrinsics: &Intrinsics,
    frames: &[ClipFrame<'_>],
    refine: &RefineConfig,
    config: &IdentityConfig,
    start: &[f32],
) -> Result<IdentityFit> {
    config.validate(template.identity_count)?;
    refine.validate()?;
    let k_count = config.components;
    if !start.is_empty() && start.len() != k_count {
        return Err(TrackingError::InvalidInput(format!(
            "{} starting identity coefficients for {k_count} components",
            start.len()
        )));
    }
    let vertices = refiner.point_vertices();
    // The identity deltas at the fitted points, component-major.
    let mut basis = Vec::with_capacity(k_count * vertices.len());
    for j in 0..k_count {
        let delta = template.identity_delta(j);
        for &v in vertices {
            let d = *delta.get(v as usize).ok_or_else(|| {
                TrackingError::InvalidInput(format!(
                    "point vertex {v} is outside the template's {} vertices",
                    delta.len()
                ))
            })?;
            basis.push(d);
        }
    }
    let n_points = vertices.len();
    let at = |j: usize, k: usize| basis[j * n_points + k];

    let mut prepared: Vec<FrameTerms> = Vec::new();
    for frame in frames {
        if !frame.params.is_finite() {
            return Err(TrackingError::InvalidInput(
                "a clip frame's parameters contain NaN or infinite values".into(),
            ));
        }
        let used: Vec<&LandmarkObservation> = frame
            .observations
            .points
            .iter()
            .filter(|o| {
                o.index < n_points && o.pixel.is_finite() && o.weight.is_finite() && o.weight > 0.0
            })
            .collect();
        let (lo, hi) = used.iter().fold(
            (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
            |(lo, hi), o| (lo.min(o.pixel), hi.max(o.pixel)),
        );
        let size = (hi - lo).max_element();
        if used.len() < 2 || !(size.is_finite() && size >= 1.0) {
            continue;
        }
        let total: f64 = used.iter().map(|o| f64::from(o.weight)).sum();
        let bases = refiner.residual_bases(&used, refine.contour_slide);
        let points = used
            .iter()
            .zip(bases)
            .map(|(o, b)| (o.index, o.pixel, b, f64::from(o.weight) / total))
            .collect();
        let positions = (0..n_points)
            .map(|k| refiner.point_position(k, &frame.params.weights))
            .collect();
        prepared.push(FrameTerms {
            rotation: frame.params.pose.rotation(),
            translation: frame.params.pose.translation,
            scale: 100.0 / size,
            points,
            positions,
        });
    }
    if prepared.is_empty() {
        return Err(TrackingError::InvalidInput(
            "no frame of the clip has points to fit an identity to".into(),
        ));
    }
    let per_frame = 1.0 / prepared.len() as f64;
    let delta = f64::from(refine.huber_scale);
    let lambda = f64::from(config.prior);

    // The identity offset at every point, once per alpha (every frame shares it).
    let offsets = |alpha: &[f64]| -> Vec<Vec3> {
        (0..n_points)
            .map(|k| (0..k_count).fold(Vec3::ZERO, |acc, j| acc + alpha[j] as f32 * at(j, k)))
            .collect()
    };
    // Energy and weighted squared pixel residual; None when a point falls behind the camera.
    let energy = |alpha: &[f64]| -> Option<(f64, f64)> {
        let offset = offsets(alpha);
        let mut e = 0.0;
        let mut sq = 0.0;
        for f in &prepared {
            for &(k, observed, b, c) in &f.points {
                let p = f.rotation * (f.positions[k] + offset[k]) + f.translation;
                let d = intrinsics.project(p)? - observed;
                let r = Vec2::new(b[0].dot(d), b[1].dot(d)) * f.scale;
                e += c * per_frame * huber(f64::from(r.length()), delta).0;
                sq += c * per_frame * f64::from(d.length_squared());
            }
        }
        Some((e + lambda * alpha.iter().map(|a| a * a).sum::<f64>(), sq))
    };

    let mut alpha: Vec<f64> = if start.is_empty() {
        vec![0.0; k_count]
    } else {
        start.iter().map(|&a| f64::from(a)).collect()
    };
    let (mut e, sq_before) = energy(&alpha).ok_or_else(|| {
        TrackingError::InvalidInput("a clip frame puts a point behind the camera".into())
    })?;
    let mut sq = sq_before;
    for _ in 0..config.iterations {
        let mut h = vec![0.0f64; k_count * k_count];
        let mut g: Vec<f64> = alpha.iter().map(|a| lambda * a).collect();
        for (j, hj) in h.chunks_exact_mut(k_count).enumerate() {
            hj[j] = lambda;
        }
        let mut row = vec![0.0f64; k_count];
        let offset = offsets(&alpha);
        for f in &prepared {
            for &(k, observed, b, c) in &f.points {
                let p = f.rotation * (f.positions[k] + offset[k]) + f.translation;
                let (Some(pixel), Some(jp)) =
                    (intrinsics.project(p), intrinsics.project_jacobian(p))
                else {
                    continue;
                };
                let d = pixel - observed;
                let r = Vec2::new(b[0].dot(d), b[1].dot(d)) * f.scale;
                let omega = c * per_frame * huber(f64::from(r.length()), delta).1;
                for (q, bq) in b.iter().enumerate() {
                    // d r_q / d alpha_j = s b_q . J_proj R I_j = s (R^T J_proj^T b_q) . I_j.
                    let back = f.rotation.transpose() * (jp[0] * bq.x + jp[1] * bq.y) * f.scale;
                    for (j, x) in row.iter_mut().enumerate() {
                        *x = f64::from(back.dot(at(j, k)));
                    }
                    let rq = f64::from(r[q]);
                    for (j, &xj) in row.iter().enumerate() {
                        g[j] += omega * rq * xj;
                        let hj = &mut h[j * k_count..(j + 1) * k_count];
                        for (hjl, &xl) in hj[j..].iter_mut().zip(&row[j..]) {
                            *hjl += omega * xj * xl;
                        }
                    }
                }
            }
        }
        let mut step: Vec<f64> = g.iter().map(|x| -x).collect();
        if !cholesky_solve(&mut h, k_count, &mut step) {
            break;
        }
        // Backtracking: the Huber weights and the projection make a full step a guess.
        let mut scale = 1.0;
        let mut accepted = false;
        for _ in 0..6 {
            let trial: Vec<f64> = alpha
                .iter()
                .zip(&step)
                .map(|(a, s)| a + scale * s)
                .collect();
            if let Some((e_trial, sq_trial)) = energy(&trial)
                && e_trial < e
            {
                let gain = (e - e_trial) / e.max(1e-12);
                alpha = trial;
                e = e_trial;
                sq = sq_trial;
                accepted = true;
                if gain < 1e-7 {
                    scale = 0.0;
                }
                break;
            }
            scale *= 0.5;
        }
        if !accepted || scale == 0.0 {
            break;
        }
    }
    let coefficients: Vec<f32> = alpha.iter().map(|&a| a as f32).collect();
    if coefficients.iter().any(|a| !a.is_finite()) {
        return Err(TrackingError::NonFinite {
            model: "identity fit".into(),
            output: "coefficients".into(),
        });
    }
    Ok(IdentityFit {
        coefficients,
        rms_before_px: sq_before.sqrt() as f32,
        rms_after_px: sq.sqrt() as f32,
        frames: prepared.len(),
    })
}

/// `blendshapes` with the identity offset sum_j alpha_j I_j added to the base (the
/// expression deltas are unchanged: ICT's expressions are offsets on any identity).
pub fn with_identity(
    template: &Template,
    blendshapes: &PersonalizedBlendshapes,
    coefficients: &[f32],
) -> Result<PersonalizedBlendshapes> {
    if coefficients.len() > template.identity_count {
        return Err(TrackingError::InvalidInput(format!(
            "{} identity coefficients, the template has {} components",
            coefficients.len(),
            template.identity_count
        )));
    }
    if blendshapes.base.len() != template.vertex_count() {
        return Err(TrackingError::InvalidInput(format!(
            "blendshapes of {} vertices for a template of {}",
            blendshapes.base.len(),
            template.vertex_count()
        )));
    }
    let mut out = blendshapes.clone();
    for (j, &a) in coefficients.iter().enumerate() {
        if a == 0.0 {
            continue;
        }
        for (b, d) in out.base.iter_mut().zip(template.identity_delta(j)) {
            *b += a * *d;
        }
    }
    Ok(out)
}
