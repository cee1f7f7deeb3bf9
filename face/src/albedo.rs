//! The procedural mean albedo R_0 of equation (3).
//!
//! The paper learns albedo corrections on top of a mean albedo R_0 in UV space. ICT FaceKit
//! ships no texture, so R_0 is authored here from the template alone, deterministically, so
//! that every machine (and the Python training code, which reads the exported maps) agrees on
//! it bit for bit without shipping an image.
//!
//! The upstream UVs form UDIM-like tiles, one per material; each tile becomes one
//! [`AlbedoLayer`] map. Skin colour is a function of the 3D position on the neutral S_0
//! rather than of UV, so that the face tile and the head tile agree across their seams; facial
//! features (lips, brows, eyelids) are drawn from the 68 landmarks' UVs, whose contours the
//! UV parsing map T ([`crate::parsing`]) shares through the `pub(crate)` helpers below.

use glam::{Vec2, Vec3};

use crate::template::{NUM_LANDMARKS, Template};
use crate::uv::{UvMap, rasterize_uv_triangle, texel_center_uv};

/// Side of every albedo layer map. Four times the correction maps' 128, so that lips, lid
/// margins and the iris keep sharp edges while R_0 stays small enough to regenerate at start.
pub const ALBEDO_SIZE: usize = 512;

/// Texels each chart is grown into empty space, so bilinear sampling and mipmapping at a
/// chart border read the chart's own colour instead of the fill colour.
const PAD_TEXELS: usize = 6;

/// One UV tile of the template and its albedo map.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AlbedoLayer {
    /// `M_Face`: the paper's face region; the only layer the corrections apply to.
    Face,
    /// `M_BackHead`: back of the head, neck, mouth socket and eye sockets.
    Head,
    GumsTongue,
    Teeth,
    /// The outer eyeball shell (`M_Sclera*`); both eyes share one layout.
    Eyeball,
    Eyelashes,
}

impl AlbedoLayer {
    pub const ALL: [AlbedoLayer; 6] = [
        AlbedoLayer::Face,
        AlbedoLayer::Head,
        AlbedoLayer::GumsTongue,
        AlbedoLayer::Teeth,
        AlbedoLayer::Eyeball,
        AlbedoLayer::Eyelashes,
    ];

    /// Position in [`AlbedoLayer::ALL`] and in [`MeanAlbedo::layers`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The tile's offset in u: a template UV minus this lies in the layer's [0, 1]^2.
    pub fn uv_offset(self) -> f32 {
        match self {
            AlbedoLayer::Face | AlbedoLayer::Eyeball => 0.0,
            AlbedoLayer::Head => 1.0,
            AlbedoLayer::GumsTongue => 2.0,
            AlbedoLayer::Teeth => 3.0,
            AlbedoLayer::Eyelashes => 6.0,
        }
    }

    /// Short lowercase name for file names and messages.
    pub fn name(self) -> &'static str {
        match self {
            AlbedoLayer::Face => "face",
            AlbedoLayer::Head => "head",
            AlbedoLayer::GumsTongue => "gums_tongue",
            AlbedoLayer::Teeth => "teeth",
            AlbedoLayer::Eyeball => "eyeball",
            AlbedoLayer::Eyelashes => "eyelashes",
        }
    }
}

/// The albedo layer a triangle is textured from, or `None` when it is not drawn.
///
/// Lacrimal fluid, eye blend and eye occlusion are transparent helper meshes. The iris disk
/// (`M_Iris*`) is `None` too: it sits just behind the eyeball shell and even pokes through it
/// at the limbus, while the shell's UVs run continuously over the cornea, so R_0 paints iris
/// and pupil onto the shell's layout; drawing the disk with the same layer (its UVs map the
/// iris radially in another way) would put sclera texels into the iris ring.
pub fn triangle_layer(template: &Template, triangle: usize) -> Option<AlbedoLayer> {
    match template.triangle_material(triangle)? {
        "M_Face" => Some(AlbedoLayer::Face),
        "M_BackHead" => Some(AlbedoLayer::Head),
        "M_GumsTongue" => Some(AlbedoLayer::GumsTongue),
        "M_Teeth" => Some(AlbedoLayer::Teeth),
        "M_ScleraLeft" | "M_ScleraRight" => Some(AlbedoLayer::Eyeball),
        "M_EyeLashes" => Some(AlbedoLayer::Eyelashes),
        _ => None,
    }
}

/// R_0: one [`ALBEDO_SIZE`]^2 RGB map per [`AlbedoLayer`], display-encoded values in [0, 1].
#[derive(Clone, Debug, PartialEq)]
pub struct MeanAlbedo {
    /// In [`AlbedoLayer::ALL`] order.
    pub layers: Vec<UvMap>,
}

impl MeanAlbedo {
    /// The face tile: the paper's R_0, the layer that equation (3)'s corrections apply to.
    pub fn face(&self) -> &UvMap {
        self.layer(AlbedoLayer::Face)
    }

    pub fn layer(&self, layer: AlbedoLayer) -> &UvMap {
        &self.layers[layer.index()]
    }

    /// Paints every layer from the template's geometry and landmarks.
    pub fn generate(template: &Template) -> MeanAlbedo {
        let regions = TemplateRegions::new(template);
        let layers = AlbedoLayer::ALL
            .iter()
            .map(|&layer| paint_layer(&regions, layer))
            .collect();
        MeanAlbedo { layers }
    }
}

// ---------------------------------------------------------------------------------------
// Colours (display-encoded sRGB). A medium-light skin tone near the mean of common
// morphable-model albedos, so that the corrections start from a plausible face.

