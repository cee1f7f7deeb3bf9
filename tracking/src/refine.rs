//! Test-time refinement of TrackNet's parameters p = (w, R, t, gamma) on one frame.
//!
//! TrackNet regresses p from the crop in one pass; its projected landmarks can be a few
//! percent of the face size off the detected ones, which shows as mouth corners that do
//! not quite meet or a head that swims. A few damped Gauss-Newton (Levenberg-Marquardt) iterations on the
//! landmark reprojection error, started from TrackNet's estimate and held near it by
//! priors, remove most of that at a cost far below a frame time. This is the classic
//! analysis-by-synthesis fit of the optimisation-based trackers the paper compares with,
//! restricted to the paper's own model: shape S(w) of equation (2) with the person's
//! blendshapes, S~ = R S + t, and the perspective camera Phi; the landmark term is the
//! paper's L_lm (68 iBUG points marked on the template) evaluated on the real detector's
//! output, and the optional photometric term compares the image with albedo x SH
//! irradiance like the training's L_ph.
//!
//! Energy minimised (all terms dimensionless, so the defaults do not depend on how many
//! pixels the face covers):
//!
//! ```text
//! E = sum_k (c_k / C) rho(|B_k (Phi(R S_k(w) + t) - o_k)| 100 / s)          (landmarks)
//!   + (lambda_ph / N) sum_v rho_ph(100 |I(Phi(R S_v(w) + t))
//!                                       - a_v max(Y(R n_v(w)) gamma_c, 0)|)  (photometric)
//!   + lambda_w |w - w0|^2 + lambda_1 sum_i w_i
//!   + lambda_R |theta - theta0|^2 + lambda_t |(t - t0) / |t0_z||^2
//!   + lambda_gamma |gamma - gamma0|^2
//! ```
//!
//! - o_k: observed pixel of landmark k with confidence c_k (C = sum c_k); s: the size of
//!   the observed landmarks' bounding box in pixels, so a residual of 1 is 1 % of the face
//!   size (the NME unit of the paper's evaluation).
//! - B_k: identity for most landmarks. The jaw contour (iBUG 0-16) is a silhouette that a
//!   2D detector places on the visible outline: when the head turns, the detected point
//!   slides along the contour away from any fixed mesh vertex. So for jaw points B_k keeps
//!   the full residual across the observed contour and only `contour_slide` of it along
//!   the contour (the contour direction is taken from the neighbouring observed jaw points).
//! - rho: Huber's loss (quadratic up to `huber_scale`, linear beyond), so one wrong
//!   landmark (an occluding hand, a detector failure) pulls with a bounded force.
//! - theta: Euler angles (yaw, pitch, roll) in radians; translation differences are taken
//!   relative to the distance to the camera, the scale on which they affect the image.
//! - w is kept in [0, 1] (the paper's sigmoid range) by projection: after each step the
//!   weights are clamped, and weights at a bound whose gradient points outwards are held
//!   fixed for that step (an active set), so the step is taken in the remaining ones.
//! - gamma enters only through the photometric term; without it gamma is returned as given.
//!   The focal length is fixed (that of the frame's [`Intrinsics`]).
//!
//! The fitted points need not be the 68: [`Refiner::with_points`] takes any template
//! vertices under a detector's points (Face Mesh's 468 through their ICT correspondence,
//! issue 32) and any contour chains that slide like the jaw. The energy averages over the
//! points (c_k / C), so priors tuned for 68 weigh as much against 468; with unregularised
//! fits, 468 points with 1.5 px of noise recover the weights to 0.42 where 68 reach 1.36
//! (tests/refine.rs).
//!
//! Cost: only the fitted vertices' rows of the blendshapes are read (gathered once by
//! [`Refiner::new`]); an iteration linearises the 136 residual rows (68 points), builds the normal
//! equations of the free unknowns (at most 59; weights held at a bound drop out) and
//! solves them by Cholesky. The photometric term adds 3 rows per vertex and the 27
//! lighting unknowns.

use std::ops::RangeInclusive;

use face::camera::{HeadPose, Intrinsics, PoseJacobians};
use face::sh::{SH_COEFFICIENTS, sh_basis, sh_basis_gradient};
use face::{NUM_BLENDSHAPES, NUM_LANDMARKS, PersonalizedBlendshapes, Template};
use glam::{DVec3, Vec2, Vec3};
use image::RgbImage;

use crate::error::{Result, TrackingError};
use crate::params::FaceParams;

const NW: usize = NUM_BLENDSHAPES;
/// Offset of (yaw, pitch, roll, tx, ty, tz) in the unknown vector.
const POSE: usize = NW;
/// Geometry unknowns: w and the pose.
const NG: usize = NW + 6;
/// All unknowns, with the lighting gamma when the photometric term is on.
const NX: usize = NG + SH_COEFFICIENTS;

/// iBUG-68 indices of the jaw contour, whose detected points slide along the outline.
pub const JAW_CONTOUR: RangeInclusive<usize> = 0..=16;

/// The points a [`Refiner`] fits: the template vertex under each observed point, and the
/// chains of points that lie on an outline (an ordered list of point indices each), whose
/// detected positions slide along it (`RefineConfig::contour_slide`).
#[derive(Clone, Debug, PartialEq)]
pub struct FitPoints {
    pub vertices: Vec<u32>,
    pub contours: Vec<Vec<usize>>,
}

impl FitPoints {
    /// The 68 iBUG landmarks of the template with the jaw as the one contour (L_lm).
    pub fn ibug68(template: &Template) -> Self {
        Self {
            vertices: template.landmarks_68.to_vec(),
            contours: vec![JAW_CONTOUR.collect()],
        }
    }
}

/// One detected landmark.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LandmarkObservation {
    /// Index in the iBUG 68-point layout (the template's `landmarks_68` order).
    pub index: usize,
    /// Detected position in frame pixels (x right, y down; pixel (j, i) covers
    /// [j, j+1) x [i, i+1), the convention of [`Intrinsics::project`]).
    pub pixel: Vec2,
    /// Confidence >= 0; 0 ignores the point.
    pub weight: f32,
}

/// The detected landmarks of one frame, any subset of the 68 (a 66-point detector simply
/// leaves out the two it does not have).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LandmarkObservations {
    pub points: Vec<LandmarkObservation>,
}

impl LandmarkObservations {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn push(&mut self, index: usize, pixel: Vec2, weight: f32) {
        self.points.push(LandmarkObservation {
            index,
            pixel,
            weight,
        });
    }

    /// All 68 points in iBUG order with weight 1.
    pub fn from_68(points: &[Vec2; NUM_LANDMARKS]) -> Self {
        Self {
            points: points
                .iter()
                .enumerate()
                .map(|(index, &pixel)| LandmarkObservation {
                    index,
                    pixel,
                    weight: 1.0,
                })
                .collect(),
        }
    }

    /// Points in iBUG order with their confidences, `None` for points the detector does
    /// not have (e.g. the inner mouth corners 60 and 64 of a 66-point detector).
    pub fn from_ibug68(points: &[Option<(Vec2, f32)>; NUM_LANDMARKS]) -> Self {
        Self {
            points: points
                .iter()
                .enumerate()
                .filter_map(|(index, p)| {
                    p.map(|(pixel, weight)| LandmarkObservation {
                        index,
                        pixel,
                        weight,
                    })
                })
                .collect(),
        }
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }
}

