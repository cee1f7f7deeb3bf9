//! Drawing a retargeted puppet with the renderer: a loaded glTF/VRM puppet becomes the
//! renderer's plain [`MeshData`] (every mesh node's primitives in their rest world space, one
//! blendshape per morph target) and [`TextureLayers`] (one layer per material: its base
//! colour texture times its factor, or the factor alone), so morph targets blend on the GPU
//! like the face's.
//!
//! Head rotation turns the whole puppet about its centre: the preview has no skinning, which
//! is exact for puppets whose head node carries the face mesh (the project's puppets, most
//! face-only rigs) and an approximation for skinned full-body avatars.

use anyhow::{Result, bail};
use face::camera::Intrinsics;
use glam::{Mat3, Mat4, Quat, Vec3};
use renderer::{Camera, MAX_BLENDSHAPES, MeshData, OffscreenRenderer, RenderVertex, TextureLayers};
use retarget::{Puppet, PuppetPose};

/// Largest texture side the preview uploads (bigger base colour maps are downsampled).
pub const MAX_LAYER_SIDE: u32 = 1024;
const FIELD_OF_VIEW_DEG: f32 = 30.0;

pub struct PuppetView {
    pub mesh: MeshData,
    pub textures: TextureLayers,
    /// Blendshape k of `mesh` is morph target `shapes[k] = (mesh index, target index)`.
    pub shapes: Vec<(usize, usize)>,
    /// Whether back faces may be culled: no drawn material is double-sided (glTF's
    /// default), and mirrored nodes have had their triangles re-wound so that fronts stay
    /// counter-clockwise. Culling halves the triangles a software rasteriser sets up.
    pub cull_back_faces: bool,
    /// Bounding sphere of the rest pose (world space).
    pub center: Vec3,
    pub radius: f32,
    node_rest_world: Vec<Mat4>,
    node_parent: Vec<Option<usize>>,
    node_rest_rotation: Vec<Quat>,
}

fn normals_of(positions: &[Vec3], indices: &[u32]) -> Vec<Vec3> {
    let triangles: Vec<[u32; 3]> = indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect();
    face::geometry::vertex_normals(positions, &triangles)
}

