//! Gaze: the eyeballs turned by the eyeLook weights.
//!
//! ICT FaceKit's 53 shapes leave the eyeballs where they are (its eyeLook shapes move the
//! lids by under a pixel at 128 px), so a tracked gaze would be invisible. Likeness turns
//! each eyeball about its own centre by a fixed angle per unit of weight, the same
//! mapping in the training data (`training/likeness_train/face.py`, `turn_eyes`), the
//! renderer and the Live Link export: yaw = (look towards the subject's left) x 30 degrees,
//! pitch = (down - up) x 25 degrees, with the signs of the head's yaw and pitch
//! ([`crate::camera::euler_to_matrix`]: R = Ry(yaw) Rx(pitch), no roll).

use glam::{Mat3, Vec3};

use crate::names::ict_index;
use crate::template::Template;

/// Degrees of eye yaw per unit of eyeLookIn/Out (ARKit's gaze shapes reach about this far).
pub const GAZE_YAW_DEG_PER_UNIT: f32 = 30.0;
/// Degrees of eye pitch per unit of eyeLookUp/Down.
pub const GAZE_PITCH_DEG_PER_UNIT: f32 = 25.0;
/// The template parts that turn, the subject's left eye (+x) first.
pub const EYEBALL_PARTS: [&str; 2] = ["eyeball_left", "eyeball_right"];

/// (yaw, pitch) in radians of the left and right eye for ICT-ordered weights.
pub fn eye_angles(weights: &[f32; crate::NUM_BLENDSHAPES]) -> [[f32; 2]; 2] {
    let w = |name: &str| ict_index(name).map_or(0.0, |i| weights[i]);
    let yaw = GAZE_YAW_DEG_PER_UNIT.to_radians();
    let pitch = GAZE_PITCH_DEG_PER_UNIT.to_radians();
    [
        [
            (w("eyeLookOut_L") - w("eyeLookIn_L")) * yaw,
            (w("eyeLookDown_L") - w("eyeLookUp_L")) * pitch,
        ],
        [
            (w("eyeLookIn_R") - w("eyeLookOut_R")) * yaw,
            (w("eyeLookDown_R") - w("eyeLookUp_R")) * pitch,
        ],
    ]
}

/// The rotation of one eye: R = Ry(yaw) Rx(pitch).
pub fn eye_rotation([yaw, pitch]: [f32; 2]) -> Mat3 {
    Mat3::from_rotation_y(yaw) * Mat3::from_rotation_x(pitch)
}

/// The eyeballs of a mesh: each eye's vertex range and the centre it turns about.
#[derive(Clone, Debug, PartialEq)]
pub struct Eyes {
    pub ranges: [std::ops::Range<usize>; 2],
    pub centres: [Vec3; 2],
}