/// Settings of [`Refiner::refine`]. Residuals are normalised (landmarks in percent of the
/// landmark box, colours in percent of full scale, translation relative to the distance),
/// so the defaults hold for any face size and resolution.
///
/// The prior weights are those of a maximum a posteriori fit with Gaussian errors:
/// lambda = sigma_lm^2 / (K sigma_p^2) for K landmarks detected with a per-coordinate
/// error sigma_lm (percent of the box) and a TrackNet error sigma_p in the parameter. The
/// translation prior assumes sigma_lm = 1.2 % (a 66-point detector on video), K = 66 and a
/// TrackNet error of 3 % of the distance; the weight and rotation priors are stronger than
/// that model says, because the detector's errors are biased, not only noisy (measured on
/// the held-out clips; see each field). A better detector calls for weaker priors.
#[derive(Clone, Debug, PartialEq)]
pub struct RefineConfig {
    /// Levenberg-Marquardt iterations (each one linearisation and one solve; a rejected
    /// step counts). 5 takes a TrackNet estimate most of the way; more gives diminishing
    /// returns on noisy landmarks.
    pub iterations: usize,
    /// Refine the blendshape weights w; `false` refines only the pose (and lighting).
    pub refine_weights: bool,
    /// lambda_w on |w - w0|^2 (default 32). Weights that move many landmarks far (jawOpen:
    /// about 95 in the landmark term's curvature) follow the landmarks largely; weights the
    /// landmarks barely see (a brow raise moves 5 points, a blink 2-4 eyelid points:
    /// curvatures around 0.5 to 1) stay with TrackNet instead of fitting the detector's
    /// noise and bias. Chosen with `weight_sparsity` on tuning clips of seed 9002, never on
    /// the held-out ones (tracking/README.md, `evaluate --tune`): with the calibrated
    /// TrackNet a weaker prior raised the expression MAE (1: 0.066 -> 0.072 at best); with
    /// the TrackNet fine-tuned on seed 6, 32 against 16: 0.0609 against 0.0610, 2.20 % NME
    /// against 2.21 % (16 raised the held-out clips' MAE, by less than 0.0001).
    pub weight_prior: f32,
    /// lambda_1 on sum_i w_i (the paper's L1 sparsity of L^w_reg; w >= 0 so it is linear;
    /// default 3.2, chosen with `weight_prior`): it pulls the weights the landmarks move
    /// by noise alone back towards 0.
    pub weight_sparsity: f32,
    /// lambda_R on |theta - theta0|^2 (radians; default 1000). The landmarks' curvature
    /// in rotation is 1500 to 4700, so this keeps the rotation largely TrackNet's: a 66-point
    /// detector's systematic offsets from the template's landmark vertices (brows, jaw
    /// outline) otherwise turn into head rotation. On the held-out clips a prior of 10
    /// lowered the landmark NME less (2.87 against 2.65 %) and raised the yaw and pitch
    /// errors from 3.4 / 1.5 to 4.9 / 3.7 degrees.
    pub rotation_prior: f32,
    /// lambda_t on |(t - t0) / |t0_z||^2 (default 250). Small against tx and ty (landmark
    /// curvature ~140000), felt in the depth (~3800), which the landmarks constrain least
    /// because it trades against the face's size and expression. Measured on the tuning
    /// clips (seed 9002) with the TrackNet of 2026-12-07 noon, whose depth is better than
    /// the points say: landmark NME 2.33 / 2.22 / 2.18 / 2.26 % at 25 / 250 / 1000 / 4000
    /// with OpenSeeFace (2.48 / 2.34 / 2.30 / 2.40 % with Face Mesh), expression MAE
    /// unchanged (0.0629-0.0630). 250 takes most of that gain and still corrects a start
    /// 2 cm off in depth by more than half in five iterations (tests/refine.rs), which 1000
    /// does not (44 %): real footage's depth is less certain than the clips'.
    pub translation_prior: f32,
    /// lambda_gamma on |gamma - gamma0|^2 (photometric term only).
    pub lighting_prior: f32,
    /// Huber scale of the landmark residuals, in percent of the landmark box: 3 is about
    /// 6 px on a 200 px face, the error of a good detector on a hard frame; larger errors
    /// count linearly.
    pub huber_scale: f32,
    /// Weight in [0, 1] of the along-contour part of jaw-contour residuals (1: plain
    /// point-to-point; 0: points may slide freely along the outline).
    pub contour_slide: f32,
    /// lambda_ph of the photometric term (used only when an image is given). A colour error
    /// of 10 % at every vertex then weighs like a landmark error of 1.4 %.
    pub photometric_weight: f32,
    /// Huber scale of the photometric residual, in percent of full colour scale: hair,
    /// hands, specular highlights and shadowed regions differ by far more than a good fit.
    pub photometric_huber: f32,
    /// Initial Levenberg-Marquardt damping mu, relative to the diagonal of the normal
    /// equations (Marquardt's scaling, which makes it independent of the unknowns' units).
    pub damping: f32,
    /// Stop when an accepted step lowers the energy by less than this fraction.
    pub tolerance: f32,
}

impl Default for RefineConfig {
    fn default() -> Self {
        Self {
            iterations: 5,
            refine_weights: true,
            weight_prior: 32.0,
            weight_sparsity: 3.2,
            rotation_prior: 1000.0,
            translation_prior: 250.0,
            lighting_prior: 1.0,
            huber_scale: 3.0,
            contour_slide: 0.1,
            photometric_weight: 0.02,
            photometric_huber: 10.0,
            damping: 1e-3,
            tolerance: 1e-6,
        }
    }
}

impl RefineConfig {
    /// No priors, no robust loss, point-to-point jaw: the plain least-squares fit (for
    /// exact synthetic data, and to measure what the priors do).
    pub fn unregularised() -> Self {
        Self {
            weight_prior: 0.0,
            weight_sparsity: 0.0,
            rotation_prior: 0.0,
            translation_prior: 0.0,
            lighting_prior: 0.0,
            huber_scale: f32::INFINITY,
            contour_slide: 1.0,
            ..Self::default()
        }
    }

    /// Checks that every value is in its range, naming the first bad one.
    pub fn validate(&self) -> Result<()> {
        let values = [
            ("weight_prior", self.weight_prior),
            ("weight_sparsity", self.weight_sparsity),
            ("rotation_prior", self.rotation_prior),
            ("translation_prior", self.translation_prior),
            ("lighting_prior", self.lighting_prior),
            ("photometric_weight", self.photometric_weight),
            ("damping", self.damping),
            ("tolerance", self.tolerance),
        ];
        for (name, v) in values {
            if !(v.is_finite() && v >= 0.0) {
                return Err(TrackingError::InvalidInput(format!(
                    "refinement `{name}` is {v}, must be a finite number >= 0"
                )));
            }
        }
        // The Huber scales may be infinite (plain least squares), never 0 or NaN.
        for (name, v) in [
            ("huber_scale", self.huber_scale),
            ("photometric_huber", self.photometric_huber),
        ] {
            if v.is_nan() || v <= 0.0 {
                return Err(TrackingError::InvalidInput(format!(
                    "refinement `{name}` is {v}, must be > 0"
                )));
            }
        }
        if !(0.0..=1.0).contains(&self.contour_slide) {
            return Err(TrackingError::InvalidInput(format!(
                "refinement `contour_slide` is {}, must be in [0, 1]",
                self.contour_slide
            )));
        }
        Ok(())
    }
}

/// The refined parameters and what the refinement did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Refined {
    pub params: FaceParams,
    pub report: RefineReport,
}

/// What a refinement did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefineReport {
    /// Weighted RMS landmark residual in pixels before and after: sqrt(sum_k c_k |B_k r_k|^2
    /// / sum_k c_k), i.e. the residual the fit sees (point-to-point, except across the
    /// contour for jaw points) without the robust loss. 0 without observations.
    pub initial_rms_px: f32,
    pub final_rms_px: f32,
    /// The energy E before and after (never larger after).
    pub initial_energy: f64,
    pub final_energy: f64,
    /// Iterations run (0 without observations).
    pub iterations: usize,
    /// The fit stopped because a step no longer lowered E by `tolerance`, or the gradient
    /// vanished, rather than by running out of iterations.
    pub converged: bool,
}

/// The frame's colours for the photometric term.
#[derive(Clone, Copy, Debug)]
pub struct PhotometricObservation<'a> {
    /// The frame, display-encoded RGB like the renderer's output it is compared with.
    pub image: &'a RgbImage,
    /// Albedo per vertex of the subset given to [`Refiner::with_photometric`], in the same
    /// order, RGB in [0, 1] (e.g. equation (3) sampled at the vertices' UVs).
    pub albedo: &'a [Vec3],
}

/// A person's model prepared for refining many frames: the landmark vertices' rows of
/// equation (2) gathered once, and optionally the photometric subset with its one-rings.
#[derive(Clone, Debug)]
pub struct Refiner {
    /// S_k for w = 0 (base + identity correction) at each fitted point's vertex (the 68
    /// landmarks, or the points of a dense detector).
    landmark_base: Vec<Vec3>,
    /// dS_k/dw_i at each landmark vertex (equation (2) is linear in w), as three
    /// coordinate rows (x_i), (y_i), (z_i) so that S_k(w) and the Jacobian rows are plain
    /// vectorisable inner products and multiply-adds over i.
    landmark_deltas: Vec<[[f32; NW]; 3]>,
    /// The model vertex under each fitted point.
    point_vertices: Vec<u32>,
    /// For each point, the contour chain it lies on and its place there.
    contour_of: Vec<Option<(usize, usize)>>,
    contours: Vec<Vec<usize>>,
    photometric: Option<PhotometricSubset>,
}

/// The vertices the photometric term samples, with what their normals need: the one-ring
/// triangles and those vertices' rows of equation (2), in a local numbering.
#[derive(Clone, Debug)]
struct PhotometricSubset {
    /// Local vertex (subset vertices first, then their ring neighbours): S for w = 0.
    base: Vec<Vec3>,
    /// dS/dw_i per local vertex.
    deltas: Vec<[Vec3; NW]>,
    /// One-ring triangles in local indices, those of subset vertex j at
    /// `ring[ring_start[j]..ring_start[j + 1]]`.
    ring: Vec<[u32; 3]>,
    ring_start: Vec<u32>,
}

impl PhotometricSubset {
    fn len(&self) -> usize {
        self.ring_start.len() - 1
    }
}

fn check_blendshapes(blendshapes: &PersonalizedBlendshapes) -> Result<()> {
    let v = blendshapes.vertex_count;
    if blendshapes.base.len() != v || blendshapes.deltas.len() != v * NW {
        return Err(TrackingError::InvalidInput(format!(
            "blendshapes of {v} vertices hold {} base positions and {} deltas (expected {v} \
             and {})",
            blendshapes.base.len(),
            blendshapes.deltas.len(),
            v * NW
        )));
    }
    Ok(())
}

fn gather(blendshapes: &PersonalizedBlendshapes, v: usize) -> Result<(Vec3, [Vec3; NW])> {
    let base = blendshapes.base[v];
    let deltas = blendshapes.vertex_jacobian(v);
    if !base.is_finite() || deltas.iter().any(|d| !d.is_finite()) {
        return Err(TrackingError::InvalidInput(format!(
            "the blendshapes have NaN or infinite values at vertex {v}"
        )));
    }
    Ok((base, deltas))
}