impl PuppetView {
    pub fn new(puppet: &Puppet) -> Result<Self> {
        let world = puppet.world_matrices(&[]);
        let layer_of_material = |m: Option<usize>| {
            m.filter(|&m| m < puppet.materials.len())
                .map_or(puppet.materials.len(), |m| m)
        };
        // Which (node, mesh) pairs are drawn and which blendshapes they bring.
        let mut shapes: Vec<(usize, usize)> = Vec::new();
        let mut drawn: Vec<(usize, usize)> = Vec::new();
        for (n, node) in puppet.nodes.iter().enumerate() {
            let Some(m) = node.mesh else { continue };
            drawn.push((n, m));
            for t in 0..puppet.meshes[m].target_names.len() {
                if !shapes.contains(&(m, t)) {
                    shapes.push((m, t));
                }
            }
        }
        if shapes.len() > MAX_BLENDSHAPES {
            bail!(
                "{}: {} morph targets in total; the preview draws at most {MAX_BLENDSHAPES}",
                puppet.path.display(),
                shapes.len()
            );
        }
        let mut mesh = MeshData::default();
        let mut deltas: Vec<Vec<[f32; 3]>> = vec![Vec::new(); shapes.len()];
        let mut normal_deltas: Vec<Vec<[f32; 3]>> = vec![Vec::new(); shapes.len()];
        let mut double_sided = false;
        for &(n, m) in &drawn {
            // Skinned meshes are in their skeleton's space at rest: no node transform.
            let transform = if puppet.nodes[n].skin.is_some() {
                Mat4::IDENTITY
            } else {
                world[n]
            };
            let linear = Mat3::from_mat4(transform);
            let normal_matrix = linear.inverse().transpose();
            // glTF: a node whose transform has a negative determinant (a mirror) flips the
            // winding of its triangles.
            let mirrored = linear.determinant() < 0.0;
            for p in &puppet.meshes[m].primitives {
                let base = mesh.base_positions.len() as u32;
                double_sided |= p
                    .material
                    .and_then(|m| puppet.materials.get(m))
                    .is_some_and(|m| m.double_sided);
                let indices: Vec<u32> = if mirrored {
                    p.indices
                        .chunks_exact(3)
                        .flat_map(|t| [t[0], t[2], t[1]])
                        .collect()
                } else {
                    p.indices.clone()
                };
                let positions: Vec<Vec3> = p
                    .positions
                    .iter()
                    .map(|&q| transform.transform_point3(Vec3::from(q)))
                    .collect();
                let normals: Vec<Vec3> = if p.normals.len() == p.positions.len() {
                    p.normals
                        .iter()
                        .map(|&q| (normal_matrix * Vec3::from(q)).normalize_or_zero())
                        .collect()
                } else {
                    normals_of(&positions, &indices)
                };
                for (k, &(sm, st)) in shapes.iter().enumerate() {
                    if sm == m {
                        let target = &p.targets[st];
                        let d: Vec<Vec3> = target
                            .positions
                            .iter()
                            .map(|&q| linear * Vec3::from(q))
                            .collect();
                        let moved: Vec<Vec3> =
                            positions.iter().zip(&d).map(|(a, b)| *a + *b).collect();
                        let moved_normals = if target.normals.len() == positions.len() {
                            normals
                                .iter()
                                .zip(&target.normals)
                                .map(|(a, b)| {
                                    (*a + normal_matrix * Vec3::from(*b)).normalize_or_zero()
                                })
                                .collect()
                        } else {
                            normals_of(&moved, &indices)
                        };
                        deltas[k].extend(d.iter().map(|v| v.to_array()));
                        normal_deltas[k].extend(
                            moved_normals
                                .iter()
                                .zip(&normals)
                                .map(|(a, b)| (*a - *b).to_array()),
                        );
                    } else {
                        deltas[k].extend(std::iter::repeat_n([0.0; 3], positions.len()));
                        normal_deltas[k].extend(std::iter::repeat_n([0.0; 3], positions.len()));
                    }
                }
                let layer = layer_of_material(p.material) as u32;
                for (v, _) in positions.iter().enumerate() {
                    let uv = p.uvs.get(v).copied().unwrap_or([0.0, 0.0]);
                    // glTF UVs start at the top-left; the renderer's at the bottom-left.
                    mesh.corners.push(RenderVertex {
                        vertex: base + v as u32,
                        layer,
                        uv: [uv[0], 1.0 - uv[1]],
                    });
                }
                mesh.indices.extend(indices.iter().map(|i| base + i));
                mesh.base_positions
                    .extend(positions.iter().map(|v| v.to_array()));
                mesh.base_normals
                    .extend(normals.iter().map(|v| v.to_array()));
            }
        }
        if mesh.indices.is_empty() {
            bail!("{}: no triangles to draw", puppet.path.display());
        }
        mesh.blend_deltas = deltas.into_iter().flatten().collect();
        mesh.normal_deltas = normal_deltas.into_iter().flatten().collect();
        let (lo, hi) = mesh.base_positions.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(Vec3::from(*p)), hi.max(Vec3::from(*p))),
        );
        let center = (lo + hi) * 0.5;
        let radius = ((hi - lo).length() * 0.5).max(1e-4);
        Ok(Self {
            mesh,
            textures: texture_layers(puppet),
            shapes,
            cull_back_faces: !double_sided,
            center,
            radius,
            node_rest_world: world,
            node_parent: puppet.nodes.iter().map(|n| n.parent).collect(),
            node_rest_rotation: puppet.nodes.iter().map(|n| n.rotation).collect(),
        })
    }

    /// The renderer's weight vector for a pose.
    pub fn weights(&self, pose: &PuppetPose) -> Vec<f32> {
        self.shapes
            .iter()
            .map(|&(m, t)| {
                pose.morph_weights
                    .get(m)
                    .and_then(|w| w.get(t))
                    .copied()
                    .unwrap_or(0.0)
            })
            .collect()
    }

    /// The world-space rotation the pose's head rotation stands for.
    fn head_world_rotation(&self, pose: &PuppetPose) -> Quat {
        let Some((node, local)) = pose.head else {
            return Quat::IDENTITY;
        };
        let parent = self
            .node_parent
            .get(node)
            .copied()
            .flatten()
            .map_or(Quat::IDENTITY, |p| {
                self.node_rest_world[p].to_scale_rotation_translation().1
            });
        let rest = self
            .node_rest_rotation
            .get(node)
            .copied()
            .unwrap_or(Quat::IDENTITY);
        (parent * local * rest.inverse() * parent.inverse()).normalize()
    }

    /// A camera in front of the puppet (+z) framing its rest bounding sphere; `orbit_yaw_deg`
    /// turns the view around it.
    pub fn camera(&self, pose: &PuppetPose, orbit_yaw_deg: f32, width: u32, height: u32) -> Camera {
        let focal = face::camera::focal_length_px(width.min(height), FIELD_OF_VIEW_DEG);
        let distance = self.radius / (FIELD_OF_VIEW_DEG.to_radians() * 0.5).tan() * 1.05;
        let model = Mat4::from_translation(Vec3::new(0.0, 0.0, -distance))
            * Mat4::from_rotation_y(orbit_yaw_deg.to_radians())
            * Mat4::from_quat(self.head_world_rotation(pose))
            * Mat4::from_translation(-self.center);
        let near = (distance - 2.0 * self.radius).max(distance * 0.01);
        Camera {
            view_from_model: model,
            clip_from_view: Intrinsics::centered(width, height, focal)
                .clip_from_view(near, distance + 2.0 * self.radius),
        }
    }
}

