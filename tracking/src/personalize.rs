//! Personalization (section 3.2 of the paper at test time): ModelNet on N diverse frames of
//! one person gives their corrections; equations (2) and (3) then make their own
//! blendshapes and dynamic albedo.

use face::PersonalCorrections;

use crate::backend::Tensor;
use crate::error::{Result, TrackingError};
use crate::networks::ModelNet;
use crate::pipeline::FrameOutput;
use crate::select::{Candidate, select_diverse};

/// Default number of frames ModelNet sees (the paper trains with N = 4; more frames
/// average more views of the identity).
pub const DEFAULT_FRAMES: usize = 8;
/// Frames whose face locator confidence is below this are used only when there are too
/// few others.
pub const MIN_CONFIDENCE: f32 = 0.5;

/// Picks up to `n` diverse tracked frames among `outputs` (those with a face and a kept
/// network input) and runs ModelNet on them. Returns the corrections and the indices
/// (into `outputs`) of the frames used.
pub fn personalize(
    model_net: &mut ModelNet,
    outputs: &[FrameOutput],
    n: usize,
) -> Result<(PersonalCorrections, Vec<usize>)> {
    if n == 0 {
        return Err(TrackingError::InvalidInput(
            "personalization needs at least 1 frame".into(),
        ));
    }
    let usable: Vec<usize> = (0..outputs.len())
        .filter(|&i| outputs[i].input.is_some() && outputs[i].tracknet.is_some())
        .collect();
    if usable.is_empty() {
        return Err(TrackingError::InvalidInput(
            "no frame with a face to personalize from".into(),
        ));
    }
    let candidates: Vec<Candidate> = usable
        .iter()
        .filter_map(|&i| {
            Some(Candidate {
                index: i,
                params: outputs[i].tracknet?,
                confidence: outputs[i].confidence,
            })
        })
        .collect();
    let picked: Vec<usize> = select_diverse(&candidates, n, MIN_CONFIDENCE)
        .into_iter()
        .map(|k| candidates[k].index)
        .collect();
    let inputs: Vec<&Tensor> = picked
        .iter()
        .filter_map(|&i| outputs[i].input.as_ref())
        .collect();
    let batch = stack(&inputs)?;
    let corrections = model_net.run(&batch)?;
    Ok((corrections, picked))
}

/// Stacks [1, C, H, W] tensors into [N, C, H, W].
pub fn stack(tensors: &[&Tensor]) -> Result<Tensor> {
    let first = tensors
        .first()
        .ok_or_else(|| TrackingError::InvalidInput("nothing to stack".into()))?;
    if first.shape.first() != Some(&1) || tensors.iter().any(|t| t.shape != first.shape) {
        return Err(TrackingError::InvalidInput(
            "tensors of different shapes".into(),
        ));
    }
    let mut shape = first.shape.clone();
    shape[0] = tensors.len();
    let data = tensors
        .iter()
        .flat_map(|t| t.data.iter().copied())
        .collect();
    Tensor::new(shape, data)
}