impl Refiner {
    /// Gathers the landmark vertices' rows of `blendshapes` (template or personalized)
    /// for the 68 iBUG landmarks ([`FitPoints::ibug68`]).
    pub fn new(blendshapes: &PersonalizedBlendshapes, template: &Template) -> Result<Self> {
        Self::with_points(blendshapes, &FitPoints::ibug68(template))
    }

    /// Gathers the rows of `points`' vertices: observations then index `points.vertices`
    /// (a dense detector's points through its correspondence with the template).
    pub fn with_points(blendshapes: &PersonalizedBlendshapes, points: &FitPoints) -> Result<Self> {
        check_blendshapes(blendshapes)?;
        if points.vertices.is_empty() {
            return Err(TrackingError::InvalidInput("no points to fit".into()));
        }
        let mut landmark_base = Vec::with_capacity(points.vertices.len());
        let mut landmark_deltas = Vec::with_capacity(points.vertices.len());
        for (k, &v) in points.vertices.iter().enumerate() {
            let v = v as usize;
            if v >= blendshapes.vertex_count {
                return Err(TrackingError::InvalidInput(format!(
                    "point {k} is vertex {v}, but the blendshapes have {} vertices",
                    blendshapes.vertex_count
                )));
            }
            let (base, deltas) = gather(blendshapes, v)?;
            landmark_base.push(base);
            landmark_deltas.push([0, 1, 2].map(|c| deltas.map(|d| d[c])));
        }
        let mut contour_of = vec![None; points.vertices.len()];
        for (c, chain) in points.contours.iter().enumerate() {
            for (place, &k) in chain.iter().enumerate() {
                match contour_of.get_mut(k) {
                    Some(slot @ None) => *slot = Some((c, place)),
                    Some(Some(_)) => {
                        return Err(TrackingError::InvalidInput(format!(
                            "point {k} lies on two contours"
                        )));
                    }
                    None => {
                        return Err(TrackingError::InvalidInput(format!(
                            "contour {c} names point {k}, but there are {} points",
                            points.vertices.len()
                        )));
                    }
                }
            }
        }
        Ok(Self {
            landmark_base,
            landmark_deltas,
            point_vertices: points.vertices.clone(),
            contour_of,
            contours: points.contours.clone(),
            photometric: None,
        })
    }

    /// How many points observations may index.
    pub fn point_count(&self) -> usize {
        self.landmark_base.len()
    }

    /// The two directions each of `used` is measured along: x and y, or for a point on a
    /// contour chain the direction across the observed chain and `contour_slide`'s square
    /// root times the one along it (the chain's direction from its neighbouring observed
    /// points), so that a point sliding along its outline costs little.
    pub(crate) fn residual_bases(
        &self,
        used: &[&LandmarkObservation],
        contour_slide: f32,
    ) -> Vec<[Vec2; 2]> {
        let mut on_contour: Vec<Vec<Option<Vec2>>> =
            self.contours.iter().map(|c| vec![None; c.len()]).collect();
        for o in used {
            if let Some((c, place)) = self.contour_of[o.index]
                && on_contour[c][place].is_none()
            {
                on_contour[c][place] = Some(o.pixel);
            }
        }
        let slide = contour_slide.sqrt();
        used.iter()
            .map(|o| {
                let Some((c, place)) = self.contour_of[o.index] else {
                    return [Vec2::X, Vec2::Y];
                };
                let chain = &on_contour[c];
                let prev = place.checked_sub(1).and_then(|i| chain[i]);
                let next = chain.get(place + 1).copied().flatten();
                let tangent = match (prev, next) {
                    (Some(a), Some(b)) => b - a,
                    (Some(a), None) => o.pixel - a,
                    (None, Some(b)) => b - o.pixel,
                    (None, None) => Vec2::ZERO,
                }
                .try_normalize();
                match tangent {
                    Some(t) => [t.perp(), t * slide],
                    None => [Vec2::X, Vec2::Y],
                }
            })
            .collect()
    }

    /// The model vertex under each fitted point.
    pub(crate) fn point_vertices(&self) -> &[u32] {
        &self.point_vertices
    }

    /// Fitted point `k`'s model-space position under `weights` (equation (2) at its vertex).
    pub(crate) fn point_position(&self, k: usize, weights: &[f32; NW]) -> Vec3 {
        self.landmark(k, weights)
    }

    /// Like [`Refiner::new`], and prepares the photometric term on `vertices` (a fixed
    /// subset of face vertices, e.g. a few hundred spread over the skin; the caller's
    /// albedo follows this order). Scans the template's triangles once for their
    /// one-rings, so build it once per person, not per frame.
    pub fn with_photometric(
        blendshapes: &PersonalizedBlendshapes,
        template: &Template,
        vertices: &[u32],
    ) -> Result<Self> {
        let mut refiner = Self::new(blendshapes, template)?;
        let count = blendshapes.vertex_count;
        if vertices.is_empty() {
            return Err(TrackingError::InvalidInput(
                "the photometric subset has no vertices".into(),
            ));
        }
        const NONE: u32 = u32::MAX;
        let mut local = vec![NONE; count];
        let mut order: Vec<u32> = Vec::with_capacity(vertices.len() * 7);
        for &v in vertices {
            if v as usize >= count {
                return Err(TrackingError::InvalidInput(format!(
                    "photometric vertex {v} is out of range (the blendshapes have {count})"
                )));
            }
            if local[v as usize] != NONE {
                return Err(TrackingError::InvalidInput(format!(
                    "photometric vertex {v} is listed twice"
                )));
            }
            local[v as usize] = order.len() as u32;
            order.push(v);
        }
        let subset = vertices.len();
        let mut per_vertex: Vec<Vec<[u32; 3]>> = vec![Vec::new(); subset];
        for tri in &template.triangles {
            if tri.iter().any(|&v| v as usize >= count) {
                return Err(TrackingError::InvalidInput(format!(
                    "template triangle {tri:?} indexes past the {count} blendshape vertices"
                )));
            }
            for &v in tri {
                let j = local[v as usize];
                if j != NONE && (j as usize) < subset {
                    per_vertex[j as usize].push(*tri);
                }
            }
        }
        let mut ring = Vec::new();
        let mut ring_start = Vec::with_capacity(subset + 1);
        for (j, tris) in per_vertex.iter().enumerate() {
            if tris.is_empty() {
                return Err(TrackingError::InvalidInput(format!(
                    "photometric vertex {} is on no triangle (no normal)",
                    vertices[j]
                )));
            }
            ring_start.push(ring.len() as u32);
            for tri in tris {
                let mut l = [0u32; 3];
                for (o, &v) in l.iter_mut().zip(tri) {
                    if local[v as usize] == NONE {
                        local[v as usize] = order.len() as u32;
                        order.push(v);
                    }
                    *o = local[v as usize];
                }
                ring.push(l);
            }
        }
        ring_start.push(ring.len() as u32);
        let mut base = Vec::with_capacity(order.len());
        let mut deltas = Vec::with_capacity(order.len());
        for &v in &order {
            let (b, d) = gather(blendshapes, v as usize)?;
            base.push(b);
            deltas.push(d);
        }
        refiner.photometric = Some(PhotometricSubset {
            base,
            deltas,
            ring,
            ring_start,
        });
        Ok(refiner)
    }

    /// Refines `init` (TrackNet's estimate) on the landmarks of one frame. Gamma is
    /// returned unchanged. Without observations (or only zero weights) returns `init`
    /// unchanged with an empty report.
    pub fn refine(
        &self,
        intrinsics: &Intrinsics,
        init: &FaceParams,
        observations: &LandmarkObservations,
        config: &RefineConfig,
    ) -> Result<Refined> {
        self.run(intrinsics, init, observations, None, config)
    }

    /// [`Refiner::refine`] plus the photometric term on the subset given to
    /// [`Refiner::with_photometric`], which also refines gamma. Vertices facing away from
    /// the camera (normal more than ~84 degrees from the view ray) or projecting outside
    /// the image at `init` are left out, decided once so the energy stays smooth; if none
    /// is left, this is [`Refiner::refine`]. Occlusion by other parts of the face is not
    /// tested: the robust loss absorbs it.
    pub fn refine_photometric(
        &self,
        intrinsics: &Intrinsics,
        init: &FaceParams,
        observations: &LandmarkObservations,
        photometric: &PhotometricObservation<'_>,
        config: &RefineConfig,
    ) -> Result<Refined> {
        self.run(intrinsics, init, observations, Some(photometric), config)
    }

    fn run(
        &self,
        intrinsics: &Intrinsics,
        init: &FaceParams,
        observations: &LandmarkObservations,
        photometric: Option<&PhotometricObservation<'_>>,
        config: &RefineConfig,
    ) -> Result<Refined> {
        let problem = Problem::new(self, intrinsics, init, observations, photometric, config)?;
        let Some(problem) = problem else {
            return Ok(Refined {
                params: *init,
                report: RefineReport {
                    initial_rms_px: 0.0,
                    final_rms_px: 0.0,
                    initial_energy: 0.0,
                    final_energy: 0.0,
                    iterations: 0,
                    converged: true,
                },
            });
        };
        Ok(problem.solve(config))
    }
}