const SKIN: Vec3 = Vec3::new(0.80, 0.62, 0.52);
const SKIN_FLUSH: Vec3 = Vec3::new(0.80, 0.50, 0.46);
const LIP: Vec3 = Vec3::new(0.71, 0.43, 0.41);
const LIP_INNER: Vec3 = Vec3::new(0.61, 0.33, 0.33);
const LID_MARGIN: Vec3 = Vec3::new(0.76, 0.50, 0.48);
const BROW: Vec3 = Vec3::new(0.23, 0.16, 0.12);
const LASH: Vec3 = Vec3::new(0.07, 0.055, 0.045);
const MOUTH_FRONT: Vec3 = Vec3::new(0.58, 0.26, 0.27);
const MOUTH_DEEP: Vec3 = Vec3::new(0.28, 0.08, 0.09);
const EYE_SOCKET: Vec3 = Vec3::new(0.74, 0.47, 0.45);
const GUMS: Vec3 = Vec3::new(0.86, 0.52, 0.54);
const TONGUE: Vec3 = Vec3::new(0.78, 0.39, 0.40);
const TEETH: Vec3 = Vec3::new(0.93, 0.89, 0.79);
const SCLERA: Vec3 = Vec3::new(0.93, 0.90, 0.87);
const SCLERA_EDGE: Vec3 = Vec3::new(0.88, 0.80, 0.77);
const VESSEL: Vec3 = Vec3::new(0.78, 0.36, 0.36);
const IRIS_INNER: Vec3 = Vec3::new(0.60, 0.44, 0.20);
const IRIS_OUTER: Vec3 = Vec3::new(0.36, 0.24, 0.12);
const LIMBUS: Vec3 = Vec3::new(0.14, 0.10, 0.07);
const PUPIL: Vec3 = Vec3::new(0.015, 0.012, 0.012);

/// Iris radius on the eyeball shell's layout: the shell's UV centre is the front pole, and
/// r = 0.125 lands about 0.6 cm off the eye axis, where the template's iris disk meets the
/// shell.
pub(crate) const IRIS_RADIUS: f32 = 0.125;
/// Pupil radius on the shell's layout (about 0.18 cm, a neutral pupil).
pub(crate) const PUPIL_RADIUS: f32 = 0.035;

// ---------------------------------------------------------------------------------------
// Shared geometry: which surface each triangle is, which triangle covers each texel, and
// the landmark regions of the face tile. Used by R_0 and by the parsing map T.

/// What a triangle is, finer than its material.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Surface {
    FaceSkin,
    HeadSkin,
    MouthSocket,
    EyeSocket,
    Gums,
    Tongue,
    Teeth,
    Eyeball,
    Eyelashes,
}

/// Everything about the template that painting R_0 or T needs, computed once.
pub(crate) struct TemplateRegions<'a> {
    pub template: &'a Template,
    /// Per triangle; `None` for triangles that are not drawn.
    pub surfaces: Vec<Option<(AlbedoLayer, Surface)>>,
    /// `None` when a landmark has no face-tile UV (a broken template): the face is then
    /// painted and labelled as skin only.
    pub face: Option<FaceRegions>,
    anchors: SkinAnchors,
}

impl<'a> TemplateRegions<'a> {
    pub fn new(template: &'a Template) -> Self {
        let anchors = SkinAnchors::new(template);
        let mut surfaces: Vec<Option<(AlbedoLayer, Surface)>> = (0..template.triangles.len())
            .map(|t| {
                let layer = triangle_layer(template, t)?;
                let surface = match layer {
                    AlbedoLayer::Face => Surface::FaceSkin,
                    AlbedoLayer::Head => {
                        // By polygon, not by vertex: socket triangles along the seams use
                        // the face part's vertices.
                        let polygon = template.triangle_polygon[t];
                        let part = template
                            .parts
                            .iter()
                            .find(|p| p.polygons.contains(&polygon))
                            .map(|p| p.name.as_str());
                        match part {
                            Some("mouth_socket") => Surface::MouthSocket,
                            Some(p) if p.starts_with("eye_socket") => Surface::EyeSocket,
                            _ => Surface::HeadSkin,
                        }
                    }
                    AlbedoLayer::GumsTongue => Surface::Gums,
                    AlbedoLayer::Teeth => Surface::Teeth,
                    AlbedoLayer::Eyeball => Surface::Eyeball,
                    AlbedoLayer::Eyelashes => Surface::Eyelashes,
                };
                Some((layer, surface))
            })
            .collect();
        mark_tongue(template, &mut surfaces, anchors.lips_z);
        let face = landmark_uvs(template).map(|lm| FaceRegions::new(&lm));
        Self {
            template,
            surfaces,
            face,
            anchors,
        }
    }

    /// Position on the neutral S_0 at barycentrics `bary` of `triangle`.
    pub fn position(&self, triangle: usize, bary: [f32; 3]) -> Vec3 {
        let tri = self.template.triangles[triangle];
        (0..3).fold(Vec3::ZERO, |acc, k| {
            acc + bary[k] * self.template.neutral[tri[k] as usize]
        })
    }
}

/// The gums-and-tongue material covers gums, tongue, floor of the mouth and uvula in
/// separate UV charts. The gums are the charts at the front (their 3D centroid within
/// 3.5 cm behind the lips); everything further back is tongue-coloured.
fn mark_tongue(template: &Template, surfaces: &mut [Option<(AlbedoLayer, Surface)>], lips_z: f32) {
    const GUM_DEPTH_CM: f32 = 3.5;
    let mut parent: Vec<u32> = (0..template.uvs.len() as u32).collect();
    fn find(parent: &mut [u32], mut a: u32) -> u32 {
        while parent[a as usize] != a {
            let up = parent[parent[a as usize] as usize];
            parent[a as usize] = up;
            a = up;
        }
        a
    }
    let gum_tris: Vec<usize> = (0..surfaces.len())
        .filter(|&t| matches!(surfaces[t], Some((_, Surface::Gums))))
        .collect();
    for &t in &gum_tris {
        let [a, b, c] = template.triangle_uvs[t];
        let ra = find(&mut parent, a);
        for other in [b, c] {
            let ro = find(&mut parent, other);
            parent[ro as usize] = ra;
        }
    }
    // Per chart root: sum of triangle-centroid z and count.
    let mut chart_z: Vec<(f32, u32)> = vec![(0.0, 0); template.uvs.len()];
    let mut roots = Vec::with_capacity(gum_tris.len());
    for &t in &gum_tris {
        let root = find(&mut parent, template.triangle_uvs[t][0]) as usize;
        let z = template.triangles[t]
            .iter()
            .map(|&v| template.neutral[v as usize].z)
            .sum::<f32>()
            / 3.0;
        chart_z[root].0 += z;
        chart_z[root].1 += 1;
        roots.push(root);
    }
    for (&t, &root) in gum_tris.iter().zip(&roots) {
        let (sum, n) = chart_z[root];
        if n > 0 && sum / (n as f32) < lips_z - GUM_DEPTH_CM {
            surfaces[t] = Some((AlbedoLayer::GumsTongue, Surface::Tongue));
        }
    }
}

