//! The eyeballs' turn for one set of weights ([`face::gaze`]), in the one form that the
//! shaders (through the weights uniform) and the CPU blend both apply after the blend, so
//! every blend path turns the eyes the same way.

use face::gaze::{Eyes, eye_angles, eye_rotation};

/// Per eye: the vertex range that turns (empty when the eye looks straight ahead, so that
/// a still eye is bit for bit the blend), the rows of its rotation and its centre.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(crate) struct EyePose {
    pub ranges: [[u32; 2]; 2],
    pub rows: [[[f32; 3]; 3]; 2],
    pub centres: [[f32; 3]; 2],
}

impl EyePose {
    /// The pose of `eyes` for K `weights` (ICT-ordered when there are eyes: the mesh was
    /// validated for it); no eye turns without eyes.
    pub fn new(eyes: Option<&Eyes>, weights: &[f32]) -> Self {
        let mut pose = Self::default();
        let (Some(eyes), Ok(weights)) = (eyes, <&[f32; face::NUM_BLENDSHAPES]>::try_from(weights))
        else {
            return pose;
        };
        for (e, angles) in eye_angles(weights).into_iter().enumerate() {
            if angles == [0.0, 0.0] {
                continue;
            }
            let rotation = eye_rotation(angles);
            let range = &eyes.ranges[e];
            // Validated against V, which fits in u32 (`MeshData::counts`).
            pose.ranges[e] = [range.start as u32, range.end as u32];
            pose.rows[e] =
                [rotation.row(0), rotation.row(1), rotation.row(2)].map(|r| r.to_array());
            pose.centres[e] = eyes.centres[e].to_array();
        }
        pose
    }

    /// Which eye turns vertex `v`, if any (`eye_of` in `face.wgsl`).
    pub fn eye_of(&self, v: u32) -> Option<usize> {
        self.ranges
            .iter()
            .position(|[start, end]| (*start..*end).contains(&v))
    }

    /// `R d` as `face.wgsl`'s `eye_turn` computes it: a dot product per row.
    pub fn turn(&self, e: usize, d: [f32; 3]) -> [f32; 3] {
        self.rows[e].map(|r| r[0] * d[0] + r[1] * d[1] + r[2] * d[2])
    }

    /// `c + R (p - c)`.
    pub fn turn_point(&self, e: usize, p: [f32; 3]) -> [f32; 3] {
        let c = self.centres[e];
        let t = self.turn(e, [p[0] - c[0], p[1] - c[1], p[2] - c[2]]);
        [c[0] + t[0], c[1] + t[1], c[2] + t[2]]
    }

    /// The `Weights` uniform's eye block: the ranges, then per eye three rows and the centre.
    pub fn uniform(&self) -> ([u32; 4], [[f32; 4]; 8]) {
        let [[a, b], [c, d]] = self.ranges;
        let mut frames = [[0.0; 4]; 8];
        for e in 0..2 {
            for (k, row) in self.rows[e].iter().chain([&self.centres[e]]).enumerate() {
                frames[4 * e + k] = [row[0], row[1], row[2], 0.0];
            }
        }
        ([a, b, c, d], frames)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use face::names::ict_index;
    use glam::Vec3;

    fn eyes() -> Eyes {
        Eyes {
            ranges: [0..2, 2..3],
            centres: [Vec3::new(1.0, 0.0, 0.0), Vec3::new(-1.0, 0.0, 0.0)],
        }
    }

    #[test]
    fn a_still_gaze_turns_nothing_and_a_turned_one_matches_face_gaze() {
        let mut w = [0.0; face::NUM_BLENDSHAPES];
        assert_eq!(EyePose::new(Some(&eyes()), &w), EyePose::default());
        w[ict_index("eyeLookOut_L").unwrap()] = 0.5;
        w[ict_index("eyeLookUp_R").unwrap()] = 0.3;
        let pose = EyePose::new(Some(&eyes()), &w);
        assert_eq!(pose.ranges, [[0, 2], [2, 3]]);
        assert_eq!(
            (pose.eye_of(1), pose.eye_of(2), pose.eye_of(3)),
            (Some(0), Some(1), None)
        );
        // The same vertices turned by face::gaze::Eyes::turn, the reference.
        let points = [
            Vec3::new(1.0, 0.2, 1.0),
            Vec3::new(1.3, -0.4, 0.8),
            Vec3::new(-1.0, 0.0, 1.2),
        ];
        let mut reference = points.to_vec();
        eyes().turn(&w, &mut reference, None);
        for (v, (p, want)) in points.iter().zip(&reference).enumerate() {
            let e = pose.eye_of(v as u32).unwrap();
            let got = Vec3::from(pose.turn_point(e, p.to_array()));
            assert!((got - *want).length() < 1e-6, "{v}: {got} against {want}");
        }
        // No eyes, or weights that are not ICT's 53: nothing turns.
        assert_eq!(EyePose::new(None, &w), EyePose::default());
        assert_eq!(EyePose::new(Some(&eyes()), &w[..5]), EyePose::default());
    }

    #[test]
    fn the_uniform_block_is_rows_then_centre_per_eye() {
        let mut w = [0.0; face::NUM_BLENDSHAPES];
        w[ict_index("eyeLookDown_R").unwrap()] = 1.0;
        let pose = EyePose::new(Some(&eyes()), &w);
        let (ranges, frames) = pose.uniform();
        assert_eq!(ranges, [0, 0, 2, 3]);
        assert_eq!(frames[..4], [[0.0; 4]; 4]);
        assert_eq!(frames[7], [-1.0, 0.0, 0.0, 0.0]);
        for k in 0..3 {
            assert_eq!(frames[4 + k][..3], pose.rows[1][k]);
        }
    }
}