/// One-call form of [`Refiner::new`] + [`Refiner::refine`]. For video, keep a [`Refiner`]
/// per person: gathering the landmark rows touches 68 x 53 scattered cache lines.
pub fn refine(
    blendshapes: &PersonalizedBlendshapes,
    template: &Template,
    intrinsics: &Intrinsics,
    init: &FaceParams,
    observations: &LandmarkObservations,
    config: &RefineConfig,
) -> Result<Refined> {
    Refiner::new(blendshapes, template)?.refine(intrinsics, init, observations, config)
}

/// One landmark residual: 2 rows b_i . (Phi(...) - o) scaled to percent of the box.
#[derive(Clone, Copy, Debug)]
struct LandmarkTerm {
    landmark: usize,
    observed: Vec2,
    /// Row directions in pixels (unit vectors times sqrt of their weight).
    basis: [Vec2; 2],
    /// c_k / C.
    weight: f64,
}

/// The frame's photometric data, restricted to the vertices used.
struct PhotoTerm<'a> {
    image: &'a RgbImage,
    albedo: &'a [Vec3],
    subset: &'a PhotometricSubset,
    /// Subset indices of the vertices used.
    used: Vec<usize>,
    /// lambda_ph / N.
    weight: f64,
}

/// Everything that depends only on the unknowns x, computed once per evaluation.
struct Eval {
    weights: [f32; NW],
    pose: HeadPose,
    gamma: [f32; SH_COEFFICIENTS],
    /// The rotation and its derivatives, once per evaluation.
    jacobians: PoseJacobians,
    /// Positions of the photometric subset's local vertices (empty without it), in f64:
    /// normals take differences of neighbouring positions ~10 cm from the origin and a few
    /// millimetres apart, where f32 would leave only four or five significant digits.
    photo_positions: Vec<DVec3>,
}

struct Problem<'a> {
    refiner: &'a Refiner,
    intrinsics: &'a Intrinsics,
    landmarks: Vec<LandmarkTerm>,
    /// 100 / s: pixels to percent of the landmark box.
    landmark_scale: f32,
    huber: f64,
    photo: Option<PhotoTerm<'a>>,
    photo_huber: f64,
    /// Number of unknowns in play: NG, or NX with the photometric term.
    n: usize,
    x0: [f32; NX],
    /// Prior weight per unknown (lambda_w, lambda_R, lambda_t / t0_z^2, lambda_gamma).
    prior: [f64; NX],
    sparsity: f64,
    refine_weights: bool,
}

fn to_x(p: &FaceParams) -> [f32; NX] {
    let mut x = [0.0; NX];
    x[..NW].copy_from_slice(&p.weights);
    x[POSE..POSE + 3].copy_from_slice(&p.pose.euler_rad.to_array());
    x[POSE + 3..NG].copy_from_slice(&p.pose.translation.to_array());
    x[NG..].copy_from_slice(&p.gamma);
    x
}

fn from_x(x: &[f32; NX]) -> FaceParams {
    let mut p = FaceParams::default();
    p.weights.copy_from_slice(&x[..NW]);
    p.pose.euler_rad = Vec3::from_slice(&x[POSE..POSE + 3]);
    p.pose.translation = Vec3::from_slice(&x[POSE + 3..NG]);
    p.gamma.copy_from_slice(&x[NG..]);
    p
}

/// Huber's loss in the form rho(r) = r^2 for r <= delta, 2 delta r - delta^2 beyond, and
/// its IRLS weight rho'(r) / (2 r).
pub(crate) fn huber(r: f64, delta: f64) -> (f64, f64) {
    if r <= delta {
        (r * r, 1.0)
    } else {
        (2.0 * delta * r - delta * delta, delta / r)
    }
}

impl<'a> Problem<'a> {
    fn new(
        refiner: &'a Refiner,
        intrinsics: &'a Intrinsics,
        init: &FaceParams,
        observations: &LandmarkObservations,
        photometric: Option<&PhotometricObservation<'a>>,
        config: &RefineConfig,
    ) -> Result<Option<Self>> {
        config.validate()?;
        if !init.is_finite() {
            return Err(TrackingError::InvalidInput(
                "the initial parameters contain NaN or infinite values".into(),
            ));
        }
        let f = intrinsics.focal_px;
        if !(f.is_finite() && f > 0.0 && intrinsics.cx.is_finite() && intrinsics.cy.is_finite()) {
            return Err(TrackingError::InvalidInput(format!(
                "camera intrinsics {intrinsics:?} are not a valid pinhole camera"
            )));
        }
        let point_count = refiner.point_count();
        for (i, o) in observations.points.iter().enumerate() {
            if o.index >= point_count {
                return Err(TrackingError::InvalidInput(format!(
                    "landmark observation {i} has index {}, beyond the {point_count}-point \
                     layout",
                    o.index
                )));
            }
            if !o.pixel.is_finite() || !o.weight.is_finite() || o.weight < 0.0 {
                return Err(TrackingError::InvalidInput(format!(
                    "landmark observation {i} (landmark {}) is at {} with weight {}: \
                     positions must be finite and weights finite and >= 0",
                    o.index, o.pixel, o.weight
                )));
            }
        }
        let used: Vec<&LandmarkObservation> = observations
            .points
            .iter()
            .filter(|o| o.weight > 0.0)
            .collect();
        if used.is_empty() {
            return Ok(None);
        }
        let total_weight: f64 = used.iter().map(|o| f64::from(o.weight)).sum();

        // Start inside the feasible set (TrackNet's sigmoid range).
        let mut x0 = to_x(init);
        x0[..NW].iter_mut().for_each(|w| *w = w.clamp(0.0, 1.0));
        let ev = refiner.eval(&x0, None);
        for o in &used {
            let p = ev.jacobians.rotation * refiner.landmark(o.index, &ev.weights)
                + ev.pose.translation;
            if intrinsics.project(p).is_none() {
                return Err(TrackingError::InvalidInput(format!(
                    "the initial pose puts landmark {} behind the camera (translation {})",
                    o.index, init.pose.translation
                )));
            }
        }

        // Face size: the observed landmarks' box, or the model's projected landmarks when
        // fewer than two distinct points are observed.
        let bbox = |points: &mut dyn Iterator<Item = Vec2>| {
            let (lo, hi) = points.fold(
                (Vec2::splat(f32::INFINITY), Vec2::splat(f32::NEG_INFINITY)),
                |(lo, hi), p| (lo.min(p), hi.max(p)),
            );
            (hi - lo).max_element()
        };
        let mut size = bbox(&mut used.iter().map(|o| o.pixel));
        if !(size.is_finite() && size >= 1.0) {
            let projected: Vec<Vec2> = (0..point_count)
                .filter_map(|k| {
                    intrinsics.project(
                        ev.jacobians.rotation * refiner.landmark(k, &ev.weights)
                            + ev.pose.translation,
                    )
                })
                .collect();
            size = bbox(&mut projected.into_iter());
        }
        let size = if size.is_finite() { size.max(1.0) } else { 1.0 };

        let bases = refiner.residual_bases(&used, config.contour_slide);
        let landmarks = used
            .iter()
            .zip(bases)
            .map(|(o, basis)| LandmarkTerm {
                landmark: o.index,
                observed: o.pixel,
                basis,
                weight: f64::from(o.weight) / total_weight,
            })
            .collect();

        let mut prior = [0.0f64; NX];
        prior[..NW].fill(f64::from(config.weight_prior));
        prior[POSE..POSE + 3].fill(f64::from(config.rotation_prior));
        let depth = f64::from(x0[NG - 1].abs()).max(1e-3);
        prior[POSE + 3..NG].fill(f64::from(config.translation_prior) / (depth * depth));
        prior[NG..].fill(f64::from(config.lighting_prior));

        let photo = match photometric {
            None => None,
            Some(obs) => {
                let subset = refiner.photometric.as_ref().ok_or_else(|| {
                    TrackingError::InvalidInput(
                        "photometric refinement needs a Refiner built with_photometric".into(),
                    )
                })?;
                if obs.albedo.len() != subset.len() {
                    return Err(TrackingError::InvalidInput(format!(
                        "{} albedo values for a photometric subset of {} vertices",
                        obs.albedo.len(),
                        subset.len()
                    )));
                }
                if let Some(i) = obs.albedo.iter().position(|a| !a.is_finite()) {
                    return Err(TrackingError::InvalidInput(format!(
                        "albedo of photometric vertex {i} is not finite"
                    )));
                }
                if obs.image.width() < 2 || obs.image.height() < 2 {
                    return Err(TrackingError::InvalidInput(
                        "the photometric term needs an image of at least 2 x 2 pixels".into(),
                    ));
                }
                let ev = refiner.eval(&x0, Some(subset));
                let (w, h) = (obs.image.width() as f32, obs.image.height() as f32);
                let used: Vec<usize> = (0..subset.len())
                    .filter(|&j| {
                        let p = ev.jacobians.rotation * ev.photo_positions[j].as_vec3()
                            + ev.pose.translation;
                        let n = ev.jacobians.rotation * subset.normal(j, &ev.photo_positions).0;
                        let facing = n.dot(-p.normalize_or_zero()) > 0.1;
                        let inside = intrinsics.project(p).is_some_and(|px| {
                            px.x >= 1.0 && px.y >= 1.0 && px.x <= w - 1.0 && px.y <= h - 1.0
                        });
                        facing && inside
                    })
                    .collect();
                (!used.is_empty()).then(|| PhotoTerm {
                    image: obs.image,
                    albedo: obs.albedo,
                    subset,
                    weight: f64::from(config.photometric_weight) / used.len() as f64,
                    used,
                })
            }
        };

        let problem = Self {
            refiner,
            intrinsics,
            landmarks,
            landmark_scale: 100.0 / size,
            huber: f64::from(config.huber_scale),
            n: if photo.is_some() { NX } else { NG },
            photo,
            photo_huber: f64::from(config.photometric_huber),
            x0,
            prior,
            sparsity: f64::from(config.weight_sparsity),
            refine_weights: config.refine_weights,
        };
        Ok(Some(problem))
    }