/// Face-tile UV of each of the 68 landmarks, or `None` if one has no face-tile UV.
pub(crate) fn landmark_uvs(template: &Template) -> Option<[Vec2; NUM_LANDMARKS]> {
    let uvs = template.face_vertex_uvs();
    let mut out = [Vec2::ZERO; NUM_LANDMARKS];
    for (o, &v) in out.iter_mut().zip(&template.landmarks_68) {
        *o = (*uvs.get(v as usize)?)?;
    }
    Some(out)
}

/// Which triangle of one layer covers each texel, with barycentrics.
pub(crate) struct LayerRaster {
    pub size: usize,
    /// Triangle per texel, [`LayerRaster::EMPTY`] where none.
    pub triangle: Vec<u32>,
    pub bary: Vec<[f32; 3]>,
}

impl LayerRaster {
    pub const EMPTY: u32 = u32::MAX;

    pub fn new(regions: &TemplateRegions, layer: AlbedoLayer, size: usize) -> Self {
        let template = regions.template;
        let mut triangle = vec![Self::EMPTY; size * size];
        let mut bary = vec![[0.0; 3]; size * size];
        let offset = Vec2::new(layer.uv_offset(), 0.0);
        for (t, s) in regions.surfaces.iter().enumerate() {
            if !matches!(s, Some((l, _)) if *l == layer) {
                continue;
            }
            let uv = template.triangle_uvs[t].map(|k| template.uvs[k as usize] - offset);
            rasterize_uv_triangle(uv, size, size, |x, y, b| {
                triangle[y * size + x] = t as u32;
                bary[y * size + x] = b;
            });
        }
        Self {
            size,
            triangle,
            bary,
        }
    }

    /// Grows every chart by `steps` texels into empty texels: a new texel copies a filled
    /// 4-neighbour's triangle and barycentrics (first in left, right, up, down order, so the
    /// result is deterministic).
    pub fn grow(&mut self, steps: usize) {
        let n = self.size as isize;
        for _ in 0..steps {
            let snapshot = self.triangle.clone();
            for y in 0..n {
                for x in 0..n {
                    let k = (y * n + x) as usize;
                    if snapshot[k] != Self::EMPTY {
                        continue;
                    }
                    let from = [(-1, 0), (1, 0), (0, -1), (0, 1)]
                        .into_iter()
                        .map(|(dx, dy)| (x + dx, y + dy))
                        .filter(|&(nx, ny)| nx >= 0 && ny >= 0 && nx < n && ny < n)
                        .map(|(nx, ny)| (ny * n + nx) as usize)
                        .find(|&j| snapshot[j] != Self::EMPTY);
                    if let Some(j) = from {
                        self.triangle[k] = snapshot[j];
                        self.bary[k] = self.bary[j];
                    }
                }
            }
        }
    }

    /// The triangle at texel `k`, if any.
    pub fn at(&self, k: usize) -> Option<usize> {
        let t = *self.triangle.get(k)?;
        (t != Self::EMPTY).then_some(t as usize)
    }
}

/// A polygon or polyline in UV, with a bounding box to skip far texels quickly.
#[derive(Clone, Debug)]
pub(crate) struct Shape {
    points: Vec<Vec2>,
    closed: bool,
    /// Arc length up to each point, normalised to end at 1.
    arc: Vec<f32>,
    min: Vec2,
    max: Vec2,
}

impl Shape {
    pub fn new(points: Vec<Vec2>, closed: bool) -> Self {
        let min = points.iter().fold(Vec2::splat(f32::MAX), |m, p| m.min(*p));
        let max = points.iter().fold(Vec2::splat(f32::MIN), |m, p| m.max(*p));
        let mut arc = Vec::with_capacity(points.len());
        let mut length = 0.0;
        for (i, p) in points.iter().enumerate() {
            if i > 0 {
                length += p.distance(points[i - 1]);
            }
            arc.push(length);
        }
        if length > 0.0 {
            arc.iter_mut().for_each(|a| *a /= length);
        }
        Self {
            points,
            closed,
            arc,
            min,
            max,
        }
    }

    fn segments(&self) -> impl Iterator<Item = (usize, Vec2, Vec2)> + '_ {
        let n = self.points.len();
        let count = if self.closed { n } else { n.saturating_sub(1) };
        (0..count).map(move |i| (i, self.points[i], self.points[(i + 1) % n]))
    }

    /// Distance from `p` to the outline and the arc-length fraction of the nearest point, or
    /// `None` when `p` is farther than `reach` from the bounding box.
    pub fn nearest(&self, p: Vec2, reach: f32) -> Option<(f32, f32)> {
        let outside = (self.min - p).max(p - self.max).max(Vec2::ZERO);
        if outside.length() > reach || self.points.is_empty() {
            return None;
        }
        if self.points.len() == 1 {
            return Some((p.distance(self.points[0]), 0.0));
        }
        let mut best = (f32::MAX, 0.0);
        for (i, a, b) in self.segments() {
            let ab = b - a;
            let len2 = ab.length_squared();
            let h = if len2 > 0.0 {
                ((p - a).dot(ab) / len2).clamp(0.0, 1.0)
            } else {
                0.0
            };
            let d = p.distance(a + h * ab);
            if d < best.0 {
                let a0 = self.arc[i];
                let a1 = self.arc.get(i + 1).copied().unwrap_or(1.0);
                best = (d, a0 + h * (a1 - a0));
            }
        }
        Some(best)
    }

    /// Even-odd point-in-polygon test (closed shapes only).
    pub fn contains(&self, p: Vec2) -> bool {
        if !self.closed || p.cmplt(self.min).any() || p.cmpgt(self.max).any() {
            return false;
        }
        let mut inside = false;
        for (_, a, b) in self.segments() {
            if (a.y > p.y) != (b.y > p.y) {
                let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
                if p.x < x {
                    inside = !inside;
                }
            }
        }
        inside
    }

    /// Signed distance, negative inside; values beyond `reach` are clamped to `reach`.
    pub fn signed_distance(&self, p: Vec2, reach: f32) -> f32 {
        match self.nearest(p, reach) {
            None => reach,
            Some((d, _)) if self.contains(p) => -d.min(reach),
            Some((d, _)) => d.min(reach),
        }
    }
}

