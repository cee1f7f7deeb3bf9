use crate::{MAX_BLENDSHAPES, RenderError};
use std::collections::HashSet;

/// Everything the GPU needs about one mesh with K blendshapes; built by the caller.
#[derive(Clone, Debug, Default)]
pub struct MeshData {
    /// V vertices: the rest shape (for the face: `S_0 + F(dS_0)`).
    pub base_positions: Vec<[f32; 3]>,
    /// V unit normals of the rest shape.
    pub base_normals: Vec<[f32; 3]>,
    /// K * V, blendshape-major: position delta of shape k at vertex v is
    /// `blend_deltas[k * V + v]`.
    pub blend_deltas: Vec<[f32; 3]>,
    /// K * V, same layout: normal of the shape minus the base normal (the shader
    /// renormalises the blended normal).
    pub normal_deltas: Vec<[f32; 3]>,
    /// Render vertices (a mesh vertex can have several UVs at seams).
    pub corners: Vec<RenderVertex>,
    /// Triangle list into `corners`.
    pub indices: Vec<u32>,
    /// Mesh vertex indices drawn as dots in [`crate::ViewMode::Landmarks`].
    pub landmark_vertices: Vec<u32>,
    /// Eyeballs that turn with the gaze ([`face::gaze`]): each eye's vertex range and the
    /// centre it turns about, after the blend, by the angles of the eyeLook weights. Only for
    /// the 53 ICT-ordered blendshapes; `None` for a mesh without eyes (or a puppet's).
    pub eyes: Option<face::gaze::Eyes>,
}

/// One render vertex: which mesh vertex it shows, and where in the albedo texture array.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
pub struct RenderVertex {
    /// Mesh vertex index (into `MeshData::base_positions`).
    pub vertex: u32,
    /// Albedo texture-array layer.
    pub layer: u32,
    /// UV inside the layer's tile `[0,1]^2`, origin bottom-left (OBJ convention).
    pub uv: [f32; 2],
}

/// Albedo texture array: `layers[l]` is `width * height` RGBA texels, rows top-first,
/// display-encoded colour (uploaded as `Rgba8Unorm`, no sRGB conversion).
#[derive(Clone, Debug, Default)]
pub struct TextureLayers {
    pub width: u32,
    pub height: u32,
    pub layers: Vec<Vec<[u8; 4]>>,
}

/// Sizes derived from a validated [`MeshData`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct MeshCounts {
    pub vertices: u32,
    pub shapes: u32,
    pub corners: u32,
    pub indices: u32,
    pub landmarks: u32,
    /// Highest `RenderVertex::layer` used plus one.
    pub layers_used: u32,
}

fn first_non_finite(values: &[[f32; 3]]) -> Option<usize> {
    values
        .iter()
        .position(|p| !(p[0].is_finite() && p[1].is_finite() && p[2].is_finite()))
}

impl MeshData {
    /// Number of mesh vertices V.
    pub fn vertex_count(&self) -> usize {
        self.base_positions.len()
    }

    /// Number of blendshapes K (rounded down if the deltas do not divide evenly; see
    /// [`Self::validate`]).
    pub fn shape_count(&self) -> usize {
        self.blend_deltas
            .len()
            .checked_div(self.vertex_count())
            .unwrap_or(0)
    }

    /// Check every length, index and value; the error names what is wrong.
    pub fn validate(&self) -> Result<(), RenderError> {
        self.counts().map(|_| ())
    }