    /// Residual rows of landmark term `term` at `ev`, and their Jacobian if asked. `None`
    /// when the point is behind the camera.
    fn landmark_rows(
        &self,
        term: &LandmarkTerm,
        ev: &Eval,
        jacobian: Option<&mut [[f32; NX]; 2]>,
    ) -> Option<[f32; 2]> {
        let k = term.landmark;
        let point = self.refiner.landmark(k, &ev.weights);
        let s = self.landmark_scale;
        let Some(jacobian) = jacobian else {
            let pixel = self
                .intrinsics
                .project(ev.jacobians.rotation * point + ev.pose.translation)?;
            let d = pixel - term.observed;
            return Some(term.basis.map(|b| s * b.dot(d)));
        };
        let (pixel, d_pose, d_point) = ev.jacobians.project(self.intrinsics, point)?;
        let d = pixel - term.observed;
        let [dx, dy, dz] = &self.refiner.landmark_deltas[k];
        let mut out = [0.0; 2];
        for ((row, b), o) in jacobian.iter_mut().zip(term.basis).zip(&mut out) {
            let b = b * s;
            *o = b.dot(d);
            // d(row)/dS: b . d(pixel)/dS, then dS/dw_i = delta_i.
            let q = Vec3::new(b.dot(d_point[0]), b.dot(d_point[1]), b.dot(d_point[2]));
            for (((j, x), y), z) in row[..NW].iter_mut().zip(dx).zip(dy).zip(dz) {
                *j = q.x * x + q.y * y + q.z * z;
            }
            for (j, dp) in row[POSE..NG].iter_mut().zip(d_pose) {
                *j = b.dot(dp);
            }
            row[NG..].fill(0.0);
        }
        Some(out)
    }

    /// RGB residual rows (percent of full scale) of photometric vertex `j` at `ev`, and
    /// their Jacobian if asked. `None` behind the camera.
    fn photo_rows(
        &self,
        photo: &PhotoTerm<'_>,
        j: usize,
        ev: &Eval,
        jacobian: Option<&mut [[f32; NX]; 3]>,
    ) -> Option<[f32; 3]> {
        let subset = photo.subset;
        let point = ev.photo_positions[j].as_vec3();
        let (normal, len) = subset.normal(j, &ev.photo_positions);
        let n_cam = ev.jacobians.rotation * normal;
        let y = sh_basis(n_cam);
        let albedo = photo.albedo[j];
        let irradiance: [f32; 3] =
            std::array::from_fn(|c| (0..9).map(|k| ev.gamma[c * 9 + k] * y[k]).sum());
        let Some(jacobian) = jacobian else {
            let pixel = self
                .intrinsics
                .project(ev.jacobians.rotation * point + ev.pose.translation)?;
            let (colour, _) = sample_bilinear(photo.image, pixel);
            return Some(std::array::from_fn(|c| {
                100.0 * (colour[c] - albedo[c] * irradiance[c].max(0.0))
            }));
        };
        let (pixel, d_pose, d_point) = ev.jacobians.project(self.intrinsics, point)?;
        let (colour, gradient) = sample_bilinear(photo.image, pixel);
        let y_gradient = sh_basis_gradient(n_cam);

        // dm/dw_i for the unnormalised normal m = sum over the one-ring of (b - a) x (c - a).
        let mut dm = [Vec3::ZERO; NW];
        let p = &ev.photo_positions;
        let ring = &subset.ring[subset.ring_start[j] as usize..subset.ring_start[j + 1] as usize];
        for tri in ring {
            let [a, b, c] = tri.map(|v| v as usize);
            let (e1, e2) = ((p[b] - p[a]).as_vec3(), (p[c] - p[a]).as_vec3());
            let (da, db, dc) = (&subset.deltas[a], &subset.deltas[b], &subset.deltas[c]);
            for i in 0..NW {
                dm[i] += (db[i] - da[i]).cross(e2) + e1.cross(dc[i] - da[i]);
            }
        }
        let mut out = [0.0; 3];
        for (c, (row, o)) in jacobian.iter_mut().zip(&mut out).enumerate() {
            let lit = irradiance[c] > 0.0;
            *o = 100.0 * (colour[c] - albedo[c] * irradiance[c].max(0.0));
            // Image side: d I_c(Phi(R S + t)) = grad I_c . d(pixel).
            let g = gradient[c];
            // Shading side: d shade_c / d n_cam = albedo_c grad_n (Y(n) . gamma_c), zero
            // where the irradiance is clamped.
            let grad_y: Vec3 = if lit {
                (0..9).fold(Vec3::ZERO, |acc, k| {
                    acc + ev.gamma[c * 9 + k] * y_gradient[k]
                }) * albedo[c]
            } else {
                Vec3::ZERO
            };
            // Through n = m / |m| in model space: d n = (I - n n^T) dm / |m|, n_cam = R n.
            let h_model = ev.jacobians.rotation.transpose() * grad_y;
            let h = (h_model - normal * normal.dot(h_model)) / len;
            let q = Vec3::new(g.dot(d_point[0]), g.dot(d_point[1]), g.dot(d_point[2]));
            for i in 0..NW {
                let delta = subset.deltas[j][i];
                row[i] = 100.0 * (q.dot(delta) - h.dot(dm[i]));
            }
            for r in 0..3 {
                let dn = ev.jacobians.rotation_derivatives[r] * normal;
                row[POSE + r] = 100.0 * (g.dot(d_pose[r]) - grad_y.dot(dn));
            }
            for r in 3..6 {
                row[POSE + r] = 100.0 * g.dot(d_pose[r]);
            }
            row[NG..].fill(0.0);
            if lit {
                for k in 0..9 {
                    row[NG + c * 9 + k] = -100.0 * albedo[c] * y[k];
                }
            }
        }
        Some(out)
    }

    /// Energy E at x; `None` if a point falls behind the camera.
    fn energy(&self, x: &[f32; NX]) -> Option<f64> {
        let ev = self.refiner.eval(x, self.photo.as_ref().map(|p| p.subset));
        let mut e = 0.0;
        for term in &self.landmarks {
            let r = self.landmark_rows(term, &ev, None)?;
            let norm = f64::from(Vec2::from(r).length());
            e += term.weight * huber(norm, self.huber).0;
        }
        if let Some(photo) = &self.photo {
            for &j in &photo.used {
                let r = self.photo_rows(photo, j, &ev, None)?;
                let norm = f64::from(Vec3::from(r).length());
                e += photo.weight * huber(norm, self.photo_huber).0;
            }
        }
        Some(e + self.prior_energy(x))
    }

    fn prior_energy(&self, x: &[f32; NX]) -> f64 {
        let e: f64 = (x.iter().zip(&self.x0).zip(&self.prior))
            .take(self.n)
            .map(|((x, x0), lambda)| {
                let d = f64::from(x - x0);
                lambda * d * d
            })
            .sum();
        e + self.sparsity * x[..NW].iter().map(|&w| f64::from(w)).sum::<f64>()
    }

    /// Weighted RMS landmark residual in pixels (see [`RefineReport`]).
    fn rms_px(&self, x: &[f32; NX]) -> f32 {
        let ev = self.refiner.eval(x, None);
        let mut sum = 0.0;
        for term in &self.landmarks {
            if let Some(r) = self.landmark_rows(term, &ev, None) {
                sum += term.weight * f64::from(Vec2::from(r).length_squared());
            }
        }
        (sum.sqrt() / f64::from(self.landmark_scale)) as f32
    }

    /// Number of residual rows: 2 per landmark, 3 per photometric vertex.
    fn rows(&self) -> usize {
        2 * self.landmarks.len() + self.photo.as_ref().map_or(0, |p| 3 * p.used.len())
    }