/// Samples an open Catmull-Rom spline through `points` (end points repeated), so that
/// contours through a few landmarks come out as smooth curves instead of polygons.
fn catmull_rom(points: &[Vec2], samples_per_segment: usize) -> Vec<Vec2> {
    let n = points.len();
    if n < 3 {
        return points.to_vec();
    }
    let at = |i: isize| points[i.clamp(0, n as isize - 1) as usize];
    let mut out = Vec::with_capacity((n - 1) * samples_per_segment + 1);
    for i in 0..n as isize - 1 {
        let (p0, p1, p2, p3) = (at(i - 1), at(i), at(i + 1), at(i + 2));
        for s in 0..samples_per_segment {
            let t = s as f32 / samples_per_segment as f32;
            let (t2, t3) = (t * t, t * t * t);
            out.push(
                0.5 * (2.0 * p1
                    + (p2 - p0) * t
                    + (2.0 * p0 - 5.0 * p1 + 4.0 * p2 - p3) * t2
                    + (3.0 * p1 - p0 - 3.0 * p2 + p3) * t3),
            );
        }
    }
    out.push(points[n - 1]);
    out
}

/// Landmark contours of the face tile, in UV. Sizes are fractions of the outer-eye-corner
/// distance `scale`, so they follow the layout if the template's UVs are rescaled.
#[derive(Clone, Debug)]
pub(crate) struct FaceRegions {
    /// |lm 36 - lm 45| in UV.
    pub scale: f32,
    /// Outer upper lip contour (48-54) closed along the mouth line.
    pub upper_lip: Shape,
    /// Outer lower lip contour (54-59, 48) closed along the mouth line.
    pub lower_lip: Shape,
    /// The whole outer lip contour: one shape, so the soft lip edge of R_0 has no seam along
    /// the mouth line where the two halves meet.
    pub lips: Shape,
    /// Where the lips meet: the corners 48/60 and 54/64 through the midpoints of the inner
    /// contour's facing points. In this template the inner contour 60-67 lies on the lips'
    /// rolled-in inner side, away from the mouth hole, so the mouth line (not the inner
    /// contour) is what splits the lips.
    pub mouth_line: Shape,
    /// Eye openings 36-41 and 42-47.
    pub eyes: [Shape; 2],
    /// Upper lid margins 36-39 and 42-45.
    pub upper_lids: [Shape; 2],
    /// Mean v of the eye corners: above it is the upper lid.
    pub eye_centre_v: f32,
    pub nose: Shape,
    /// Brow centre lines from tail (17, 26) to head (21, 22).
    pub brows: [Shape; 2],
}

impl FaceRegions {
    /// Eye openings are grown by this (times `scale`) so the lid margins and lashes belong
    /// to the eyes, as face parsers label them.
    pub const EYE_GROWTH: f32 = 0.012;
    const BROW_SHIFT: f32 = 0.028;
    const BROW_TAIL_HALF_WIDTH: f32 = 0.014;
    const BROW_HEAD_HALF_WIDTH: f32 = 0.048;

    pub fn new(lm: &[Vec2; NUM_LANDMARKS]) -> Self {
        let scale = lm[36].distance(lm[45]);
        let pick = |ids: &[usize]| ids.iter().map(|&i| lm[i]).collect::<Vec<_>>();
        let mid = |a: usize, b: usize| 0.5 * (lm[a] + lm[b]);
        const SAMPLES: usize = 6;

        let mouth = catmull_rom(
            &[lm[60], mid(61, 67), mid(62, 66), mid(63, 65), lm[64]],
            SAMPLES,
        );
        let outer_upper = catmull_rom(&pick(&[48, 49, 50, 51, 52, 53, 54]), SAMPLES);
        let outer_lower = catmull_rom(&pick(&[54, 55, 56, 57, 58, 59, 48]), SAMPLES);
        let mut upper = outer_upper.clone();
        upper.extend(mouth.iter().rev());
        let mut lower = outer_lower.clone();
        lower.extend(mouth.iter());
        let mut lips = outer_upper;
        lips.extend(&outer_lower[1..outer_lower.len() - 1]);
        let mut mouth_line = vec![lm[48]];
        mouth_line.extend(&mouth);
        mouth_line.push(lm[54]);

        let eye = |ids: [usize; 6]| {
            let mut ring = catmull_rom(&pick(&ids[0..4]), SAMPLES);
            let lower = catmull_rom(&pick(&[ids[3], ids[4], ids[5], ids[0]]), SAMPLES);
            let upper_lid = Shape::new(ring.clone(), false);
            ring.extend(&lower[1..lower.len() - 1]);
            (Shape::new(ring, true), upper_lid)
        };
        let (eye_r, lid_r) = eye([36, 37, 38, 39, 40, 41]);
        let (eye_l, lid_l) = eye([45, 44, 43, 42, 47, 46]);

        // Nose: bridge from 27 widening down to the tip 30, out to the alae beside 31 and
        // 35, along below the nostril base 31-35; drawn from the image's left (smaller u)
        // down and back up on the right. Offsets are (away from the midline, up).
        let (left, right) = if lm[31].x < lm[35].x {
            ((31, 32), (35, 34))
        } else {
            ((35, 34), (31, 32))
        };
        let at = |i: usize, sign: f32, across: f32, up: f32| {
            lm[i] + scale * Vec2::new(sign * across, up)
        };
        let side = |sign: f32, ala: usize| {
            [
                at(27, sign, 0.06, 0.0),
                at(28, sign, 0.065, 0.0),
                at(29, sign, 0.08, 0.0),
                at(30, sign, 0.11, 0.0),
                at(ala, sign, 0.06, 0.05),
                at(ala, sign, 0.085, 0.0),
                at(ala, sign, 0.05, -0.03),
            ]
        };
        let mut nose_ring = side(-1.0, left.0).to_vec();
        nose_ring.extend([
            at(left.1, 0.0, 0.0, -0.03),
            at(33, 0.0, 0.0, -0.035),
            at(right.1, 0.0, 0.0, -0.03),
        ]);
        nose_ring.extend(side(1.0, right.0).into_iter().rev());
        let nose = closed_smooth(&nose_ring, SAMPLES);

        let brow = |ids: [usize; 5]| {
            let shifted: Vec<Vec2> = ids
                .iter()
                .map(|&i| lm[i] - Vec2::new(0.0, Self::BROW_SHIFT * scale))
                .collect();
            Shape::new(catmull_rom(&shifted, SAMPLES), false)
        };

        Self {
            scale,
            upper_lip: Shape::new(upper, true),
            lower_lip: Shape::new(lower, true),
            lips: Shape::new(lips, true),
            mouth_line: Shape::new(mouth_line, false),
            eyes: [eye_r, eye_l],
            upper_lids: [lid_r, lid_l],
            eye_centre_v: 0.25 * (lm[36].y + lm[39].y + lm[42].y + lm[45].y),
            nose,
            brows: [brow([17, 18, 19, 20, 21]), brow([26, 25, 24, 23, 22])],
        }
    }

