//! Equations (2) and (3) of the paper: the personalized shape and albedo.
//!
//! Shape (2): S = w_0 S_0 + F(dS_0) + sum_i w_i [S_i + F(A_i dS_i)], with
//! w_0 = 1 - sum_i w_i. Expanding w_0 gives the form evaluated here,
//! S = (S_0 + F(dS_0)) + sum_i w_i (S_i - S_0 + F(A_i dS_i)): the bracketed terms depend
//! only on the person, so they are sampled once ([`PersonalizedBlendshapes`]) and each frame
//! costs one weighted sum.
//!
//! Albedo (3): R = R_0^t + dR_0 + sum_i w_i A_i dR_i in UV space. Bilinear upsampling is
//! linear, so the 128 x 128 terms are summed first and upsampled once onto R_0's grid.

use glam::Vec3;

use crate::error::{FaceError, Result};
use crate::masks::AttentionMasks;
use crate::names::{ICT_NAMES, NUM_BLENDSHAPES};
use crate::sampling::CorrectionSampler;
use crate::template::{NUM_LANDMARKS, Template};
use crate::uv::{CORRECTION_SIZE, UvMap, texel_center_uv};

/// Expression weights w_1..w_53 (ICT order), validated: finite and in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BlendshapeWeights(pub [f32; NUM_BLENDSHAPES]);

/// What [`BlendshapeWeights::from_slice_clamped`] had to change, for the UI or CLI to say.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ClampReport {
    /// (ICT name, value before clamping).
    pub clamped: Vec<(&'static str, f32)>,
}

impl Default for BlendshapeWeights {
    fn default() -> Self {
        Self([0.0; NUM_BLENDSHAPES])
    }
}

impl BlendshapeWeights {
    /// Weights from 53 values; values outside [0, 1] are clamped and reported, NaN or
    /// infinite values are an error.
    pub fn from_slice_clamped(values: &[f32]) -> Result<(Self, ClampReport)> {
        if values.len() != NUM_BLENDSHAPES {
            return Err(FaceError::InvalidInput(format!(
                "expected {NUM_BLENDSHAPES} blendshape weights, got {}",
                values.len()
            )));
        }
        let mut out = [0.0; NUM_BLENDSHAPES];
        let mut report = ClampReport::default();
        for (i, &w) in values.iter().enumerate() {
            if !w.is_finite() {
                return Err(FaceError::InvalidInput(format!(
                    "weight of `{}` is {w}, not a number in [0, 1]",
                    ICT_NAMES[i]
                )));
            }
            let c = w.clamp(0.0, 1.0);
            if c != w {
                report.clamped.push((ICT_NAMES[i], w));
            }
            out[i] = c;
        }
        Ok((Self(out), report))
    }

    /// w_0 = 1 - sum_i w_i, the weight of the neutral in equation (2).
    pub fn neutral_weight(&self) -> f32 {
        1.0 - self.0.iter().sum::<f32>()
    }
}

/// The person-specific corrections ModelNet predicts, all in the 128 x 128 UV space of the
/// face tile: shape in centimetres (template units), albedo in display-encoded RGB.
#[derive(Clone, Debug, PartialEq)]
pub struct PersonalCorrections {
    /// dS_0: identity shape correction (3 channels).
    pub identity_shape: UvMap,
    /// dS_i: per-blendshape shape corrections (53 maps, 3 channels), before the mask A_i.
    pub expression_shapes: Vec<UvMap>,
    /// dR_0: static albedo correction (3 channels).
    pub static_albedo: UvMap,
    /// dR_i: dynamic albedo corrections (53 maps, 3 channels), before the mask A_i.
    pub dynamic_albedo: Vec<UvMap>,
}

impl PersonalCorrections {
    /// No corrections: the template itself.
    pub fn zeros() -> Self {
        let map = || UvMap::zeros(CORRECTION_SIZE, CORRECTION_SIZE, 3);
        Self {
            identity_shape: map(),
            expression_shapes: (0..NUM_BLENDSHAPES).map(|_| map()).collect(),
            static_albedo: map(),
            dynamic_albedo: (0..NUM_BLENDSHAPES).map(|_| map()).collect(),
        }
    }