    /// Linearises the residuals at x (IRLS weights of the robust loss at x): fills
    /// J~ = sqrt(omega) J transposed into `jt` (one contiguous row of all residuals per
    /// unknown, `rows()` long), r~ = sqrt(omega) r into `rt`, and the halved gradient
    /// g = J~^T r~ + prior gradient.
    ///
    /// The Gauss-Newton matrix H = J~^T J~ + priors is left to [`Problem::gram`], which
    /// computes it only for the unknowns the step can move: with J~ transposed each entry
    /// is one long inner product, where rank-one updates of H per residual row would spend
    /// their time in loop overhead on short triangular rows.
    fn linearize(
        &self,
        x: &[f32; NX],
        g: &mut [f64],
        jt: &mut [f32],
        rt: &mut [f32],
    ) -> Option<()> {
        let n = self.n;
        let m = self.rows();
        let ev = self.refiner.eval(x, self.photo.as_ref().map(|p| p.subset));
        let mut put = |row: usize, omega: f64, r: f32, j: &[f32; NX]| {
            let s = omega.sqrt() as f32;
            rt[row] = s * r;
            for (c, &v) in j[..n].iter().enumerate() {
                jt[c * m + row] = s * v;
            }
        };
        let mut row = 0;
        let mut rows2 = [[0.0f32; NX]; 2];
        for term in &self.landmarks {
            let r = self.landmark_rows(term, &ev, Some(&mut rows2))?;
            let omega = term.weight * huber(f64::from(Vec2::from(r).length()), self.huber).1;
            for q in 0..2 {
                put(row, omega, r[q], &rows2[q]);
                row += 1;
            }
        }
        if let Some(photo) = &self.photo {
            let mut rows3 = [[0.0f32; NX]; 3];
            for &j in &photo.used {
                let r = self.photo_rows(photo, j, &ev, Some(&mut rows3))?;
                let norm = f64::from(Vec3::from(r).length());
                let omega = photo.weight * huber(norm, self.photo_huber).1;
                for q in 0..3 {
                    put(row, omega, r[q], &rows3[q]);
                    row += 1;
                }
            }
        }
        for (i, gi) in g[..n].iter_mut().enumerate() {
            let ji = &jt[i * m..(i + 1) * m];
            *gi = ji
                .iter()
                .zip(&rt[..m])
                .map(|(a, b)| f64::from(*a) * f64::from(*b))
                .sum::<f64>()
                + self.prior[i] * f64::from(x[i] - self.x0[i]);
        }
        for gi in &mut g[..NW] {
            *gi += 0.5 * self.sparsity;
        }
        Some(())
    }

    /// H = J~^T J~ + priors restricted to the unknowns `free` (row-major, upper triangle
    /// and diagonal filled), from the `jt` of [`Problem::linearize`]. In f32 (twice the SIMD
    /// width of f64): the iteration's fixed point is where g vanishes, so only g needs full
    /// precision; H just steers.
    fn gram(&self, free: &[usize], jt: &[f32], h: &mut [f32]) {
        let m = self.rows();
        let nf = free.len();
        for (a, &i) in free.iter().enumerate() {
            let ji = &jt[i * m..(i + 1) * m];
            for (b, &k) in free.iter().enumerate().skip(a) {
                h[a * nf + b] = dot_f32(ji, &jt[k * m..(k + 1) * m]);
            }
            h[a * nf + a] += self.prior[i] as f32;
        }
    }

    /// Projected Levenberg-Marquardt from x0, with Nielsen's damping update.
    fn solve(&self, config: &RefineConfig) -> Refined {
        let n = self.n;
        let m = self.rows();
        let mut x = self.x0;
        // `Problem::new` checked every landmark is in front of the camera at x0.
        let initial_energy = self.energy(&x).unwrap_or(f64::INFINITY);
        let initial_rms_px = self.rms_px(&x);
        let tolerance = f64::from(config.tolerance);
        let mut energy = initial_energy;
        let mut mu = f64::from(config.damping);
        let mut nu = 2.0;
        let mut g = vec![0.0f64; n];
        let mut jt = vec![0.0f32; n * m];
        let mut rt = vec![0.0f32; m];
        let mut h = vec![0.0f32; n * n];
        let mut a = vec![0.0f64; n * n];
        let mut step = vec![0.0f64; n];
        let mut free: Vec<usize> = Vec::with_capacity(n);
        let mut stale = true;
        let mut converged = false;
        let mut iterations = 0;
        while iterations < config.iterations {
            if stale {
                if self.linearize(&x, &mut g, &mut jt, &mut rt).is_none() {
                    break;
                }
                // Active set: weights held by their bounds (the gradient pushes them out),
                // and all weights when they are not refined. Only the free unknowns enter
                // H and the solve: TrackNet's weights are mostly near 0, so after the
                // first step many sit at the bound and the system shrinks accordingly.
                free.clear();
                free.extend((0..n).filter(|&i| {
                    i >= NW
                        || (self.refine_weights
                            && !((x[i] <= 0.0 && g[i] > 0.0) || (x[i] >= 1.0 && g[i] < 0.0)))
                }));
                let gradient_norm = free.iter().map(|&i| g[i] * g[i]).sum::<f64>().sqrt();
                if gradient_norm <= 1e-12 * (1.0 + energy) {
                    converged = true;
                    break;
                }
                self.gram(&free, &jt, &mut h);
                stale = false;
            }
            iterations += 1;
            // (H + mu diag(H)) step = -g on the free unknowns (Marquardt's scaling; a floor
            // keeps unknowns the data do not see solvable).
            let nf = free.len();
            let max_diag = (0..nf)
                .map(|i| f64::from(h[i * nf + i]))
                .fold(0.0, f64::max);
            let floor = 1e-9 * max_diag.max(1e-12);
            for i in 0..nf {
                for j in i + 1..nf {
                    a[i * nf + j] = f64::from(h[i * nf + j]);
                }
                let d = f64::from(h[i * nf + i]).max(floor);
                a[i * nf + i] = d + mu * d;
                step[i] = -g[free[i]];
            }
            if !cholesky_solve(&mut a[..nf * nf], nf, &mut step[..nf]) {
                mu *= nu;
                nu *= 2.0;
                continue;
            }
            let mut candidate = x;
            for (s, &i) in step.iter().zip(&free) {
                candidate[i] += *s as f32;
            }
            for w in &mut candidate[..NW] {
                *w = w.clamp(0.0, 1.0);
            }
            // The decrease the quadratic model predicts for the step actually taken (after
            // clamping): E(x + d) ~ E(x) + 2 g.d + d.H.d with the halved g and H.
            for (t, &i) in step.iter_mut().zip(&free) {
                *t = f64::from(candidate[i]) - f64::from(x[i]);
            }
            let taken = &step[..nf];
            let linear: f64 = free.iter().zip(taken).map(|(&i, t)| g[i] * t).sum();
            let predicted = -(2.0 * linear + quadratic_form(&h[..nf * nf], nf, taken));
            match self.energy(&candidate) {
                Some(e) if e < energy && predicted > 0.0 => {
                    let decrease = energy - e;
                    let gain = decrease / predicted;
                    x = candidate;
                    energy = e;
                    stale = true;
                    mu *= (1.0 - (2.0 * gain - 1.0).powi(3)).max(1.0 / 3.0);
                    nu = 2.0;
                    // 1e-10: the residual is 1e5 times smaller than at the start, the f32
                    // floor.
                    if decrease <= tolerance * energy || energy <= 1e-10 * initial_energy {
                        converged = true;
                        break;
                    }
                }
                _ => {
                    // Nothing left the model can find at this precision: at the optimum.
                    if predicted <= tolerance * energy {
                        converged = true;
                        break;
                    }
                    mu *= nu;
                    nu *= 2.0;
                }
            }
        }
        let params = FaceParams {
            gamma: if self.photo.is_some() {
                from_x(&x).gamma
            } else {
                from_x(&self.x0).gamma
            },
            ..from_x(&x)
        };
        let report = RefineReport {
            initial_rms_px,
            final_rms_px: self.rms_px(&x),
            initial_energy,
            final_energy: energy,
            iterations,
            converged,
        };
        Refined { params, report }
    }
}

/// Inner product with four independent partial sums: a single running sum is one long
/// dependency chain of additions (latency-bound, and the compiler may not reorder it).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut acc = [0.0f64; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let tail: f64 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for q in 0..4 {
            acc[q] += x[q] * y[q];
        }
    }
    (acc[0] + acc[1]) + (acc[2] + acc[3]) + tail
}

/// d^T H d for H given by its upper triangle (row-major n x n).
fn quadratic_form(h: &[f32], n: usize, d: &[f64]) -> f64 {
    let mut sum = 0.0;
    for i in 0..n {
        let row = &h[i * n..(i + 1) * n];
        let off: f64 = (i + 1..n).map(|k| f64::from(row[k]) * d[k]).sum();
        sum += d[i] * (f64::from(row[i]) * d[i] + 2.0 * off);
    }
    sum
}

/// f32 inner product with eight independent partial sums (two SIMD registers' worth), so
/// the compiler can vectorise it: a single running sum is a serial chain it may not
/// reorder.
fn dot_f32(a: &[f32], b: &[f32]) -> f32 {
    let mut acc = [0.0f32; 8];
    let (ca, cb) = (a.chunks_exact(8), b.chunks_exact(8));
    let tail: f32 = ca
        .remainder()
        .iter()
        .zip(cb.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in ca.zip(cb) {
        for q in 0..8 {
            acc[q] += x[q] * y[q];
        }
    }
    ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7])) + tail
}

