//! The sampling function F of equation (2): UV-space correction maps to per-vertex values.
//!
//! The correction maps live in the face tile (u, v in [0, 1]) of the "face" part, the
//! region of the paper's template. The ICT mesh also has separate skin meshes stitched to
//! that part (head and neck, mouth and eye sockets, eyelashes, ...) whose vertices coincide
//! with face vertices along the seams. If F were zero there, a correction would open a crack
//! at every seam, so each such vertex reads the sample of its nearest face vertex, faded
//! out with distance (full strength within [`ATTACH_FULL_CM`], zero beyond
//! [`ATTACH_ZERO_CM`]). Rigid parts (teeth, gums and tongue, eyeballs) get no correction:
//! a personal shape correction must not bend teeth or eyeballs.

use glam::{Vec2, Vec3};

use crate::template::Template;
use crate::uv::{CORRECTION_SIZE, UvMap, bilinear_taps};

/// Up to this distance (cm) from the nearest face vertex a stitched vertex follows it fully.
pub const ATTACH_FULL_CM: f32 = 0.5;
/// Beyond this distance (cm) a stitched vertex gets no correction.
pub const ATTACH_ZERO_CM: f32 = 2.0;

/// Parts that move rigidly and never receive UV corrections.
const RIGID_PARTS: [&str; 4] = ["teeth", "gums_and_tongue", "eyeball_left", "eyeball_right"];

/// Where and how strongly vertex v samples the correction maps.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleSite {
    /// UV in the face tile.
    pub uv: Vec2,
    /// 1 for face vertices; the distance fade for stitched vertices.
    pub weight: f32,
}

/// Precomputed F for one template at one map size: per vertex the four bilinear taps
/// (texel index, weight) with the site weight folded in.
#[derive(Clone, Debug)]
pub struct CorrectionSampler {
    pub size: usize,
    pub sites: Vec<Option<SampleSite>>,
    taps: Vec<[(u32, f32); 4]>,
}

impl CorrectionSampler {
    /// Builds F for `template` and square maps of side `size` (normally
    /// [`CORRECTION_SIZE`]).
    pub fn new(template: &Template, size: usize) -> Self {
        let sites = sample_sites(template);
        let taps = sites
            .iter()
            .map(|site| match site {
                Some(s) => bilinear_taps(s.uv, size, size).map(|(t, w)| (t, w * s.weight)),
                None => [(0, 0.0); 4],
            })
            .collect();
        Self { size, sites, taps }
    }

    /// Builds F at the paper's 128 x 128.
    pub fn for_template(template: &Template) -> Self {
        Self::new(template, CORRECTION_SIZE)
    }

    /// F(map) for a 3-channel map: one vector per vertex.
    pub fn sample_vec3(&self, map: &UvMap) -> Vec<Vec3> {
        debug_assert_eq!(map.channels, 3);
        self.taps
            .iter()
            .map(|taps| {
                taps.iter().fold(Vec3::ZERO, |acc, &(t, w)| {
                    let s = t as usize * 3;
                    acc + w * Vec3::new(map.data[s], map.data[s + 1], map.data[s + 2])
                })
            })
            .collect()
    }

    /// F(A ⊙ map): samples the texel-wise product of a 1-channel mask and a 3-channel map
    /// without building the product map.
    pub fn sample_masked_vec3(&self, mask: &UvMap, map: &UvMap) -> Vec<Vec3> {
        self.taps
            .iter()
            .map(|taps| {
                taps.iter().fold(Vec3::ZERO, |acc, &(t, w)| {
                    let s = t as usize * 3;
                    let a = mask.data[t as usize];
                    acc + (w * a) * Vec3::new(map.data[s], map.data[s + 1], map.data[s + 2])
                })
            })
            .collect()
    }

    /// F(map) for a 1-channel map.
    pub fn sample_scalar(&self, map: &UvMap) -> Vec<f32> {
        self.taps
            .iter()
            .map(|taps| taps.iter().map(|&(t, w)| w * map.data[t as usize]).sum())
            .collect()
    }
}

/// The sample site of every vertex (see the module docs).
pub fn sample_sites(template: &Template) -> Vec<Option<SampleSite>> {
    let face_uvs = template.face_vertex_uvs();
    let face_points: Vec<(Vec3, Vec2)> = face_uvs
        .iter()
        .enumerate()
        .filter_map(|(v, uv)| uv.map(|uv| (template.neutral[v], uv)))
        .collect();
    let grid = PointGrid::new(&face_points, ATTACH_ZERO_CM);
    (0..template.vertex_count())
        .map(|v| {
            if let Some(uv) = face_uvs[v] {
                return Some(SampleSite { uv, weight: 1.0 });
            }
            let part = template.vertex_part(v as u32).unwrap_or("");
            if RIGID_PARTS.contains(&part) {
                return None;
            }
            let (nearest, dist) = grid.nearest(template.neutral[v])?;
            let weight = attach_weight(dist);
            (weight > 0.0).then_some(SampleSite {
                uv: face_points[nearest].1,
                weight,
            })
        })
        .collect()
}

/// 1 up to [`ATTACH_FULL_CM`], smoothly to 0 at [`ATTACH_ZERO_CM`].
fn attach_weight(dist: f32) -> f32 {
    let t = ((dist - ATTACH_FULL_CM) / (ATTACH_ZERO_CM - ATTACH_FULL_CM)).clamp(0.0, 1.0);
    1.0 - t * t * (3.0 - 2.0 * t)
}

/// A uniform grid over points for nearest-neighbour queries within a fixed radius.
/// Written by hand: the query radius is fixed and small, so 27 cells suffice and a k-d tree
/// crate would be more machinery than the problem needs.
struct PointGrid {
    cell: f32,
    cells: std::collections::HashMap<(i32, i32, i32), Vec<usize>>,
    points: Vec<Vec3>,
}

impl PointGrid {
    fn new(points: &[(Vec3, Vec2)], cell: f32) -> Self {
        let mut cells: std::collections::HashMap<(i32, i32, i32), Vec<usize>> =
            std::collections::HashMap::new();
        for (i, (p, _)) in points.iter().enumerate() {
            cells.entry(Self::key(*p, cell)).or_default().push(i);
        }
        Self {
            cell,
            cells,
            points: points.iter().map(|(p, _)| *p).collect(),
        }
    }

    fn key(p: Vec3, cell: f32) -> (i32, i32, i32) {
        let k = (p / cell).floor();
        (k.x as i32, k.y as i32, k.z as i32)
    }

    /// Nearest point within one cell size, with its distance.
    fn nearest(&self, p: Vec3) -> Option<(usize, f32)> {
        let (kx, ky, kz) = Self::key(p, self.cell);
        let mut best: Option<(usize, f32)> = None;
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let Some(list) = self.cells.get(&(kx + dx, ky + dy, kz + dz)) else {
                        continue;
                    };
                    for &i in list {
                        let d = self.points[i].distance(p);
                        if best.is_none_or(|(_, bd)| d < bd) {
                            best = Some((i, d));
                        }
                    }
                }
            }
        }
        best.filter(|&(_, d)| d <= self.cell)
    }
}