/// One layer per material (base colour texture x factor, or the factor alone) and a last,
/// white layer for primitives without a material; all resized to one square side.
pub fn texture_layers(puppet: &Puppet) -> TextureLayers {
    let side = puppet
        .materials
        .iter()
        .filter_map(|m| m.base_color_image.and_then(|i| puppet.images.get(i)))
        .map(|img| img.width.max(img.height))
        .max()
        .unwrap_or(4)
        .clamp(4, MAX_LAYER_SIDE);
    let texels = (side * side) as usize;
    let mut layers = Vec::with_capacity(puppet.materials.len() + 1);
    for m in &puppet.materials {
        let factor = m.base_color_factor;
        let scaled = |c: [u8; 4]| -> [u8; 4] {
            std::array::from_fn(|k| (f32::from(c[k]) * factor[k].clamp(0.0, 1.0)).round() as u8)
        };
        let layer = match m.base_color_image.and_then(|i| puppet.images.get(i)) {
            Some(img) => {
                match image::RgbaImage::from_raw(img.width, img.height, img.pixels.clone()) {
                    Some(rgba) => {
                        let resized = image::imageops::resize(
                            &rgba,
                            side,
                            side,
                            image::imageops::FilterType::Triangle,
                        );
                        resized.pixels().map(|p| scaled(p.0)).collect()
                    }
                    None => vec![scaled([255; 4]); texels],
                }
            }
            None => vec![scaled([255; 4]); texels],
        };
        layers.push(layer);
    }
    layers.push(vec![[255; 4]; texels]);
    TextureLayers {
        width: side,
        height: side,
        layers,
    }
}

/// Renders a pose offscreen (the renderer must have been made from `view.mesh` and
/// `view.textures`).
pub fn render_puppet(
    renderer: &mut OffscreenRenderer,
    view: &PuppetView,
    pose: &PuppetPose,
    orbit_yaw_deg: f32,
    size: (u32, u32),
) -> Result<image::RgbaImage> {
    renderer
        .face
        .set_weights(&renderer.queue, &view.weights(pose))?;
    let mut params = renderer::FrameParams::new(view.camera(pose, orbit_yaw_deg, size.0, size.1));
    params.sh_coefficients = face::sh::studio_light();
    params.background = [0.11, 0.12, 0.14, 1.0];
    Ok(renderer.render_image(size.0, size.1, &params)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use retarget::puppet::{Material, Mesh, MorphTarget, Node, Primitive};

    /// One triangle, counter-clockwise seen from +z, under a node scaled by `scale`.
    fn one_triangle(scale: Vec3, double_sided: bool) -> Puppet {
        Puppet {
            path: "triangle.glb".into(),
            meshes: vec![Mesh {
                name: "tri".into(),
                target_names: vec!["open".into()],
                default_weights: vec![0.0],
                primitives: vec![Primitive {
                    positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    normals: Vec::new(),
                    uvs: Vec::new(),
                    indices: vec![0, 1, 2],
                    joints: Vec::new(),
                    weights: Vec::new(),
                    material: Some(0),
                    targets: vec![MorphTarget {
                        positions: vec![[0.0; 3], [0.0; 3], [0.0, 0.5, 0.0]],
                        normals: Vec::new(),
                    }],
                }],
            }],
            nodes: vec![Node {
                name: "tri".into(),
                parent: None,
                children: Vec::new(),
                mesh: Some(0),
                skin: None,
                translation: Vec3::ZERO,
                rotation: Quat::IDENTITY,
                scale,
            }],
            skins: Vec::new(),
            materials: vec![Material {
                name: "skin".into(),
                base_color_factor: [1.0; 4],
                base_color_image: None,
                double_sided,
            }],
            images: Vec::new(),
            roots: vec![0],
            vrm: None,
            extensions_used: Vec::new(),
        }
    }

    /// The triangle's normal from its winding, (b - a) x (c - a).
    fn wound_normal(view: &PuppetView) -> Vec3 {
        let corner = |i: usize| {
            let v = view.mesh.corners[view.mesh.indices[i] as usize].vertex as usize;
            Vec3::from(view.mesh.base_positions[v])
        };
        (corner(1) - corner(0)).cross(corner(2) - corner(0))
    }

    #[test]
    fn mirrored_nodes_keep_fronts_counter_clockwise_and_double_sided_stops_culling() {
        let plain = PuppetView::new(&one_triangle(Vec3::ONE, false)).unwrap();
        assert!(plain.cull_back_faces);
        assert!(wound_normal(&plain).z > 0.0);
        // Mirrored in x: the positions flip, the winding is re-ordered, and the front
        // (counter-clockwise side) still faces +z, where the computed normal points.
        let mirrored = PuppetView::new(&one_triangle(Vec3::new(-1.0, 1.0, 1.0), false)).unwrap();
        assert_eq!(mirrored.mesh.base_positions[1], [-1.0, 0.0, 0.0]);
        assert!(wound_normal(&mirrored).z > 0.0);
        assert!(
            mirrored.mesh.base_normals[0][2] > 0.99,
            "{:?}",
            mirrored.mesh.base_normals
        );
        assert!(mirrored.cull_back_faces);
        let double = PuppetView::new(&one_triangle(Vec3::ONE, true)).unwrap();
        assert!(
            !double.cull_back_faces,
            "a double-sided material is drawn from both sides"
        );
    }
}
