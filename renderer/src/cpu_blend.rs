//! [`crate::BlendPath::Cpu`]: the blend of `face.wgsl`'s pre-pass (`fs_blend`) computed on
//! the CPU from sparse deltas and uploaded as the blended texture.
//!
//! Why by hand: on a software rasteriser the pre-pass is a fragment shader that, for every
//! vertex, loops over every active shape and reads its delta whether or not the shape moves
//! that vertex (27k vertices x 53 shapes: ~40 ms on lavapipe, `benches/render.rs`). Most
//! blendshapes move a small part of the mesh, so summing only the non-zero deltas on the
//! CPU is far cheaper, and uploading 2V texels is a memory copy there.

/// One blendshape's non-zero deltas: the vertices it moves (ascending) with their position
/// and normal deltas.
#[derive(Clone, Debug, Default, PartialEq)]
struct SparseShape {
    vertices: Vec<u32>,
    position: Vec<[f32; 3]>,
    normal: Vec<[f32; 3]>,
}

/// The mesh data the CPU blend needs: base positions and normals, each shape's sparse
/// deltas, and the eyeballs that turn with the gaze.
#[derive(Clone, Debug, Default, PartialEq)]
pub(crate) struct CpuBlend {
    base_positions: Vec<[f32; 3]>,
    base_normals: Vec<[f32; 3]>,
    shapes: Vec<SparseShape>,
    eyes: Option<face::gaze::Eyes>,
}

/// `face.wgsl`'s `unit_normal`: a degenerate sum falls back to "towards camera".
fn unit_normal(n: [f32; 3]) -> [f32; 3] {
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    if len > 1e-12 {
        let inv = 1.0 / len.max(1e-20);
        [n[0] * inv, n[1] * inv, n[2] * inv]
    } else {
        [0.0, 0.0, 1.0]
    }
}

impl CpuBlend {
    /// Keeps the base shape and the non-zero deltas of `mesh` (validated by the caller:
    /// K * V deltas of each kind).
    pub(crate) fn new(mesh: &crate::MeshData) -> Self {
        let v = mesh.base_positions.len();
        let k = mesh.blend_deltas.len().checked_div(v).unwrap_or(0);
        let shapes = (0..k)
            .map(|s| {
                let mut shape = SparseShape::default();
                let range = s * v..(s + 1) * v;
                let deltas = mesh.blend_deltas[range.clone()]
                    .iter()
                    .zip(&mesh.normal_deltas[range]);
                for (i, (dp, dn)) in deltas.enumerate() {
                    if dp.iter().chain(dn).any(|&x| x != 0.0) {
                        shape.vertices.push(i as u32);
                        shape.position.push(*dp);
                        shape.normal.push(*dn);
                    }
                }
                shape
            })
            .collect();
        Self {
            base_positions: mesh.base_positions.clone(),
            base_normals: mesh.base_normals.clone(),
            shapes,
            eyes: mesh.eyes.clone(),
        }
    }

    /// Non-zero (vertex, shape) pairs kept, out of K * V.
    #[cfg(test)]
    fn stored_deltas(&self) -> usize {
        self.shapes.iter().map(|s| s.vertices.len()).sum()
    }