impl Eyes {
    /// The eyeballs of `template` at the positions `vertices` (the neutral mesh, or a
    /// person's with their identity); `None` when the template has no eyeball parts. The
    /// centre is the middle of the eyeball's extent across and up, and one radius (half its
    /// width) in front of its back: its extent front to back includes the cornea's bulge.
    pub fn new(template: &Template, vertices: &[Vec3]) -> Option<Self> {
        let range = |name: &str| {
            let part = template.parts.iter().find(|p| p.name == name)?;
            let r = part.vertices.start as usize..part.vertices.end as usize;
            (!r.is_empty() && r.end <= vertices.len()).then_some(r)
        };
        let ranges = [range(EYEBALL_PARTS[0])?, range(EYEBALL_PARTS[1])?];
        let centres = ranges.clone().map(|r| {
            let (low, high) = vertices[r]
                .iter()
                .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), v| {
                    (lo.min(*v), hi.max(*v))
                });
            let mut centre = 0.5 * (low + high);
            centre.z = low.z + 0.5 * (high.x - low.x);
            centre
        });
        Some(Self { ranges, centres })
    }

    /// Turns the eyeballs of `vertices` (positions after equation (2)) by the gaze of
    /// `weights`; `normals`, if given, turn with them.
    pub fn turn(
        &self,
        weights: &[f32; crate::NUM_BLENDSHAPES],
        vertices: &mut [Vec3],
        mut normals: Option<&mut [Vec3]>,
    ) {
        for (k, angles) in eye_angles(weights).into_iter().enumerate() {
            if angles == [0.0, 0.0] {
                continue;
            }
            let rotation = eye_rotation(angles);
            let centre = self.centres[k];
            for v in self.ranges[k].clone() {
                if let Some(p) = vertices.get_mut(v) {
                    *p = centre + rotation * (*p - centre);
                }
                if let Some(n) = normals.as_deref_mut().and_then(|n| n.get_mut(v)) {
                    *n = rotation * *n;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::NUM_BLENDSHAPES;

    #[test]
    fn angles_follow_the_documented_mapping_and_signs() {
        let mut w = [0.0; NUM_BLENDSHAPES];
        let set = |w: &mut [f32; NUM_BLENDSHAPES], name: &str, v: f32| {
            w[ict_index(name).expect("ICT name")] = v;
        };
        set(&mut w, "eyeLookOut_L", 0.5);
        set(&mut w, "eyeLookIn_R", 0.5);
        set(&mut w, "eyeLookUp_L", 1.0);
        set(&mut w, "eyeLookDown_R", 0.2);
        let [left, right] = eye_angles(&w);
        assert!((left[0].to_degrees() - 15.0).abs() < 1e-4, "{left:?}");
        assert!((left[1].to_degrees() + 25.0).abs() < 1e-4, "{left:?}");
        assert!((right[0].to_degrees() - 15.0).abs() < 1e-4, "{right:?}");
        assert!((right[1].to_degrees() - 5.0).abs() < 1e-4, "{right:?}");
        // Positive yaw turns the eye's axis (+z) towards the subject's left (+x), positive
        // pitch down (-y), as the head's.
        let axis = eye_rotation([0.3, 0.0]) * Vec3::Z;
        assert!(axis.x > 0.29 && axis.y.abs() < 1e-6);
        let axis = eye_rotation([0.0, 0.3]) * Vec3::Z;
        assert!(axis.y < -0.29 && axis.x.abs() < 1e-6);
    }

    #[test]
    fn the_templates_eyeballs_turn_rigidly_about_their_centres_and_nothing_else_moves() {
        let template = crate::template::test_template();
        let eyes = Eyes::new(&template, &template.neutral).expect("ICT has eyeballs");
        // The left eye is the subject's left (+x).
        assert!(eyes.centres[0].x > 1.0 && eyes.centres[1].x < -1.0);
        let mut w = [0.0; NUM_BLENDSHAPES];
        w[ict_index("eyeLookOut_L").expect("name")] = 1.0;
        w[ict_index("eyeLookUp_R").expect("name")] = 0.6;
        let mut turned = template.neutral.clone();
        let mut normals = vec![Vec3::Z; turned.len()];
        eyes.turn(&w, &mut turned, Some(&mut normals));
        for (v, (a, b)) in turned.iter().zip(&template.neutral).enumerate() {
            if !eyes.ranges.iter().any(|r| r.contains(&v)) {
                assert_eq!((a, normals[v]), (b, Vec3::Z), "vertex {v} moved");
            }
        }
        // Each vertex keeps its distance from the centre, and the frontmost vertex's
        // direction turns by the mapping's angle: 30 degrees right-handed about +y for the
        // left eye, 15 degrees up (negative pitch) for the right.
        for (k, expected) in [(0, (30.0f32, 0.0f32)), (1, (0.0, -15.0))] {
            let range = eyes.ranges[k].clone();
            let centre = eyes.centres[k];
            let front = range
                .clone()
                .max_by(|&a, &b| template.neutral[a].z.total_cmp(&template.neutral[b].z))
                .expect("vertices");
            for v in range {
                let before = (template.neutral[v] - centre).length();
                assert!(((turned[v] - centre).length() - before).abs() < 1e-4);
            }
            let d0 = template.neutral[front] - centre;
            let d1 = turned[front] - centre;
            let yaw = (d1.x.atan2(d1.z) - d0.x.atan2(d0.z)).to_degrees();
            let pitch =
                ((-d1.y).atan2(d1.x.hypot(d1.z)) - (-d0.y).atan2(d0.x.hypot(d0.z))).to_degrees();
            // The frontmost vertex is ~0.1 mm off the eye's axis: a pure pitch changes its
            // azimuth by ~0.2 degrees.
            assert!((yaw - expected.0).abs() < 0.5, "eye {k}: yaw {yaw}");
            assert!((pitch - expected.1).abs() < 0.5, "eye {k}: pitch {pitch}");
        }
    }
}