    /// How far (in UV) any region's influence reaches; beyond it texels are plain skin.
    fn reach(&self) -> f32 {
        0.25 * self.scale
    }

    /// Signed distance to the nearer eye opening (not grown).
    pub fn eye_sd(&self, uv: Vec2) -> f32 {
        let r = self.reach();
        self.eyes
            .iter()
            .map(|e| e.signed_distance(uv, r))
            .fold(r, f32::min)
    }

    /// Signed distance to the nearer brow band (negative inside) and the position along
    /// it (0 tail, 1 head).
    pub fn brow_sd(&self, uv: Vec2) -> (f32, f32) {
        let r = self.reach();
        let mut best = (r, 0.0);
        for brow in &self.brows {
            if let Some((d, t)) = brow.nearest(uv, r) {
                let w = Self::BROW_TAIL_HALF_WIDTH
                    + (Self::BROW_HEAD_HALF_WIDTH - Self::BROW_TAIL_HALF_WIDTH)
                        * smoothstep(0.0, 0.45, t);
                let sd = d - w * self.scale;
                if sd < best.0 {
                    best = (sd, t);
                }
            }
        }
        best
    }

    pub fn upper_lip_sd(&self, uv: Vec2) -> f32 {
        self.upper_lip.signed_distance(uv, self.reach())
    }

    pub fn lower_lip_sd(&self, uv: Vec2) -> f32 {
        self.lower_lip.signed_distance(uv, self.reach())
    }

    pub fn nose_sd(&self, uv: Vec2) -> f32 {
        self.nose.signed_distance(uv, self.reach())
    }
}

/// A closed Catmull-Rom curve through `points`.
fn closed_smooth(points: &[Vec2], samples: usize) -> Shape {
    let n = points.len();
    if n < 3 {
        return Shape::new(points.to_vec(), true);
    }
    // Wrap one point at each end so the open spline is smooth across the closing point.
    let mut wrapped = vec![points[n - 1]];
    wrapped.extend_from_slice(points);
    wrapped.extend([points[0], points[1]]);
    let curve = catmull_rom(&wrapped, samples);
    // Keep the part between the first and the repeated first point.
    let ring = curve[samples..samples * (n + 1)].to_vec();
    Shape::new(ring, true)
}

// ---------------------------------------------------------------------------------------
// Noise: hash-based value noise, so R_0 is reproducible everywhere without a RNG crate.

fn hash3(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    let mut h = seed.wrapping_mul(0x9E37_79B9)
        ^ (x as u32).wrapping_mul(0x85EB_CA6B)
        ^ (y as u32).wrapping_mul(0xC2B2_AE35)
        ^ (z as u32).wrapping_mul(0x27D4_EB2F);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297A_2D39);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

/// Smooth value noise in [-1, 1].
fn noise3(p: Vec3, seed: u32) -> f32 {
    let i = p.floor();
    let f = p - i;
    let s = f * f * (Vec3::splat(3.0) - 2.0 * f);
    let (x, y, z) = (i.x as i32, i.y as i32, i.z as i32);
    let corner = |dx: i32, dy: i32, dz: i32| hash3(x + dx, y + dy, z + dz, seed);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let x00 = lerp(corner(0, 0, 0), corner(1, 0, 0), s.x);
    let x10 = lerp(corner(0, 1, 0), corner(1, 1, 0), s.x);
    let x01 = lerp(corner(0, 0, 1), corner(1, 0, 1), s.x);
    let x11 = lerp(corner(0, 1, 1), corner(1, 1, 1), s.x);
    let v = lerp(lerp(x00, x10, s.y), lerp(x01, x11, s.y), s.z);
    2.0 * v - 1.0
}

fn noise2(p: Vec2, seed: u32) -> f32 {
    noise3(p.extend(0.5), seed)
}

/// Three octaves of value noise, roughly in [-1, 1].
fn fbm3(p: Vec3, seed: u32) -> f32 {
    (noise3(p, seed) + 0.5 * noise3(2.03 * p, seed + 1) + 0.25 * noise3(4.01 * p, seed + 2)) / 1.75
}

