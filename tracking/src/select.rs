//! Choosing the N frames ModelNet sees: the paper feeds ModelNet several images of a person
//! "chosen randomly from different parts of a video to ensure sufficient diversity"; here
//! the choice is deliberate: the most different expressions and head poses.

use face::NUM_BLENDSHAPES;

use crate::params::FaceParams;

/// One candidate frame: its index and TrackNet's parameters.
#[derive(Clone, Copy, Debug)]
pub struct Candidate {
    pub index: usize,
    pub params: FaceParams,
    /// Face locator confidence in [0, 1]; poorly located faces are passed over.
    pub confidence: f32,
}

/// How far apart two frames are: expression distance (L2 over w) plus head-rotation
/// distance, one radian of rotation counting as `pose_weight` of expression.
pub fn frame_distance(a: &FaceParams, b: &FaceParams, pose_weight: f32) -> f32 {
    let dw: f32 = (0..NUM_BLENDSHAPES)
        .map(|i| (a.weights[i] - b.weights[i]).powi(2))
        .sum();
    let de = (a.pose.euler_rad - b.pose.euler_rad).length_squared();
    (dw + pose_weight * pose_weight * de).sqrt()
}

/// Greedy farthest-point selection of up to `n` candidates: start from the most neutral
/// confident frame (the identity is best seen at rest), then repeatedly add the frame
/// farthest from all chosen ones. Candidates below `min_confidence` are used only if
/// there are not enough others. Returns indices into `candidates`, in the order chosen.
pub fn select_diverse(candidates: &[Candidate], n: usize, min_confidence: f32) -> Vec<usize> {
    const POSE_WEIGHT: f32 = 2.0;
    if n == 0 || candidates.is_empty() {
        return Vec::new();
    }
    let mut pool: Vec<usize> = (0..candidates.len())
        .filter(|&i| candidates[i].confidence >= min_confidence)
        .collect();
    if pool.len() < n {
        pool = (0..candidates.len()).collect();
    }
    let activity = |c: &Candidate| {
        c.params.weights.iter().sum::<f32>() + POSE_WEIGHT * c.params.pose.euler_rad.length()
    };
    let first = pool
        .iter()
        .copied()
        .min_by(|&a, &b| activity(&candidates[a]).total_cmp(&activity(&candidates[b])))
        .unwrap_or(0);
    let mut chosen = vec![first];
    let mut nearest: Vec<f32> = pool
        .iter()
        .map(|&i| {
            frame_distance(
                &candidates[i].params,
                &candidates[first].params,
                POSE_WEIGHT,
            )
        })
        .collect();
    while chosen.len() < n.min(pool.len()) {
        let Some((k, _)) = nearest
            .iter()
            .enumerate()
            .filter(|(k, _)| !chosen.contains(&pool[*k]))
            .max_by(|a, b| a.1.total_cmp(b.1))
        else {
            break;
        };
        let pick = pool[k];
        chosen.push(pick);
        for (k, d) in nearest.iter_mut().enumerate() {
            let e = frame_distance(
                &candidates[pool[k]].params,
                &candidates[pick].params,
                POSE_WEIGHT,
            );
            *d = d.min(e);
        }
    }
    chosen
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cand(index: usize, w: &[(usize, f32)], yaw: f32, confidence: f32) -> Candidate {
        let mut params = FaceParams::default();
        for &(i, v) in w {
            params.weights[i] = v;
        }
        params.pose.euler_rad.x = yaw;
        Candidate {
            index,
            params,
            confidence,
        }
    }

    #[test]
    fn picks_neutral_first_then_the_extremes() {
        // Ten near-duplicates of a neutral face, one smile, one open jaw, one turned head.
        let mut c: Vec<Candidate> = (0..10)
            .map(|i| cand(i, &[(0, 0.01 * i as f32)], 0.0, 0.9))
            .collect();
        c.push(cand(10, &[(45, 0.9), (46, 0.9)], 0.0, 0.9));
        c.push(cand(11, &[(26, 1.0)], 0.0, 0.9));
        c.push(cand(12, &[], 0.7, 0.9));
        let picked = select_diverse(&c, 4, 0.5);
        assert_eq!(picked[0], 0, "most neutral first");
        let mut rest = picked[1..].to_vec();
        rest.sort();
        assert_eq!(rest, vec![10, 11, 12]);
    }

    #[test]
    fn skips_low_confidence_unless_needed_and_handles_small_inputs() {
        let c = vec![
            cand(0, &[], 0.0, 0.9),
            cand(1, &[(26, 1.0)], 0.0, 0.1),
            cand(2, &[(10, 0.5)], 0.0, 0.8),
        ];
        let picked = select_diverse(&c, 2, 0.5);
        assert!(!picked.contains(&1));
        assert_eq!(select_diverse(&c, 3, 0.5).len(), 3);
        assert_eq!(select_diverse(&c, 10, 0.5).len(), 3);
        assert!(select_diverse(&[], 4, 0.5).is_empty());
        assert!(select_diverse(&c, 0, 0.5).is_empty());
    }
}
