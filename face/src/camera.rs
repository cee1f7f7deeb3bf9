//! Head pose and the perspective camera Phi of the paper.
//!
//! Conventions (used by the renderer, tracking and the JSON outputs): the camera sits at the
//! origin looking down -z with +y up and +x right (OpenGL). A model point p maps to camera
//! space as R p + t, where R = Rz(roll) Ry(yaw) Rx(pitch) (right-handed rotations about the
//! camera axes, angles in radians here and in degrees in files) and t is in centimetres;
//! a face in front of the camera has t.z < 0. Pixels: u = cx + f X / (-Z),
//! v = cy - f Y / (-Z), so image rows go down.

use glam::{Mat3, Mat4, Vec2, Vec3};

/// Rotation and translation of the head, R and t of the paper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeadPose {
    /// (yaw, pitch, roll) in radians: about +y, +x and +z.
    pub euler_rad: Vec3,
    /// Translation in centimetres, camera space.
    pub translation: Vec3,
}

impl Default for HeadPose {
    fn default() -> Self {
        Self {
            euler_rad: Vec3::ZERO,
            translation: Vec3::new(0.0, 0.0, -60.0),
        }
    }
}

/// R = Rz(roll) Ry(yaw) Rx(pitch) for (yaw, pitch, roll).
pub fn euler_to_matrix(euler_rad: Vec3) -> Mat3 {
    let (yaw, pitch, roll) = (euler_rad.x, euler_rad.y, euler_rad.z);
    Mat3::from_rotation_z(roll) * Mat3::from_rotation_y(yaw) * Mat3::from_rotation_x(pitch)
}

/// dR/d(yaw), dR/d(pitch), dR/d(roll).
pub fn euler_matrix_derivatives(euler_rad: Vec3) -> [Mat3; 3] {
    let (yaw, pitch, roll) = (euler_rad.x, euler_rad.y, euler_rad.z);
    let (rz, ry, rx) = (
        Mat3::from_rotation_z(roll),
        Mat3::from_rotation_y(yaw),
        Mat3::from_rotation_x(pitch),
    );
    // d/dθ of a rotation about axis a is [a]x R.
    let skew = |a: Vec3| {
        Mat3::from_cols(
            Vec3::new(0.0, a.z, -a.y),
            Vec3::new(-a.z, 0.0, a.x),
            Vec3::new(a.y, -a.x, 0.0),
        )
    };
    [
        rz * (skew(Vec3::Y) * ry) * rx,
        rz * ry * (skew(Vec3::X) * rx),
        (skew(Vec3::Z) * rz) * ry * rx,
    ]
}

impl HeadPose {
    pub fn from_degrees(yaw: f32, pitch: f32, roll: f32, translation: Vec3) -> Self {
        Self {
            euler_rad: Vec3::new(yaw, pitch, roll) * (std::f32::consts::PI / 180.0),
            translation,
        }
    }

    /// (yaw, pitch, roll) in degrees.
    pub fn degrees(&self) -> Vec3 {
        self.euler_rad * (180.0 / std::f32::consts::PI)
    }

    pub fn rotation(&self) -> Mat3 {
        euler_to_matrix(self.euler_rad)
    }

    /// R p + t.
    pub fn transform(&self, p: Vec3) -> Vec3 {
        self.rotation() * p + self.translation
    }

    /// The same transform as a 4x4 matrix (camera from model).
    pub fn view_from_model(&self) -> Mat4 {
        Mat4::from_translation(self.translation) * Mat4::from_mat3(self.rotation())
    }
}

/// Focal length in pixels that makes `extent_px` span `fov_deg`.
pub fn focal_length_px(extent_px: u32, fov_deg: f32) -> f32 {
    0.5 * extent_px as f32 / (0.5 * fov_deg.to_radians()).tan()
}

/// Pinhole intrinsics in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub focal_px: f32,
    pub cx: f32,
    pub cy: f32,
    pub width: u32,
    pub height: u32,
}

impl Intrinsics {
    /// Centred principal point and the focal length of a horizontal field of view.
    pub fn from_fov(width: u32, height: u32, horizontal_fov_deg: f32) -> Self {
        Self::centered(width, height, focal_length_px(width, horizontal_fov_deg))
    }