    /// Checks counts, sizes and finiteness, naming the first bad map.
    pub fn validate(&self) -> Result<()> {
        // The name is built only for an error: this runs on every frame a renderer's albedo
        // follows the weights.
        let check = |name: &dyn Fn() -> String, m: &UvMap| -> Result<()> {
            if m.width != CORRECTION_SIZE || m.height != CORRECTION_SIZE || m.channels != 3 {
                return Err(FaceError::InvalidInput(format!(
                    "{} is {}x{}x{}, expected {CORRECTION_SIZE}x{CORRECTION_SIZE}x3",
                    name(),
                    m.width,
                    m.height,
                    m.channels
                )));
            }
            if !m.is_finite() {
                return Err(FaceError::InvalidInput(format!(
                    "{} has NaN or infinite values",
                    name()
                )));
            }
            Ok(())
        };
        if self.expression_shapes.len() != NUM_BLENDSHAPES
            || self.dynamic_albedo.len() != NUM_BLENDSHAPES
        {
            return Err(FaceError::InvalidInput(format!(
                "expected {NUM_BLENDSHAPES} expression and dynamic albedo corrections, got {} and {}",
                self.expression_shapes.len(),
                self.dynamic_albedo.len()
            )));
        }
        check(&|| "dS_0".into(), &self.identity_shape)?;
        check(&|| "dR_0".into(), &self.static_albedo)?;
        for (name, (shape, albedo)) in ICT_NAMES
            .iter()
            .zip(self.expression_shapes.iter().zip(&self.dynamic_albedo))
        {
            check(&|| format!("dS of {name}"), shape)?;
            check(&|| format!("dR of {name}"), albedo)?;
        }
        Ok(())
    }
}

/// The template with everything derived from it once: F and the attention masks.
#[derive(Clone, Debug)]
pub struct FaceModel {
    pub template: Template,
    pub sampler: CorrectionSampler,
    pub masks: AttentionMasks,
}

impl FaceModel {
    pub fn new(template: Template) -> Self {
        let sampler = CorrectionSampler::for_template(&template);
        let masks = AttentionMasks::build(&template);
        Self {
            template,
            sampler,
            masks,
        }
    }

    /// Samples a person's shape corrections into per-vertex blendshapes.
    pub fn personalize(
        &self,
        corrections: &PersonalCorrections,
    ) -> Result<PersonalizedBlendshapes> {
        corrections.validate()?;
        let v = self.template.vertex_count();
        let identity = self.sampler.sample_vec3(&corrections.identity_shape);
        let base = self
            .template
            .neutral
            .iter()
            .zip(&identity)
            .map(|(s0, d)| *s0 + *d)
            .collect();
        let mut deltas = Vec::with_capacity(NUM_BLENDSHAPES * v);
        for i in 0..NUM_BLENDSHAPES {
            let correction = self
                .sampler
                .sample_masked_vec3(self.masks.mask(i), &corrections.expression_shapes[i]);
            deltas.extend(
                self.template
                    .expression_delta(i)
                    .iter()
                    .zip(&correction)
                    .map(|(d, c)| *d + *c),
            );
        }
        Ok(PersonalizedBlendshapes {
            vertex_count: v,
            base,
            deltas,
        })
    }

    /// The template's own blendshapes (all corrections zero).
    pub fn template_blendshapes(&self) -> PersonalizedBlendshapes {
        PersonalizedBlendshapes {
            vertex_count: self.template.vertex_count(),
            base: self.template.neutral.clone(),
            deltas: self.template.expression_deltas.clone(),
        }
    }