fn smoothstep(e0: f32, e1: f32, x: f32) -> f32 {
    let t = ((x - e0) / (e1 - e0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// 1 well inside a shape, 0 well outside, a smooth edge `width` wide around sd = 0.
fn soft_inside(sd: f32, width: f32) -> f32 {
    1.0 - smoothstep(-0.5 * width, 0.5 * width, sd)
}

// ---------------------------------------------------------------------------------------
// Painting.

/// 3D landmarks (cm, on S_0) that place the skin's flushed areas.
struct SkinAnchors {
    cheeks: [Vec3; 2],
    nose_tip: Vec3,
    alae: [Vec3; 2],
    ears: [Vec3; 2],
    chin: Vec3,
    /// z of the lips' front (landmark 62), the reference depth inside the mouth.
    lips_z: f32,
}

impl SkinAnchors {
    fn new(template: &Template) -> Self {
        let p = |i: usize| template.neutral[template.landmarks_68[i] as usize];
        let cheek = |ids: [usize; 4]| ids.iter().map(|&i| p(i)).sum::<Vec3>() / 4.0;
        // The ear's centre lies behind and below the jaw-line's top point (0 / 16): in the
        // ICT neutral the ear charts are centred about 2.4 cm lower and 3.8 cm further back.
        let ear = |i: usize| p(i) * Vec3::new(1.07, 1.0, 1.0) + Vec3::new(0.0, -2.4, -3.8);
        Self {
            cheeks: [cheek([2, 31, 41, 48]), cheek([14, 35, 46, 54])],
            nose_tip: p(30),
            alae: [p(31), p(35)],
            ears: [ear(0), ear(16)],
            chin: p(8) + Vec3::new(0.0, 1.2, 0.0),
            lips_z: p(62).z,
        }
    }

    /// How flushed the skin is at `p`, in [0, 1].
    fn flush(&self, p: Vec3) -> f32 {
        let g = |c: Vec3, sigma: f32| (-(p - c).length_squared() / (2.0 * sigma * sigma)).exp();
        let cheeks = g(self.cheeks[0], 2.0) + g(self.cheeks[1], 2.0);
        let nose = g(self.nose_tip, 0.9) + 0.7 * (g(self.alae[0], 0.6) + g(self.alae[1], 0.6));
        let ears = g(self.ears[0], 2.2) + g(self.ears[1], 2.2);
        let chin = g(self.chin, 1.3);
        (0.8 * cheeks + 0.6 * nose + 0.55 * ears + 0.25 * chin).min(1.0)
    }
}

/// Skin colour at `p` on S_0, shared by the face and head tiles so they match at seams.
fn skin(p: Vec3, anchors: &SkinAnchors) -> Vec3 {
    let broad = fbm3(p / 6.0, 11);
    let mid = noise3(p / 1.5, 21);
    let fine = noise3(p / 0.45, 31);
    let hue = noise3(p / 4.0, 41);
    let blotch = noise3(p / 2.2, 51).max(0.0);
    let flush = (anchors.flush(p) + 0.3 * blotch).min(1.0);
    let mut c = SKIN.lerp(SKIN_FLUSH, 0.6 * flush);
    c *= 1.0 + 0.045 * broad + 0.02 * mid + 0.012 * fine;
    c * Vec3::new(1.0 + 0.01 * hue, 1.0, 1.0 + 0.04 * hue)
}

/// Lips, brows and eyelids on top of the skin colour `c` at face-tile `uv`.
fn face_features(mut c: Vec3, uv: Vec2, f: &FaceRegions) -> Vec3 {
    let s = f.scale;

    // Eyelids: the lid margin inside the eye contour is pink (the slit itself has no
    // triangles); around it the lids are a little darker, more above than below, and the
    // upper lash line is dark.
    let eye_sd = f.eye_sd(uv);
    if eye_sd < f.reach() {
        let upper = smoothstep(-0.03 * s, 0.03 * s, uv.y - f.eye_centre_v);
        let strength = 0.08 + 0.07 * upper;
        let dark = strength * (-eye_sd.max(0.0) / (0.07 * s)).exp();
        c *= Vec3::ONE - dark * Vec3::new(0.85, 1.1, 0.95);
        c = c.lerp(LID_MARGIN, soft_inside(eye_sd, 0.01 * s));
        let lash = f
            .upper_lids
            .iter()
            .filter_map(|l| l.nearest(uv, 0.05 * s))
            .map(|(d, t)| {
                // Thicker towards the outer corner, as lashes grow there.
                let w = s * (0.006 + 0.006 * smoothstep(0.3, 1.0, 1.0 - t));
                1.0 - smoothstep(0.5 * w, 1.5 * w, d)
            })
            .fold(0.0, f32::max);
        c = c.lerp(LASH, 0.75 * lash);
    }

    // Brows: a soft band with hair-like streaks along it, sparser at the head.
    let (brow_sd, t) = f.brow_sd(uv);
    if brow_sd < 0.02 * s {
        let density = soft_inside(brow_sd, 0.02 * s);
        let streak = noise2(Vec2::new(uv.x * 900.0, uv.y * 120.0), 61);
        let sparse_head = 1.0 - 0.35 * smoothstep(0.75, 1.0, t);
        let amount = density * sparse_head * (0.8 + 0.2 * streak);
        c = c.lerp(BROW, 0.85 * amount.clamp(0.0, 1.0));
    }

    // Lips: redder, darker towards where they meet, with faint vertical creases.
    let lip_sd = f.lips.signed_distance(uv, f.reach());
    if lip_sd < 0.01 * s {
        let inside = soft_inside(lip_sd, 0.012 * s);
        let to_line = f
            .mouth_line
            .nearest(uv, f.reach())
            .map_or(f.reach(), |(d, _)| d);
        let inner = 1.0 - smoothstep(0.0, 0.05 * s, to_line);
        let crease = noise2(Vec2::new(uv.x * 700.0, uv.y * 60.0), 71);
        let lower_lip = f.lower_lip_sd(uv) < f.upper_lip_sd(uv);
        let mut lip = LIP.lerp(LIP_INNER, 0.8 * inner) * (1.0 + 0.03 * crease);
        if lower_lip {
            lip *= Vec3::new(1.03, 1.04, 1.04);
        }
        c = c.lerp(lip, inside);
    }
    c
}

fn mouth_socket(p: Vec3, anchors: &SkinAnchors) -> Vec3 {
    let front = smoothstep(anchors.lips_z - 6.0, anchors.lips_z - 0.5, p.z);
    MOUTH_DEEP.lerp(MOUTH_FRONT, front) * (1.0 + 0.04 * noise3(p / 0.5, 81))
}

fn eyeball(uv: Vec2) -> Vec3 {
    let d = uv - Vec2::splat(0.5);
    let r = d.length();
    let sclera_noise = noise2(uv * 40.0, 91);
    let sclera = SCLERA.lerp(SCLERA_EDGE, smoothstep(0.25, 0.5, r)) * (1.0 + 0.015 * sclera_noise);
    if r > IRIS_RADIUS + 0.01 {
        return sclera;
    }
    let t = ((r - PUPIL_RADIUS) / (IRIS_RADIUS - PUPIL_RADIUS)).clamp(0.0, 1.0);
    let dir = if r > 0.0 { d / r } else { Vec2::X };
    // Radial fibres: high angular frequency, low radial frequency; sampled on a circle so
    // the pattern has no seam.
    let fibres = noise3((dir * 22.0).extend(t * 3.0), 101);
    let crypts = noise3((dir * 7.0).extend(t * 6.0), 111);
    let base = IRIS_INNER.lerp(IRIS_OUTER, smoothstep(0.1, 0.55, t));
    let mut iris = base * (0.85 + 0.22 * fibres + 0.1 * crypts);
    iris = iris.lerp(LIMBUS, 0.7 * smoothstep(0.72, 1.0, t));
    iris = iris.lerp(
        PUPIL,
        1.0 - smoothstep(PUPIL_RADIUS - 0.003, PUPIL_RADIUS + 0.003, r),
    );
    iris.lerp(
        sclera,
        smoothstep(IRIS_RADIUS - 0.004, IRIS_RADIUS + 0.004, r),
    )
}

/// Paints a few faint, wiggly vessels on the visible sclera, from the shell's periphery
/// towards the iris.
fn stamp_vessels(map: &mut UvMap, raster: &LayerRaster) {
    const VESSELS: u32 = 10;
    const STEP: f32 = 0.001;
    let size = map.width as f32;
    for k in 0..VESSELS {
        let jitter = hash3(k as i32, 0, 0, 131);
        let mut angle = std::f32::consts::TAU * (k as f32 + jitter) / VESSELS as f32;
        let mut r = 0.46;
        let stop = 0.19 + 0.08 * hash3(k as i32, 1, 0, 131);
        let width = 0.0012 + 0.0012 * hash3(k as i32, 2, 0, 131);
        let mut step = 0;
        while r > stop {
            let wiggle = noise2(Vec2::new(k as f32 * 7.3, step as f32 * 0.04), 141);
            angle += 0.012 * wiggle;
            r -= STEP;
            step += 1;
            let centre = Vec2::splat(0.5) + r * Vec2::new(angle.cos(), angle.sin());
            // Fade in from the periphery and out towards the tip.
            let alpha = 0.08 * smoothstep(stop, stop + 0.08, r) * (0.6 + 0.4 * (r / 0.46));
            let w = width * (0.5 + r / 0.46);
            let reach = (w * size).ceil() as isize + 1;
            let cx = (centre.x * size) as isize;
            let cy = ((1.0 - centre.y) * size) as isize;
            for y in cy - reach..=cy + reach {
                for x in cx - reach..=cx + reach {
                    if x < 0 || y < 0 || x >= map.width as isize || y >= map.height as isize {
                        continue;
                    }
                    let (x, y) = (x as usize, y as usize);
                    if raster.at(y * map.width + x).is_none() {
                        continue;
                    }
                    let texel = texel_center_uv(x, y, map.width, map.height);
                    let cover = 1.0 - smoothstep(0.5 * w, w, texel.distance(centre));
                    let a = alpha * cover;
                    if a <= 0.0 {
                        continue;
                    }
                    for (c, v) in map.texel_mut(x, y).iter_mut().zip(VESSEL.to_array()) {
                        *c += (v - *c) * a;
                    }
                }
            }
        }
    }
}

fn fill_colour(layer: AlbedoLayer) -> Vec3 {
    match layer {
        AlbedoLayer::Face | AlbedoLayer::Head => SKIN,
        AlbedoLayer::GumsTongue => GUMS,
        AlbedoLayer::Teeth => TEETH,
        AlbedoLayer::Eyeball => SCLERA,
        AlbedoLayer::Eyelashes => LASH,
    }
}

fn paint_layer(regions: &TemplateRegions, layer: AlbedoLayer) -> UvMap {
    let size = ALBEDO_SIZE;
    let mut raster = LayerRaster::new(regions, layer, size);
    raster.grow(PAD_TEXELS);
    let anchors = &regions.anchors;
    let mut map = UvMap::zeros(size, size, 3);
    for y in 0..size {
        for x in 0..size {
            let k = y * size + x;
            let uv = texel_center_uv(x, y, size, size);
            let colour = match raster.at(k) {
                None => fill_colour(layer),
                Some(t) => {
                    let p = regions.position(t, raster.bary[k]);
                    let surface = regions.surfaces[t].map(|(_, s)| s);
                    match surface {
                        Some(Surface::FaceSkin) => {
                            let c = skin(p, anchors);
                            match &regions.face {
                                Some(f) => face_features(c, uv, f),
                                None => c,
                            }
                        }
                        Some(Surface::HeadSkin) => skin(p, anchors),
                        Some(Surface::MouthSocket) => mouth_socket(p, anchors),
                        Some(Surface::EyeSocket) => {
                            EYE_SOCKET * (1.0 + 0.03 * noise3(p / 0.3, 151))
                        }
                        Some(Surface::Gums) => GUMS * (1.0 + 0.03 * noise3(p / 0.4, 161)),
                        Some(Surface::Tongue) => {
                            TONGUE
                                * (1.0 + 0.05 * noise3(p / 0.12, 171) + 0.03 * noise3(p / 0.8, 172))
                        }
                        Some(Surface::Teeth) => {
                            TEETH
                                * Vec3::new(1.0, 1.0, 1.0 + 0.04 * noise3(p / 0.4, 181))
                                * (1.0 + 0.02 * noise3(p / 0.15, 182))
                        }
                        Some(Surface::Eyeball) => eyeball(uv),
                        Some(Surface::Eyelashes) => LASH * (1.0 + 0.15 * noise2(uv * 60.0, 191)),
                        None => fill_colour(layer),
                    }
                }
            };
            let out = map.texel_mut(x, y);
            for (o, v) in out.iter_mut().zip(colour.to_array()) {
                *o = if v.is_finite() {
                    v.clamp(0.0, 1.0)
                } else {
                    0.0
                };
            }
        }
    }
    if layer == AlbedoLayer::Eyeball {
        stamp_vessels(&mut map, &raster);
    }
    map
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parsing::{ParsingLabel, ParsingMap};

    fn template() -> Template {
        crate::template::test_template()
    }

    fn luma(c: &[f32]) -> f32 {
        0.2126 * c[0] + 0.7152 * c[1] + 0.0722 * c[2]
    }

    /// Mean colour of the texels of `layer` for which `keep(k)` holds.
    fn mean_where(map: &UvMap, keep: impl Fn(usize) -> bool) -> [f32; 3] {
        let mut sum = [0.0f64; 3];
        let mut n = 0usize;
        for k in 0..map.width * map.height {
            if keep(k) {
                for (s, v) in sum.iter_mut().zip(&map.data[k * 3..k * 3 + 3]) {
                    *s += f64::from(*v);
                }
                n += 1;
            }
        }
        assert!(n > 0, "no texels selected");
        sum.map(|s| (s / n as f64) as f32)
    }

    #[test]
    fn albedo_is_deterministic_finite_and_in_range() {
        let template = template();
        let start = std::time::Instant::now();
        let a = MeanAlbedo::generate(&template);
        let elapsed = start.elapsed();
        let b = MeanAlbedo::generate(&template);
        assert_eq!(a, b);
        assert_eq!(a.layers.len(), AlbedoLayer::ALL.len());
        for (layer, map) in AlbedoLayer::ALL.iter().zip(&a.layers) {
            assert_eq!(
                (map.width, map.height, map.channels),
                (ALBEDO_SIZE, ALBEDO_SIZE, 3)
            );
            assert!(
                map.data
                    .iter()
                    .all(|v| v.is_finite() && (0.0..=1.0).contains(v)),
                "{layer:?} has values outside [0, 1]"
            );
        }
        assert_eq!(a.face(), &a.layers[AlbedoLayer::Face.index()]);
        eprintln!("R_0 generated in {elapsed:?}");
    }

    #[test]
    fn albedo_features_have_the_expected_colours() {
        let template = template();
        let albedo = MeanAlbedo::generate(&template);
        let parsing = ParsingMap::generate(&template);
        let face = albedo.face();
        let labels = &parsing.layers[AlbedoLayer::Face.index()];
        let is = |label: ParsingLabel| move |k: usize| labels[k] == label as u8;
        let skin = mean_where(face, is(ParsingLabel::Skin));
        let lips = mean_where(face, |k| {
            labels[k] == ParsingLabel::UpperLip as u8 || labels[k] == ParsingLabel::LowerLip as u8
        });
        let brows = mean_where(face, is(ParsingLabel::Brows));
        assert!(
            lips[0] / lips[1] > skin[0] / skin[1] + 0.1,
            "lips {lips:?} not redder than skin {skin:?}"
        );
        assert!(
            luma(&brows) < 0.75 * luma(&skin),
            "brows {brows:?} not darker than skin {skin:?}"
        );

        let eye = albedo.layer(AlbedoLayer::Eyeball);
        let at = |r: f32| eye.sample(Vec2::new(0.5 + r, 0.5));
        let (pupil, iris, sclera) = (at(0.0), at(0.08), at(0.3));
        assert!(luma(&sclera) > luma(&iris) + 0.3, "{sclera:?} vs {iris:?}");
        assert!(luma(&pupil) < luma(&iris), "{pupil:?} vs {iris:?}");
        let darkest = AlbedoLayer::ALL
            .iter()
            .flat_map(|&l| albedo.layer(l).data.chunks_exact(3).map(luma))
            .fold(f32::MAX, f32::min);
        assert!(
            luma(&pupil) <= darkest + 1e-3,
            "pupil is not the darkest texel"
        );

        let regions = TemplateRegions::new(&template);
        let coverage = |layer: AlbedoLayer, surface: Surface| {
            let raster = LayerRaster::new(&regions, layer, ALBEDO_SIZE);
            let surfaces = &regions.surfaces;
            move |k: usize| {
                raster
                    .at(k)
                    .is_some_and(|t| surfaces[t].is_some_and(|(_, s)| s == surface))
            }
        };
        let teeth = mean_where(
            albedo.layer(AlbedoLayer::Teeth),
            coverage(AlbedoLayer::Teeth, Surface::Teeth),
        );
        let gums = mean_where(
            albedo.layer(AlbedoLayer::GumsTongue),
            coverage(AlbedoLayer::GumsTongue, Surface::Gums),
        );
        let tongue = mean_where(
            albedo.layer(AlbedoLayer::GumsTongue),
            coverage(AlbedoLayer::GumsTongue, Surface::Tongue),
        );
        assert!(luma(&teeth) > luma(&gums) + 0.15, "{teeth:?} vs {gums:?}");
        assert!(
            tongue[0] / tongue[1] > gums[0] / gums[1],
            "{tongue:?} vs {gums:?}"
        );
    }

    #[test]
    fn triangle_layers_follow_the_materials() {
        let template = template();
        let count = |layer: Option<AlbedoLayer>| {
            (0..template.triangles.len())
                .filter(|&t| triangle_layer(&template, t) == layer)
                .count()
        };
        assert_eq!(
            count(Some(AlbedoLayer::Face)),
            template.face_triangles().count()
        );
        for layer in AlbedoLayer::ALL {
            assert!(count(Some(layer)) > 0, "{layer:?} has no triangles");
        }
        // Every drawn triangle's UVs lie in its layer's tile.
        for t in 0..template.triangles.len() {
            if let Some(layer) = triangle_layer(&template, t) {
                for &k in &template.triangle_uvs[t] {
                    let u = template.uvs[k as usize].x - layer.uv_offset();
                    assert!(
                        (-1e-3..=1.001).contains(&u),
                        "{layer:?} triangle {t}: u {u}"
                    );
                }
            }
        }
    }

    /// Writes every layer as a binary PPM to /tmp for looking at R_0 by eye:
    /// `cargo test -p face dump_albedo -- --ignored`.
    #[test]
    #[ignore]
    fn dump_albedo_layers_to_tmp() {
        let template = template();
        let albedo = MeanAlbedo::generate(&template);
        for layer in AlbedoLayer::ALL {
            let map = albedo.layer(layer);
            let mut bytes = format!("P6\n{} {}\n255\n", map.width, map.height).into_bytes();
            bytes.extend(map.data.iter().map(|v| (v * 255.0).round() as u8));
            let path = std::env::temp_dir().join(format!("albedo_{}.ppm", layer.name()));
            if let Err(e) = std::fs::write(&path, bytes) {
                panic!("cannot write {path:?}: {e}");
            }
        }
    }
}