    /// The principal point at the image centre.
    pub fn centered(width: u32, height: u32, focal_px: f32) -> Self {
        Self {
            focal_px,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            width,
            height,
        }
    }

    /// Projects a camera-space point; `None` at or behind the camera plane.
    pub fn project(&self, p_camera: Vec3) -> Option<Vec2> {
        let depth = -p_camera.z;
        (depth > 1e-6).then(|| {
            Vec2::new(
                self.cx + self.focal_px * p_camera.x / depth,
                self.cy - self.focal_px * p_camera.y / depth,
            )
        })
    }

    /// d(pixel)/d(camera-space point), rows (u, v); `None` behind the camera.
    pub fn project_jacobian(&self, p_camera: Vec3) -> Option<[Vec3; 2]> {
        let depth = -p_camera.z;
        (depth > 1e-6).then(|| {
            let f = self.focal_px;
            [
                Vec3::new(f / depth, 0.0, f * p_camera.x / (depth * depth)),
                Vec3::new(0.0, -f / depth, -f * p_camera.y / (depth * depth)),
            ]
        })
    }

    /// An OpenGL-style clip-from-camera matrix with wgpu's [0, 1] depth range for these
    /// pixel intrinsics, so the rasterised image matches [`Intrinsics::project`].
    pub fn clip_from_view(&self, near: f32, far: f32) -> Mat4 {
        let (w, h) = (self.width as f32, self.height as f32);
        let sx = 2.0 * self.focal_px / w;
        let sy = 2.0 * self.focal_px / h;
        // Principal point offset in NDC (image v grows downward, NDC y upward).
        let ox = 1.0 - 2.0 * self.cx / w;
        let oy = 2.0 * self.cy / h - 1.0;
        let a = far / (near - far);
        let b = near * far / (near - far);
        Mat4::from_cols_array(&[
            sx, 0.0, 0.0, 0.0, //
            0.0, sy, 0.0, 0.0, //
            ox, oy, a, -1.0, //
            0.0, 0.0, b, 0.0,
        ])
    }
}

/// A head pose with its rotation matrix and the matrix's derivatives computed once, for
/// projecting many points with their Jacobians (six sines and cosines and a dozen matrix
/// products per pose instead of per point).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseJacobians {
    pub pose: HeadPose,
    pub rotation: Mat3,
    /// dR/d(yaw), dR/d(pitch), dR/d(roll).
    pub rotation_derivatives: [Mat3; 3],
}

impl PoseJacobians {
    pub fn new(pose: HeadPose) -> Self {
        Self {
            pose,
            rotation: pose.rotation(),
            rotation_derivatives: euler_matrix_derivatives(pose.euler_rad),
        }
    }

    /// Projection of model point `p` with d(pixel)/d(yaw, pitch, roll, tx, ty, tz) and
    /// d(pixel)/dp (for chaining with dS/dw). `None` behind the camera.
    pub fn project(
        &self,
        intrinsics: &Intrinsics,
        p: Vec3,
    ) -> Option<(Vec2, [Vec2; 6], [Vec2; 3])> {
        let r = self.rotation;
        let pc = r * p + self.pose.translation;
        let pixel = intrinsics.project(pc)?;
        let [ju, jv] = intrinsics.project_jacobian(pc)?;
        let d_cam = |d: Vec3| Vec2::new(ju.dot(d), jv.dot(d));
        let dr = &self.rotation_derivatives;
        let d_pose = [
            d_cam(dr[0] * p),
            d_cam(dr[1] * p),
            d_cam(dr[2] * p),
            d_cam(Vec3::X),
            d_cam(Vec3::Y),
            d_cam(Vec3::Z),
        ];
        let d_point = [d_cam(r.x_axis), d_cam(r.y_axis), d_cam(r.z_axis)];
        Some((pixel, d_pose, d_point))
    }
}

/// Projection of model point `p` under `pose`, with its derivatives: d(pixel)/d(yaw, pitch,
/// roll, tx, ty, tz) and d(pixel)/dp (for chaining with dS/dw). `None` behind the camera.
/// For many points under one pose, build a [`PoseJacobians`] once.
pub fn project_with_jacobians(
    intrinsics: &Intrinsics,
    pose: &HeadPose,
    p: Vec3,
) -> Option<(Vec2, [Vec2; 6], [Vec2; 3])> {
    PoseJacobians::new(*pose).project(intrinsics, p)
}