/// Solves A x = b in place (b becomes x) for a symmetric positive definite A given by its
/// upper triangle (row-major n x n, overwritten by the factor U of A = U^T U). Returns
/// `false` if A is not positive definite.
///
/// Hand-written: the systems are at most 86 x 86 and dense, one per iteration; a linear
/// algebra dependency would bring far more than these lines. Outer-product form: each
/// step updates the remaining rows with a multiply-add along contiguous rows, which
/// vectorises (the inner-product form is a chain of dependent additions).
pub(crate) fn cholesky_solve(a: &mut [f64], n: usize, b: &mut [f64]) -> bool {
    for k in 0..n {
        let (head, tail) = a.split_at_mut((k + 1) * n);
        let row_k = &mut head[k * n..];
        let d = row_k[k];
        if !(d > 0.0 && d.is_finite()) {
            return false;
        }
        let d = d.sqrt();
        row_k[k] = d;
        for v in &mut row_k[k + 1..] {
            *v /= d;
        }
        let row_k = &row_k[..];
        for i in k + 1..n {
            let f = row_k[i];
            if f == 0.0 {
                continue;
            }
            let row_i = &mut tail[(i - k - 1) * n..(i - k) * n];
            for (x, &u) in row_i[i..].iter_mut().zip(&row_k[i..]) {
                *x -= f * u;
            }
        }
    }
    // U^T y = b (column k of U^T is row k of U), then U x = y.
    for k in 0..n {
        let row_k = &a[k * n..(k + 1) * n];
        b[k] /= row_k[k];
        let y = b[k];
        for (bi, &u) in b[k + 1..].iter_mut().zip(&row_k[k + 1..]) {
            *bi -= u * y;
        }
    }
    for i in (0..n).rev() {
        let row_i = &a[i * n..(i + 1) * n];
        let s = b[i] - dot(&row_i[i + 1..], &b[i + 1..]);
        b[i] = s / row_i[i];
    }
    true
}

/// Bilinear colour (RGB in [0, 1]) at continuous pixel position `p` and its gradient per
/// channel; pixel (j, i) has its centre at (j + 0.5, i + 0.5) and taps outside the image
/// repeat the edge (zero gradient across it).
fn sample_bilinear(image: &RgbImage, p: Vec2) -> ([f32; 3], [Vec2; 3]) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let axis = |t: f32, n: usize| -> (usize, usize, f32, f32) {
        let last = (n - 1) as f32;
        let inside = (0.0..last).contains(&t);
        let t = t.clamp(0.0, last);
        let i0 = (t.floor() as usize).min(n.saturating_sub(2));
        let f = t - i0 as f32;
        (i0, (i0 + 1).min(n - 1), f, if inside { 1.0 } else { 0.0 })
    };
    let (x0, x1, fx, gx) = axis(p.x - 0.5, w);
    let (y0, y1, fy, gy) = axis(p.y - 0.5, h);
    let raw = image.as_raw();
    let px = |x: usize, y: usize, c: usize| f32::from(raw[(y * w + x) * 3 + c]) / 255.0;
    let mut colour = [0.0; 3];
    let mut gradient = [Vec2::ZERO; 3];
    for c in 0..3 {
        let (a, b, cc, d) = (px(x0, y0, c), px(x1, y0, c), px(x0, y1, c), px(x1, y1, c));
        let top = a + (b - a) * fx;
        let bottom = cc + (d - cc) * fx;
        colour[c] = top + (bottom - top) * fy;
        gradient[c] = Vec2::new(
            gx * ((b - a) + ((d - cc) - (b - a)) * fy),
            gy * (bottom - top),
        );
    }
    (colour, gradient)
}

impl Refiner {
    /// S(v) of landmark `k` under `weights` (equation (2) at one vertex).
    fn landmark(&self, k: usize, weights: &[f32; NW]) -> Vec3 {
        let [dx, dy, dz] = &self.landmark_deltas[k];
        self.landmark_base[k]
            + Vec3::new(
                dot_f32(weights, dx),
                dot_f32(weights, dy),
                dot_f32(weights, dz),
            )
    }

    fn eval(&self, x: &[f32; NX], photo: Option<&PhotometricSubset>) -> Eval {
        let p = from_x(x);
        let photo_positions = photo
            .map(|s| {
                s.base
                    .iter()
                    .zip(&s.deltas)
                    .map(|(b, d)| {
                        p.weights
                            .iter()
                            .zip(d)
                            .fold(b.as_dvec3(), |acc, (&w, delta)| {
                                acc + f64::from(w) * delta.as_dvec3()
                            })
                    })
                    .collect()
            })
            .unwrap_or_default();
        Eval {
            weights: p.weights,
            jacobians: PoseJacobians::new(p.pose),
            pose: p.pose,
            gamma: p.gamma,
            photo_positions,
        }
    }
}