    pub(crate) fn counts(&self) -> Result<MeshCounts, RenderError> {
        let bad = |m: String| Err(RenderError::InvalidMesh(m));
        let v = self.base_positions.len();
        if v == 0 {
            return bad("base_positions is empty".into());
        }
        if self.base_normals.len() != v {
            return bad(format!(
                "base_normals has {} entries, base_positions has {v}",
                self.base_normals.len()
            ));
        }
        if !self.blend_deltas.len().is_multiple_of(v) {
            return bad(format!(
                "blend_deltas has {} entries, not a multiple of the vertex count {v}",
                self.blend_deltas.len()
            ));
        }
        let k = self.blend_deltas.len() / v;
        if self.normal_deltas.len() != self.blend_deltas.len() {
            return bad(format!(
                "normal_deltas has {} entries, blend_deltas has {} (K = {k}, V = {v})",
                self.normal_deltas.len(),
                self.blend_deltas.len()
            ));
        }
        if k > MAX_BLENDSHAPES {
            return bad(format!(
                "{k} blendshapes, at most {MAX_BLENDSHAPES} are supported"
            ));
        }
        // (2 + 2K) V texels must be addressable with u32 in the shader.
        if (2 + 2 * k as u64) * v as u64 > u32::MAX as u64 / 2 {
            return bad(format!("{v} vertices x {k} shapes is too large"));
        }
        for (name, values) in [
            ("base_positions", &self.base_positions),
            ("base_normals", &self.base_normals),
            ("blend_deltas", &self.blend_deltas),
            ("normal_deltas", &self.normal_deltas),
        ] {
            if let Some(i) = first_non_finite(values) {
                return bad(format!("{name}[{i}] is not finite: {:?}", values[i]));
            }
        }
        if self.corners.is_empty() {
            return bad("corners is empty".into());
        }
        let mut layers_used = 0;
        for (i, c) in self.corners.iter().enumerate() {
            if c.vertex as usize >= v {
                return bad(format!(
                    "corners[{i}].vertex = {} is out of range (V = {v})",
                    c.vertex
                ));
            }
            if !(c.uv[0].is_finite() && c.uv[1].is_finite()) {
                return bad(format!("corners[{i}].uv is not finite: {:?}", c.uv));
            }
            layers_used = layers_used.max(c.layer.saturating_add(1));
        }
        if !self.indices.len().is_multiple_of(3) {
            return bad(format!(
                "indices has {} entries, not a multiple of 3",
                self.indices.len()
            ));
        }
        if let Some(i) = self
            .indices
            .iter()
            .position(|&i| i as usize >= self.corners.len())
        {
            return bad(format!(
                "indices[{i}] = {} is out of range ({} corners)",
                self.indices[i],
                self.corners.len()
            ));
        }
        if let Some(eyes) = &self.eyes {
            if k != face::NUM_BLENDSHAPES {
                return bad(format!(
                    "eyes turn with ICT's {} blendshapes, the mesh has {k}",
                    face::NUM_BLENDSHAPES
                ));
            }
            for (e, (range, centre)) in eyes.ranges.iter().zip(&eyes.centres).enumerate() {
                if range.start > range.end || range.end > v {
                    return bad(format!(
                        "eye {e}: vertices {range:?} are out of range (V = {v})"
                    ));
                }
                if !centre.is_finite() {
                    return bad(format!("eye {e}: centre {centre} is not finite"));
                }
            }
        }
        if let Some(i) = self.landmark_vertices.iter().position(|&l| l as usize >= v) {
            return bad(format!(
                "landmark_vertices[{i}] = {} is out of range (V = {v})",
                self.landmark_vertices[i]
            ));
        }
        let too_many = |what: &str, n: usize| format!("{what}: {n} is more than u32 can index");
        let to_u32 = |what: &str, n: usize| {
            u32::try_from(n).map_err(|_| RenderError::InvalidMesh(too_many(what, n)))
        };
        Ok(MeshCounts {
            vertices: to_u32("vertices", v)?,
            shapes: k as u32,
            corners: to_u32("corners", self.corners.len())?,
            indices: to_u32("indices", self.indices.len())?,
            landmarks: to_u32("landmarks", self.landmark_vertices.len())?,
            layers_used,
        })
    }

    /// Texels of the geometry data texture, in the layout documented in `face.wgsl`:
    /// base positions, base normals, K position-delta blocks, K normal-delta blocks, each
    /// V texels long, padded with zeros to `width * rows`.
    pub(crate) fn data_texels(&self, width: u32, rows: u32) -> Vec<[f32; 4]> {
        let mut out = Vec::with_capacity((width * rows) as usize);
        let xyz0 = |p: &[f32; 3]| [p[0], p[1], p[2], 0.0];
        out.extend(self.base_positions.iter().map(xyz0));
        out.extend(self.base_normals.iter().map(xyz0));
        out.extend(self.blend_deltas.iter().map(xyz0));
        out.extend(self.normal_deltas.iter().map(xyz0));
        out.resize((width * rows) as usize, [0.0; 4]);
        out
    }

    /// Unique edges of the triangle list as pairs of corner indices (LineList). Edges are
    /// deduplicated by *mesh* vertex, so a UV seam is drawn once rather than twice.
    pub(crate) fn unique_edges(&self) -> Vec<u32> {
        let mut seen = HashSet::with_capacity(self.indices.len());
        let mut out = Vec::with_capacity(self.indices.len());
        for tri in self.indices.chunks_exact(3) {
            for (a, b) in [(tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])] {
                let (va, vb) = (
                    self.corners[a as usize].vertex,
                    self.corners[b as usize].vertex,
                );
                if va == vb {
                    continue;
                }
                if seen.insert((va.min(vb), va.max(vb))) {
                    out.extend([a, b]);
                }
            }
        }
        out
    }
}

/// Texel count of the data texture: `(2 + 2K) V`.
pub(crate) fn data_texel_count(counts: &MeshCounts) -> u64 {
    (2 + 2 * counts.shapes as u64) * counts.vertices as u64
}

impl TextureLayers {
    /// A single-layer texture of one colour (useful for tests and placeholders).
    pub fn solid(width: u32, height: u32, layers: usize, rgba: [u8; 4]) -> Self {
        Self {
            width,
            height,
            layers: vec![vec![rgba; (width * height) as usize]; layers],
        }
    }

