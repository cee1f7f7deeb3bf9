//! Mesh geometry used by the losses, the renderer and tracking: vertex normals, the uniform
//! Laplacian of L_sd, and deformation gradients for the blendshape gradient loss L_bg.

use glam::{Mat3, Vec3};

/// Area-weighted vertex normals (unit length; a vertex on no triangle gets +z).
pub fn vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut acc = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        // The cross product's length is twice the area: area weighting for free.
        let n = (b - a).cross(c - a);
        for &i in t {
            acc[i as usize] += n;
        }
    }
    acc.into_iter()
        .map(|n| n.try_normalize().unwrap_or(Vec3::Z))
        .collect()
}

/// Vertex adjacency N_v of the uniform Laplacian: the vertices sharing an edge with v, in
/// compressed rows.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Adjacency {
    offsets: Vec<u32>,
    neighbours: Vec<u32>,
}

impl Adjacency {
    /// Adjacency over the edges of `triangles` for `vertex_count` vertices.
    pub fn from_triangles(vertex_count: usize, triangles: &[[u32; 3]]) -> Self {
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); vertex_count];
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                lists[a as usize].push(b);
                lists[b as usize].push(a);
            }
        }
        let mut offsets = Vec::with_capacity(vertex_count + 1);
        let mut neighbours = Vec::new();
        offsets.push(0);
        for mut l in lists {
            l.sort_unstable();
            l.dedup();
            neighbours.extend(l);
            offsets.push(neighbours.len() as u32);
        }
        Self {
            offsets,
            neighbours,
        }
    }

    pub fn neighbours(&self, v: usize) -> &[u32] {
        &self.neighbours[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }

    pub fn vertex_count(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Uniform Laplacian of a per-vertex field: L(x)_v = x_v - mean over N_v of x_u.
    pub fn laplacian(&self, x: &[Vec3]) -> Vec<Vec3> {
        (0..self.vertex_count())
            .map(|v| {
                let n = self.neighbours(v);
                if n.is_empty() {
                    return Vec3::ZERO;
                }
                let mean = n.iter().map(|&u| x[u as usize]).sum::<Vec3>() / n.len() as f32;
                x[v] - mean
            })
            .collect()
    }

    /// L_sd = sum_v sum_{u in N_v} ||x_v - x_u||^2 (paper's shape smoothness loss; each edge
    /// counts twice, once from each end, exactly as the double sum says).
    pub fn smoothness_loss(&self, x: &[Vec3]) -> f32 {
        (0..self.vertex_count())
            .map(|v| {
                self.neighbours(v)
                    .iter()
                    .map(|&u| (x[v] - x[u as usize]).length_squared())
                    .sum::<f32>()
            })
            .sum()
    }

    /// dL_sd/dx_v = 4 sum_{u in N_v} (x_v - x_u).
    pub fn smoothness_gradient(&self, x: &[Vec3]) -> Vec<Vec3> {
        (0..self.vertex_count())
            .map(|v| {
                4.0 * self
                    .neighbours(v)
                    .iter()
                    .map(|&u| x[v] - x[u as usize])
                    .sum::<Vec3>()
            })
            .collect()
    }
}

/// The 3x3 frame of a triangle in Sumner and Popovic's construction ("Deformation Transfer
/// for Triangle Meshes", 2004): two edges and a fourth vertex along the normal, scaled by
/// 1/sqrt(|e1 x e2|) so the frame is invertible and scales like the triangle.
fn triangle_frame(a: Vec3, b: Vec3, c: Vec3) -> Mat3 {
    let e1 = b - a;
    let e2 = c - a;
    let n = e1.cross(e2);
    let len = n.length();
    let e3 = if len > 0.0 {
        n / len.sqrt()
    } else {
        Vec3::ZERO
    };
    Mat3::from_cols(e1, e2, e3)
}

/// Deformation gradient G_{rest -> deformed} of every triangle: the linear map taking the
/// rest triangle's frame to the deformed one's (G = V_deformed V_rest^-1). Degenerate rest
/// triangles get the identity.
pub fn deformation_gradients(
    rest: &[Vec3],
    deformed: &[Vec3],
    triangles: &[[u32; 3]],
) -> Vec<Mat3> {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| rest[i as usize]);
            let [p, q, r] = t.map(|i| deformed[i as usize]);
            let rest_frame = triangle_frame(a, b, c);
            if rest_frame.determinant().abs() < 1e-12 {
                return Mat3::IDENTITY;
            }
            triangle_frame(p, q, r) * rest_frame.inverse()
        })
        .collect()
}

/// One blendshape's term of L_bg: sum over triangles of
/// ||G_{S0 -> S_i + dS_i} - G_{S0 -> S_i}||_F^2.
pub fn blendshape_gradient_loss(
    neutral: &[Vec3],
    template_shape: &[Vec3],
    corrected_shape: &[Vec3],
    triangles: &[[u32; 3]],
) -> f32 {
    let g_template = deformation_gradients(neutral, template_shape, triangles);
    let g_corrected = deformation_gradients(neutral, corrected_shape, triangles);
    g_template
        .iter()
        .zip(&g_corrected)
        .map(|(a, b)| {
            let d = *b - *a;
            d.x_axis.length_squared() + d.y_axis.length_squared() + d.z_axis.length_squared()
        })
        .sum()
}