impl PhotometricSubset {
    /// Unit normal (model space) of subset vertex `j` and the length of the unnormalised
    /// area-weighted sum m (as `face::geometry::vertex_normals`).
    fn normal(&self, j: usize, positions: &[DVec3]) -> (Vec3, f32) {
        let ring = &self.ring[self.ring_start[j] as usize..self.ring_start[j + 1] as usize];
        let m = ring.iter().fold(DVec3::ZERO, |acc, tri| {
            let [a, b, c] = tri.map(|v| positions[v as usize]);
            acc + (b - a).cross(c - a)
        });
        let len = m.length();
        if len > 0.0 && len.is_finite() {
            ((m / len).as_vec3(), len as f32)
        } else {
            (Vec3::Z, 1.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::OnceLock;

    use face::FaceModel;

    fn model() -> &'static (Template, PersonalizedBlendshapes) {
        static MODEL: OnceLock<(Template, PersonalizedBlendshapes)> = OnceLock::new();
        MODEL.get_or_init(|| {
            let path = face::template::default_template_path();
            let template = Template::load_safetensors(&path)
                .unwrap_or_else(|e| panic!("these tests need the template at {path:?}: {e}"));
            let model = FaceModel::new(template);
            let blendshapes = model.template_blendshapes();
            (model.template, blendshapes)
        })
    }

    /// Deterministic pseudo-random numbers in [-1, 1].
    fn noise(seed: u32) -> f32 {
        let mut x = seed.wrapping_mul(0x9E37_79B9) ^ 0x85EB_CA6B;
        x ^= x >> 16;
        x = x.wrapping_mul(0x7FEB_352D);
        x ^= x >> 15;
        x = x.wrapping_mul(0x846C_A68B);
        x ^= x >> 16;
        (x as f32 / u32::MAX as f32) * 2.0 - 1.0
    }

    fn params() -> FaceParams {
        let mut p = FaceParams::default();
        for (i, w) in p.weights.iter_mut().enumerate() {
            *w = 0.35 + 0.25 * noise(i as u32);
        }
        p.pose = HeadPose::from_degrees(20.0, -6.0, 4.0, Vec3::new(1.5, -1.0, -50.0));
        for (i, g) in p.gamma.iter_mut().enumerate() {
            *g += 0.05 * noise(500 + i as u32);
        }
        p
    }

    fn k() -> Intrinsics {
        Intrinsics::centered(320, 240, 400.0)
    }

    /// The observed landmarks: the model's own projection, moved by a few pixels, so the
    /// residuals are not zero.
    fn observations(refiner: &Refiner, p: &FaceParams) -> LandmarkObservations {
        let mut obs = LandmarkObservations::new();
        let r = p.pose.rotation();
        for lm in 0..refiner.point_count() {
            let s = refiner.landmark(lm, &p.weights);
            let px = k()
                .project(r * s + p.pose.translation)
                .unwrap_or_else(|| panic!("landmark {lm} behind the camera"));
            let offset = Vec2::new(noise(lm as u32 * 2), noise(lm as u32 * 2 + 1)) * 4.0;
            obs.push(lm, px + offset, 0.5 + 0.5 * noise(900 + lm as u32).abs());
        }
        obs
    }

    /// Residual rows at x, and their Jacobian rows when asked.
    type RowsFn<'a> = dyn Fn(&[f32; NX], Option<&mut Vec<[f32; NX]>>) -> Vec<f32> + 'a;

    /// Central differences of every residual row against the analytic Jacobian. `steps`
    /// per unknown; rows compared relative to the largest entry of their column.
    fn check_jacobian(
        problem: &Problem<'_>,
        x: &[f32; NX],
        rows: &RowsFn<'_>,
        steps: &dyn Fn(usize) -> f32,
        tolerance: f32,
    ) {
        let mut jacobian = Vec::new();
        let r0 = rows(x, Some(&mut jacobian));
        assert_eq!(r0.len(), jacobian.len());
        for col in 0..problem.n {
            let h = steps(col);
            let (mut plus, mut minus) = (*x, *x);
            plus[col] += h;
            minus[col] -= h;
            let (rp, rm) = (rows(&plus, None), rows(&minus, None));
            let scale = jacobian
                .iter()
                .map(|j| j[col].abs())
                .fold(0.0f32, f32::max)
                .max(1e-3);
            for (i, row) in jacobian.iter().enumerate() {
                let fd = (rp[i] - rm[i]) / (2.0 * h);
                let err = (fd - row[col]).abs() / scale;
                assert!(
                    err < tolerance,
                    "row {i}, unknown {col}: analytic {} vs finite difference {fd} (column scale {scale})",
                    row[col]
                );
            }
        }
    }

    #[test]
    fn landmark_jacobian_matches_finite_differences() {
        let (template, blendshapes) = model();
        let refiner = Refiner::new(blendshapes, template).unwrap_or_else(|e| panic!("{e}"));
        check_landmark_jacobian(&refiner);
    }

    /// A dense point set (every 23rd face vertex, as a 468-point detector's correspondence
    /// would give) with two contour chains: the same Jacobian check.
    #[test]
    fn dense_point_jacobian_matches_finite_differences() {
        let (template, blendshapes) = model();
        let vertices: Vec<u32> = template.face_vertices().step_by(23).collect();
        let n = vertices.len();
        assert!(n > 300, "{n} points");
        let points = FitPoints {
            vertices,
            contours: vec![(0..20).collect(), (100..140).step_by(3).collect()],
        };
        let refiner = Refiner::with_points(blendshapes, &points).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(refiner.point_count(), n);
        check_landmark_jacobian(&refiner);
        // Chains that overlap or name a point that is not there are refused.
        for contours in [vec![vec![1, 2], vec![2, 3]], vec![vec![n]]] {
            let bad = FitPoints {
                vertices: points.vertices.clone(),
                contours,
            };
            assert!(Refiner::with_points(blendshapes, &bad).is_err());
        }
        let none = FitPoints {
            vertices: vec![],
            contours: vec![],
        };
        assert!(Refiner::with_points(blendshapes, &none).is_err());
    }

    fn check_landmark_jacobian(refiner: &Refiner) {
        let refiner = refiner.clone();
        let p = params();
        let obs = observations(&refiner, &p);
        let config = RefineConfig {
            contour_slide: 0.3,
            ..RefineConfig::default()
        };
        let intrinsics = k();
        let problem = Problem::new(&refiner, &intrinsics, &p, &obs, None, &config)
            .unwrap_or_else(|e| panic!("{e}"))
            .unwrap_or_else(|| panic!("no problem built"));
        assert_eq!(problem.n, NG);
        let rows = |x: &[f32; NX], jac: Option<&mut Vec<[f32; NX]>>| {
            let ev = refiner.eval(x, None);
            let mut out = Vec::new();
            let mut j2 = [[0.0f32; NX]; 2];
            let want = jac.is_some();
            let mut rows_j = Vec::new();
            for term in &problem.landmarks {
                let r = if want {
                    problem.landmark_rows(term, &ev, Some(&mut j2))
                } else {
                    problem.landmark_rows(term, &ev, None)
                }
                .unwrap_or_else(|| panic!("behind the camera"));
                out.extend(r);
                rows_j.extend(j2);
            }
            if let Some(j) = jac {
                *j = rows_j;
            }
            out
        };
        let steps = |col: usize| match col {
            c if c < NW => 1e-2,
            c if c < POSE + 3 => 1e-3,
            _ => 1e-2,
        };
        check_jacobian(&problem, &problem.x0, &rows, &steps, 2e-3);
        // The Jacobian branch and the residual-only branch agree on the residuals.
        let ev = refiner.eval(&problem.x0, None);
        let mut j2 = [[0.0f32; NX]; 2];
        for term in &problem.landmarks {
            let a = problem.landmark_rows(term, &ev, Some(&mut j2));
            let b = problem.landmark_rows(term, &ev, None);
            let (Some(a), Some(b)) = (a, b) else {
                panic!("behind the camera")
            };
            assert!((Vec2::from(a) - Vec2::from(b)).length() < 1e-3);
        }
    }

    /// An image whose colour is linear in the pixel position (R = x, G = y, B constant;
    /// exact in u8 for 200 x 200), so bilinear sampling is linear everywhere inside and its
    /// finite differences are exact.
    fn ramp_image() -> RgbImage {
        RgbImage::from_fn(200, 200, |x, y| image::Rgb([x as u8, y as u8, 128]))
    }

    #[test]
    fn photometric_jacobian_matches_finite_differences() {
        let (template, blendshapes) = model();
        let face = template.face_vertices();
        let subset: Vec<u32> = face.clone().step_by(97).collect();
        let refiner = Refiner::with_photometric(blendshapes, template, &subset)
            .unwrap_or_else(|e| panic!("{e}"));
        let albedo: Vec<Vec3> = (0..subset.len())
            .map(|i| Vec3::new(0.6, 0.45, 0.4) + 0.1 * noise(7000 + i as u32))
            .collect();
        let image = ramp_image();
        let photo = PhotometricObservation {
            image: &image,
            albedo: &albedo,
        };
        let mut p = params();
        p.pose.translation = Vec3::new(0.5, 0.0, -40.0);
        let intrinsics = Intrinsics::centered(200, 200, 300.0);
        let mut obs = LandmarkObservations::new();
        obs.push(30, Vec2::new(100.0, 100.0), 1.0);
        obs.push(8, Vec2::new(100.0, 150.0), 1.0);
        let config = RefineConfig::default();
        let problem = Problem::new(&refiner, &intrinsics, &p, &obs, Some(&photo), &config)
            .unwrap_or_else(|e| panic!("{e}"))
            .unwrap_or_else(|| panic!("no problem built"));
        assert_eq!(problem.n, NX);
        let Some(term) = problem.photo.as_ref() else {
            panic!("no photometric vertex is visible")
        };
        assert!(term.used.len() > 20, "{} vertices used", term.used.len());
        let rows = |x: &[f32; NX], jac: Option<&mut Vec<[f32; NX]>>| {
            let ev = refiner.eval(x, Some(term.subset));
            let mut out = Vec::new();
            let mut j3 = [[0.0f32; NX]; 3];
            let want = jac.is_some();
            let mut rows_j = Vec::new();
            for &j in &term.used {
                let r = if want {
                    problem.photo_rows(term, j, &ev, Some(&mut j3))
                } else {
                    problem.photo_rows(term, j, &ev, None)
                }
                .unwrap_or_else(|| panic!("behind the camera"));
                out.extend(r);
                rows_j.extend(j3);
            }
            if let Some(j) = jac {
                *j = rows_j;
            }
            out
        };
        let steps = |col: usize| match col {
            c if c < NW => 2e-3,
            c if c < POSE + 3 => 1e-3,
            c if c < NG => 1e-2,
            _ => 1e-2,
        };
        check_jacobian(&problem, &problem.x0, &rows, &steps, 5e-3);
    }

    #[test]
    fn bilinear_gradient_matches_finite_differences_inside_a_cell() {
        let image = RgbImage::from_fn(16, 12, |x, y| {
            image::Rgb([
                (x * 37 % 251) as u8,
                ((x * 11 + y * 29) % 253) as u8,
                (y * 53 % 241) as u8,
            ])
        });
        for (i, p) in [
            Vec2::new(3.3, 4.9),
            Vec2::new(10.71, 2.2),
            Vec2::new(8.05, 9.6),
        ]
        .into_iter()
        .enumerate()
        {
            let (_, gradient) = sample_bilinear(&image, p);
            let h = 1e-3;
            for (c, grad) in gradient.iter().enumerate() {
                let fx = (sample_bilinear(&image, p + Vec2::X * h).0[c]
                    - sample_bilinear(&image, p - Vec2::X * h).0[c])
                    / (2.0 * h);
                let fy = (sample_bilinear(&image, p + Vec2::Y * h).0[c]
                    - sample_bilinear(&image, p - Vec2::Y * h).0[c])
                    / (2.0 * h);
                assert!((fx - grad.x).abs() < 2e-3, "point {i} channel {c} x");
                assert!((fy - grad.y).abs() < 2e-3, "point {i} channel {c} y");
            }
        }
        // Pixel centres: the sample is the pixel itself.
        let (c, _) = sample_bilinear(&image, Vec2::new(5.5, 7.5));
        let px = image.get_pixel(5, 7);
        for ch in 0..3 {
            assert!((c[ch] - f32::from(px[ch]) / 255.0).abs() < 1e-6);
        }
    }

    #[test]
    fn cholesky_solves_a_known_system() {
        // A = L L^T with a known L; b = A x for a known x.
        let n = 5;
        let l: Vec<f64> = (0..n * n)
            .map(|i| {
                let (r, c) = (i / n, i % n);
                if c > r {
                    0.0
                } else if c == r {
                    1.0 + r as f64
                } else {
                    0.3 * (r + 2 * c) as f64 - 0.5
                }
            })
            .collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| l[i * n + k] * l[j * n + k]).sum();
            }
        }
        let x: Vec<f64> = (0..n).map(|i| i as f64 - 1.5).collect();
        let mut b: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| a[i * n + j] * x[j]).sum())
            .collect();
        // Only the upper triangle is read.
        for i in 0..n {
            for j in 0..i {
                a[i * n + j] = f64::NAN;
            }
        }
        assert!(cholesky_solve(&mut a, n, &mut b));
        for i in 0..n {
            assert!((b[i] - x[i]).abs() < 1e-10, "{b:?}");
        }
        let mut not_pd = vec![1.0, 2.0, 2.0, 1.0];
        assert!(!cholesky_solve(&mut not_pd, 2, &mut [1.0, 1.0]));
    }

    #[test]
    fn huber_is_continuous_with_matching_slope() {
        let delta = 3.0;
        let (below, _) = huber(delta - 1e-9, delta);
        let (above, w) = huber(delta + 1e-9, delta);
        assert!((below - above).abs() < 1e-6);
        assert!((w - 1.0).abs() < 1e-6);
        let (e, w) = huber(10.0, delta);
        assert_eq!(e, 2.0 * 3.0 * 10.0 - 9.0);
        assert_eq!(w, 0.3);
    }
}
