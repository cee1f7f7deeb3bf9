use glam::Mat4;

/// Model-to-clip transform split into the rigid part (used for shading normals, which are
/// shaded in view space) and the projection.
///
/// Conventions: view space looks down -z with +y up (OpenGL style); clip depth is wgpu's
/// `[0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Rigid (rotation + translation, optionally uniform scale) model -> view transform.
    pub view_from_model: Mat4,
    /// Projection view -> clip.
    pub clip_from_view: Mat4,
}

impl Camera {
    /// Perspective camera for pinhole intrinsics in pixels.
    ///
    /// A view-space point `(x, y, z)` (z < 0 in front of the camera) lands at pixel
    /// `u = cx + focal_px * x / -z`, `v = cy - focal_px * y / -z`, with the image's y axis
    /// pointing down and pixel `(i, j)` covering `[i, i+1] x [j, j+1]` (so the image centre is
    /// `(width / 2, height / 2)`). Depth maps `-near -> 0`, `-far -> 1`.
    #[allow(clippy::too_many_arguments)] // mirrors the usual intrinsics argument list
    pub fn from_intrinsics(
        focal_px: f32,
        cx: f32,
        cy: f32,
        width: u32,
        height: u32,
        near: f32,
        far: f32,
        view_from_model: Mat4,
    ) -> Self {
        // One definition of the pixel camera for the whole project: the face crate's.
        let intrinsics = face::camera::Intrinsics {
            focal_px,
            cx,
            cy,
            width: width.max(1),
            height: height.max(1),
        };
        let clip_from_view = intrinsics.clip_from_view(near, far);
        Self {
            view_from_model,
            clip_from_view,
        }
    }

    /// Pixel coordinates (image y down) of a model-space point, or `None` behind the camera.
    /// The CPU counterpart of the vertex shader's projection, for tests and overlays.
    pub fn project_to_pixel(&self, p: glam::Vec3, width: u32, height: u32) -> Option<glam::Vec2> {
        let clip = self.clip_from_view * self.view_from_model * p.extend(1.0);
        if clip.w <= 0.0 {
            return None;
        }
        let ndc = clip.truncate() / clip.w;
        Some(glam::Vec2::new(
            (ndc.x + 1.0) * 0.5 * width as f32,
            (1.0 - ndc.y) * 0.5 * height as f32,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn intrinsics_projection_matches_pinhole_model() {
        let cam = Camera::from_intrinsics(500.0, 300.0, 200.0, 640, 480, 0.1, 10.0, Mat4::IDENTITY);
        let p = Vec3::new(0.2, 0.1, -2.0);
        let px = cam.project_to_pixel(p, 640, 480).unwrap();
        assert!((px.x - (300.0 + 500.0 * 0.2 / 2.0)).abs() < 1e-3, "{px}");
        assert!((px.y - (200.0 - 500.0 * 0.1 / 2.0)).abs() < 1e-3, "{px}");
        let near = cam.clip_from_view * Vec3::new(0.0, 0.0, -0.1).extend(1.0);
        let far = cam.clip_from_view * Vec3::new(0.0, 0.0, -10.0).extend(1.0);
        assert!((near.z / near.w).abs() < 1e-5);
        assert!((far.z / far.w - 1.0).abs() < 1e-5);
    }
}