    /// The person's part of equation (3), dR_0 + sum_i w_i A_i dR_i, on the corrections'
    /// own grid (128 x 128): what a renderer adds to R_0^t per frame.
    ///
    /// Runs per frame, so instead of [`PersonalCorrections::validate`] (every value of all
    /// 106 maps) it checks the maps' sizes and the result: a NaN or infinity in dR_0, in a
    /// dR_i with a non-zero weight, or in the weights makes the result non-finite.
    pub fn albedo_correction(
        &self,
        corrections: &PersonalCorrections,
        weights: &BlendshapeWeights,
    ) -> Result<UvMap> {
        let sized = |m: &UvMap| {
            m.width == CORRECTION_SIZE && m.height == CORRECTION_SIZE && m.channels == 3
        };
        if corrections.dynamic_albedo.len() != NUM_BLENDSHAPES
            || !sized(&corrections.static_albedo)
            || !corrections.dynamic_albedo.iter().all(sized)
        {
            return Err(FaceError::InvalidInput(format!(
                "albedo corrections must be dR_0 and {NUM_BLENDSHAPES} dR_i of \
                 {CORRECTION_SIZE}x{CORRECTION_SIZE}x3"
            )));
        }
        let mut correction = corrections.static_albedo.clone();
        for (i, &w) in weights.0.iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            let mask = self.masks.mask(i);
            let dynamic = &corrections.dynamic_albedo[i];
            for ((out, d), &a) in correction
                .data
                .chunks_exact_mut(3)
                .zip(dynamic.data.chunks_exact(3))
                .zip(&mask.data)
            {
                let wa = w * a;
                for (o, d) in out.iter_mut().zip(d) {
                    *o += wa * d;
                }
            }
        }
        if !correction.is_finite() {
            return Err(FaceError::InvalidInput(
                "dR_0, a weight or the dR_i of a non-zero weight has NaN or infinite values".into(),
            ));
        }
        Ok(correction)
    }

    /// Equation (3): R = R_0^t + dR_0 + sum_i w_i A_i dR_i, on the grid of `mean_albedo`
    /// (R_0^t, any size, 3 channels).
    pub fn albedo(
        &self,
        mean_albedo: &UvMap,
        corrections: &PersonalCorrections,
        weights: &BlendshapeWeights,
    ) -> Result<UvMap> {
        corrections.validate()?;
        let correction = self.albedo_correction(corrections, weights)?;
        let mut albedo = mean_albedo.clone();
        for y in 0..albedo.height {
            for x in 0..albedo.width {
                let uv = texel_center_uv(x, y, albedo.width, albedo.height);
                let add = correction.sample(uv);
                for (o, a) in albedo.texel_mut(x, y).iter_mut().zip(add) {
                    *o += a;
                }
            }
        }
        Ok(albedo)
    }
}

/// A person's blendshapes in vertex space: base S_0 + F(dS_0) and, per blendshape,
/// S_i - S_0 + F(A_i dS_i).
#[derive(Clone, Debug, PartialEq)]
pub struct PersonalizedBlendshapes {
    pub vertex_count: usize,
    pub base: Vec<Vec3>,
    /// Blendshape-major: `deltas[i * V + v]`.
    pub deltas: Vec<Vec3>,
}

impl PersonalizedBlendshapes {
    /// Delta of blendshape `i` from the neutral, per vertex.
    pub fn delta(&self, i: usize) -> &[Vec3] {
        &self.deltas[i * self.vertex_count..(i + 1) * self.vertex_count]
    }

    /// Equation (2) for all vertices.
    pub fn shape(&self, weights: &BlendshapeWeights) -> Vec<Vec3> {
        let mut out = self.base.clone();
        for (i, &w) in weights.0.iter().enumerate() {
            if w == 0.0 {
                continue;
            }
            for (o, d) in out.iter_mut().zip(self.delta(i)) {
                *o += w * *d;
            }
        }
        out
    }

    /// Equation (2) at one vertex.
    pub fn vertex(&self, v: usize, weights: &BlendshapeWeights) -> Vec3 {
        weights
            .0
            .iter()
            .enumerate()
            .fold(self.base[v], |acc, (i, &w)| {
                acc + w * self.deltas[i * self.vertex_count + v]
            })
    }

    /// dS(v)/dw_i: equation (2) is linear in w, so this is the blendshape's delta.
    pub fn vertex_jacobian(&self, v: usize) -> [Vec3; NUM_BLENDSHAPES] {
        std::array::from_fn(|i| self.deltas[i * self.vertex_count + v])
    }

    /// The 68 landmark positions under `weights`.
    pub fn landmarks(
        &self,
        template: &Template,
        weights: &BlendshapeWeights,
    ) -> [Vec3; NUM_LANDMARKS] {
        template
            .landmarks_68
            .map(|v| self.vertex(v as usize, weights))
    }

    /// Magnitude of the personal correction of blendshape `i` relative to `template`, per
    /// vertex, in centimetres: |F(A_i dS_i)|.
    pub fn correction_magnitude(&self, template: &Template, i: usize) -> Vec<f32> {
        self.delta(i)
            .iter()
            .zip(template.expression_delta(i))
            .map(|(p, t)| (*p - *t).length())
            .collect()
    }
}