    pub(crate) fn validate(&self) -> Result<(), RenderError> {
        let bad = |m: String| Err(RenderError::InvalidTexture(m));
        if self.width == 0 || self.height == 0 {
            return bad(format!("size {}x{} is empty", self.width, self.height));
        }
        if self.layers.is_empty() {
            return bad("no layers".into());
        }
        let texels = self.width as usize * self.height as usize;
        if let Some((i, l)) = self
            .layers
            .iter()
            .enumerate()
            .find(|(_, l)| l.len() != texels)
        {
            return bad(format!(
                "layer {i} has {} texels, expected {}x{} = {texels}",
                l.len(),
                self.width,
                self.height
            ));
        }
        Ok(())
    }
}

/// Full mip chain of one RGBA8 layer by 2x2 box filtering (odd sizes clamp at the edge).
/// Done on the CPU because WebGL2 has no compute and a blit-chain is not worth the code:
/// without mips the albedo aliases badly when the face is small on screen.
pub(crate) fn mip_chain(
    width: u32,
    height: u32,
    base: &[[u8; 4]],
) -> Vec<(u32, u32, Vec<[u8; 4]>)> {
    let mut levels = vec![(width, height, base.to_vec())];
    while let Some((w, h, prev)) = levels.last() {
        let (w, h) = (*w, *h);
        if w == 1 && h == 1 {
            break;
        }
        let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
        let mut next = Vec::with_capacity((nw * nh) as usize);
        for y in 0..nh {
            for x in 0..nw {
                let mut acc = [0u32; 4];
                for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                    let sx = (2 * x + dx).min(w - 1);
                    let sy = (2 * y + dy).min(h - 1);
                    let t = prev[(sy * w + sx) as usize];
                    for c in 0..4 {
                        acc[c] += t[c] as u32;
                    }
                }
                next.push(acc.map(|a| ((a + 2) / 4) as u8));
            }
        }
        levels.push((nw, nh, next));
    }
    levels
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quad() -> MeshData {
        let corners = (0..4)
            .map(|v| RenderVertex {
                vertex: v,
                layer: 0,
                uv: [0.0, 0.0],
            })
            .collect();
        MeshData {
            base_positions: vec![[0.0; 3]; 4],
            base_normals: vec![[0.0, 0.0, 1.0]; 4],
            blend_deltas: vec![[0.0; 3]; 8],
            normal_deltas: vec![[0.0; 3]; 8],
            corners,
            indices: vec![0, 1, 2, 0, 2, 3],
            landmark_vertices: vec![1],
            eyes: None,
        }
    }

    #[test]
    fn counts_and_edges() {
        let m = quad();
        let c = m.counts().unwrap();
        assert_eq!((c.vertices, c.shapes, c.layers_used), (4, 2, 1));
        // 5 unique edges: 4 sides and the diagonal.
        assert_eq!(m.unique_edges().len(), 10);
    }

    #[test]
    fn rejects_bad_data() {
        let mut m = quad();
        m.normal_deltas.pop();
        assert!(
            m.validate()
                .unwrap_err()
                .to_string()
                .contains("normal_deltas")
        );
        let mut m = quad();
        m.indices[4] = 9;
        assert!(m.validate().unwrap_err().to_string().contains("indices[4]"));
        let mut m = quad();
        m.blend_deltas[5][1] = f32::NAN;
        assert!(
            m.validate()
                .unwrap_err()
                .to_string()
                .contains("blend_deltas[5]")
        );
    }

    #[test]
    fn rejects_eyes_it_cannot_turn() {
        let eyes = |end: usize, centre: f32| face::gaze::Eyes {
            ranges: [0..2, 2..end],
            centres: [glam::Vec3::ZERO, glam::Vec3::splat(centre)],
        };
        // Two shapes, not ICT's 53.
        let mut m = quad();
        m.eyes = Some(eyes(4, 0.0));
        assert!(m.validate().unwrap_err().to_string().contains("53"));
        let with_53 = |eyes| {
            let mut m = quad();
            m.blend_deltas = vec![[0.0; 3]; 4 * face::NUM_BLENDSHAPES];
            m.normal_deltas = m.blend_deltas.clone();
            m.eyes = Some(eyes);
            m
        };
        assert!(with_53(eyes(4, 0.0)).validate().is_ok());
        let err = with_53(eyes(5, 0.0)).validate().unwrap_err().to_string();
        assert!(
            err.contains("eye 1") && err.contains("out of range"),
            "{err}"
        );
        let err = with_53(eyes(4, f32::NAN))
            .validate()
            .unwrap_err()
            .to_string();
        assert!(err.contains("eye 1") && err.contains("not finite"), "{err}");
    }

    #[test]
    fn mips_reach_one_texel() {
        let levels = mip_chain(5, 3, &[[10, 20, 30, 255]; 15]);
        assert_eq!(levels.len(), 3);
        assert_eq!(levels[2].0, 1);
        assert_eq!(levels[2].2[0], [10, 20, 30, 255]);
    }
}
