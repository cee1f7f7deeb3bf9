//! Per-frame tracking parameters p = (w, R, t, gamma) of the paper, and the cameras they
//! are expressed in.

use face::NUM_BLENDSHAPES;
use face::camera::{HeadPose, Intrinsics};
use face::sh::SH_COEFFICIENTS;
use glam::{Mat3, Vec3};

/// What TrackNet predicts for one image (after unit conversion), and what refinement and
/// smoothing improve: blendshape weights w in [0, 1] (ICT order), head pose and SH
/// lighting gamma.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FaceParams {
    pub weights: [f32; NUM_BLENDSHAPES],
    pub pose: HeadPose,
    pub gamma: [f32; SH_COEFFICIENTS],
}

impl Default for FaceParams {
    fn default() -> Self {
        Self {
            weights: [0.0; NUM_BLENDSHAPES],
            pose: HeadPose::default(),
            gamma: face::sh::studio_light(),
        }
    }
}

impl FaceParams {
    pub fn is_finite(&self) -> bool {
        self.weights.iter().all(|v| v.is_finite())
            && self.pose.euler_rad.is_finite()
            && self.pose.translation.is_finite()
            && self.gamma.iter().all(|v| v.is_finite())
    }

    pub fn blendshape_weights(&self) -> face::BlendshapeWeights {
        face::BlendshapeWeights(self.weights)
    }
}

/// Rotation between a crop's own camera (principal point at the crop centre, looking
/// through it) and the frame's camera: a network that saw only the crop reports the head
/// in the crop camera, and this turns it into the frame camera exactly (a crop off the
/// image centre is a camera turned towards it, not a shifted one).
pub fn crop_camera_rotation(frame: &Intrinsics, crop_centre_px: glam::Vec2) -> Mat3 {
    // Ray through the crop centre in the frame camera (looking down -z, v down).
    let ray = Vec3::new(
        (crop_centre_px.x - frame.cx) / frame.focal_px,
        -(crop_centre_px.y - frame.cy) / frame.focal_px,
        -1.0,
    )
    .normalize();
    // The rotation taking the crop camera's axis (-z) onto the ray, keeping "up" as close
    // to the frame's as possible (no roll about the axis).
    let forward = -ray; // the crop camera's +z in frame coordinates
    let right = Vec3::Y.cross(forward).normalize_or(Vec3::X);
    let up = forward.cross(right);
    Mat3::from_cols(right, up, forward)
}

/// Re-expresses a head pose from the crop camera in the frame camera.
pub fn pose_in_frame(pose_in_crop: &HeadPose, crop_to_frame: Mat3) -> HeadPose {
    let r = crop_to_frame * pose_in_crop.rotation();
    HeadPose {
        euler_rad: matrix_to_euler(r),
        translation: crop_to_frame * pose_in_crop.translation,
    }
}

/// (yaw, pitch, roll) of R = Rz(roll) Ry(yaw) Rx(pitch), the inverse of
/// `face::camera::euler_to_matrix` for |yaw| < 90 degrees.
pub fn matrix_to_euler(r: Mat3) -> Vec3 {
    // R = Rz Ry Rx: R[2][0] (row 2, col 0) = -sin(yaw).
    let m = r.to_cols_array_2d(); // m[col][row]
    let yaw = (-m[0][2]).clamp(-1.0, 1.0).asin();
    let pitch = m[1][2].atan2(m[2][2]);
    let roll = m[0][1].atan2(m[0][0]);
    Vec3::new(yaw, pitch, roll)
}

/// The camera of a `size` x `size` crop as TrackNet's training assumed it: principal point
/// at the centre, focal length `focal_px`.
pub fn crop_intrinsics(size: u32, focal_px: f32) -> Intrinsics {
    Intrinsics::centered(size, size, focal_px)
}

pub const SH_LEN: usize = SH_COEFFICIENTS;

#[cfg(test)]
mod tests {
    use super::*;
    use face::camera::euler_to_matrix;

    #[test]
    fn euler_round_trip() {
        for e in [
            Vec3::new(0.3, -0.2, 0.1),
            Vec3::new(-1.0, 0.5, -0.4),
            Vec3::ZERO,
            Vec3::new(0.0, 1.2, 2.5),
        ] {
            let back = matrix_to_euler(euler_to_matrix(e));
            assert!((back - e).abs().max_element() < 1e-5, "{e} -> {back}");
        }
    }

    #[test]
    fn crop_rotation_maps_axis_to_ray_and_centre_is_identity() {
        let k = Intrinsics::centered(640, 480, 500.0);
        let r = crop_camera_rotation(&k, glam::Vec2::new(320.0, 240.0));
        assert!((r - Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-6));
        let c = glam::Vec2::new(500.0, 100.0);
        let r = crop_camera_rotation(&k, c);
        // A point on the crop camera's axis projects to the crop centre in the frame.
        let p = r * Vec3::new(0.0, 0.0, -50.0);
        let px = k.project(p).unwrap();
        assert!((px - c).length() < 1e-3, "{px}");
        assert!((r.determinant() - 1.0).abs() < 1e-5);
    }
}