    /// The blended texture's texels (`texel_count` of them, zero-padded): [0, V) blended
    /// positions, [V, 2V) unit normals, as `fs_blend` writes them. Shapes are added in
    /// ascending order, the order of the GPU's active-weight list, and zero weights are
    /// skipped as they are there; then the eyeballs turn (`EyePose`), as there.
    pub(crate) fn texels(&self, weights: &[f32], texel_count: usize) -> Vec<[f32; 4]> {
        let mut positions = self.base_positions.clone();
        let mut normals = self.base_normals.clone();
        for (shape, &w) in self.shapes.iter().zip(weights) {
            if w == 0.0 {
                continue;
            }
            for ((&i, dp), dn) in shape
                .vertices
                .iter()
                .zip(&shape.position)
                .zip(&shape.normal)
            {
                let (p, n) = (&mut positions[i as usize], &mut normals[i as usize]);
                for c in 0..3 {
                    p[c] += w * dp[c];
                    n[c] += w * dn[c];
                }
            }
        }
        let eyes = crate::eyes::EyePose::new(self.eyes.as_ref(), weights);
        let mut out = Vec::with_capacity(texel_count.max(2 * positions.len()));
        out.extend(positions.iter().enumerate().map(|(v, &p)| {
            let p = match eyes.eye_of(v as u32) {
                Some(e) => eyes.turn_point(e, p),
                None => p,
            };
            [p[0], p[1], p[2], 0.0]
        }));
        out.extend(normals.iter().enumerate().map(|(v, &n)| {
            let u = unit_normal(n);
            let u = match eyes.eye_of(v as u32) {
                Some(e) => eyes.turn(e, u),
                None => u,
            };
            [u[0], u[1], u[2], 0.0]
        }));
        out.resize(texel_count.max(out.len()), [0.0; 4]);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::MeshData;

    /// Three vertices, two shapes: shape 0 moves vertex 1 only, shape 1 moves vertex 0 and
    /// turns vertex 2's normal to nothing.
    fn mesh() -> MeshData {
        MeshData {
            base_positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
            base_normals: vec![[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 1.0]],
            blend_deltas: vec![
                [0.0; 3],
                [0.0, 0.5, 0.0],
                [0.0; 3],
                [2.0, 0.0, 0.0],
                [0.0; 3],
                [0.0; 3],
            ],
            normal_deltas: vec![
                [0.0; 3],
                [3.0, 0.0, -2.0],
                [0.0; 3],
                [0.0; 3],
                [0.0; 3],
                [0.0, 0.0, -1.0],
            ],
            corners: Vec::new(),
            indices: Vec::new(),
            landmark_vertices: Vec::new(),
            eyes: None,
        }
    }

    #[test]
    fn keeps_only_the_deltas_that_move_something() {
        assert_eq!(CpuBlend::new(&mesh()).stored_deltas(), 3);
    }

    #[test]
    fn blends_like_the_dense_sum_and_renormalises_normals() {
        let blend = CpuBlend::new(&mesh());
        let texels = blend.texels(&[0.5, 1.0], 8);
        // Positions: base + 0.5 * shape 0 + 1.0 * shape 1, by hand.
        assert_eq!(texels[0], [2.0, 0.0, 0.0, 0.0]);
        assert_eq!(texels[1], [1.0, 0.25, 0.0, 0.0]);
        assert_eq!(texels[2], [0.0, 1.0, 0.0, 0.0]);
        // Normals: vertex 0 unchanged; vertex 1 (0,0,2) + 0.5 (3,0,-2) = (1.5,0,1), unit;
        // vertex 2 (0,0,1) - (0,0,1) = 0, which falls back to +z.
        assert_eq!(texels[3], [0.0, 0.0, 1.0, 0.0]);
        let len = (1.5f32 * 1.5 + 1.0).sqrt();
        for (got, want) in texels[4].iter().zip([1.5 / len, 0.0, 1.0 / len, 0.0]) {
            assert!((got - want).abs() < 1e-6, "{:?}", texels[4]);
        }
        assert_eq!(texels[5], [0.0, 0.0, 1.0, 0.0]);
        // Padding up to the texture's size.
        assert_eq!(&texels[6..], &[[0.0; 4]; 2]);
    }

    #[test]
    fn zero_weights_give_the_base_shape() {
        let m = mesh();
        let texels = CpuBlend::new(&m).texels(&[0.0, 0.0], 6);
        for v in 0..3 {
            assert_eq!(&texels[v][..3], &m.base_positions[v]);
            assert_eq!(texels[3 + v][..3], unit_normal(m.base_normals[v]));
        }
    }
}
