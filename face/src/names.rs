//! Blendshape names: the template's 53 ICT FaceKit expressions and Apple ARKit's 52, and the
//! conversion of weight vectors between them.
//!
//! ICT splits ARKit's `browInnerUp` and `cheekPuff` into `_L`/`_R` halves and has no
//! `tongueOut`. Going ICT -> ARKit a split pair becomes the *mean* of its halves (so a
//! one-sided inner-brow raise of 0.8 reads as 0.4 on the symmetric ARKit shape, which moves
//! about the same amount of skin in total); ARKit -> ICT copies the value into both halves.
//! ARKit's `tongueOut` is always 0 from ICT weights and is dropped going the other way.

use crate::error::{FaceError, Result};

/// Number of expression blendshapes S_i of the template (i = 1..=53 in the paper's notation).
pub const NUM_BLENDSHAPES: usize = 53;
/// Number of ARKit blendshape locations.
pub const NUM_ARKIT: usize = 52;

/// The 53 ICT FaceKit expression names, in the template's order (index i - 1 for S_i).
pub const ICT_NAMES: [&str; NUM_BLENDSHAPES] = [
    "browDown_L",
    "browDown_R",
    "browInnerUp_L",
    "browInnerUp_R",
    "browOuterUp_L",
    "browOuterUp_R",
    "cheekPuff_L",
    "cheekPuff_R",
    "cheekSquint_L",
    "cheekSquint_R",
    "eyeBlink_L",
    "eyeBlink_R",
    "eyeLookDown_L",
    "eyeLookDown_R",
    "eyeLookIn_L",
    "eyeLookIn_R",
    "eyeLookOut_L",
    "eyeLookOut_R",
    "eyeLookUp_L",
    "eyeLookUp_R",
    "eyeSquint_L",
    "eyeSquint_R",
    "eyeWide_L",
    "eyeWide_R",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimple_L",
    "mouthDimple_R",
    "mouthFrown_L",
    "mouthFrown_R",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDown_L",
    "mouthLowerDown_R",
    "mouthPress_L",
    "mouthPress_R",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmile_L",
    "mouthSmile_R",
    "mouthStretch_L",
    "mouthStretch_R",
    "mouthUpperUp_L",
    "mouthUpperUp_R",
    "noseSneer_L",
    "noseSneer_R",
];

/// ARKit's 52 names in camelCase, in the order Live Link Face writes its CSV columns.
pub const ARKIT_NAMES: [&str; NUM_ARKIT] = [
    "eyeBlinkLeft",
    "eyeLookDownLeft",
    "eyeLookInLeft",
    "eyeLookOutLeft",
    "eyeLookUpLeft",
    "eyeSquintLeft",
    "eyeWideLeft",
    "eyeBlinkRight",
    "eyeLookDownRight",
    "eyeLookInRight",
    "eyeLookOutRight",
    "eyeLookUpRight",
    "eyeSquintRight",
    "eyeWideRight",
    "jawForward",
    "jawRight",
    "jawLeft",
    "jawOpen",
    "mouthClose",
    "mouthFunnel",
    "mouthPucker",
    "mouthRight",
    "mouthLeft",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// Index of an ICT name (exact spelling) in [`ICT_NAMES`].
pub fn ict_index(name: &str) -> Option<usize> {
    ICT_NAMES.iter().position(|n| *n == name)
}

/// Index of an ARKit name (exact camelCase spelling) in [`ARKIT_NAMES`].
pub fn arkit_index(name: &str) -> Option<usize> {
    ARKIT_NAMES.iter().position(|n| *n == name)
}

/// Which ICT shapes make up each ARKit shape: one for most, the `_L`/`_R` pair for the two
/// split shapes, none for `tongueOut`.
pub fn arkit_sources(arkit: usize) -> &'static [usize] {
    static TABLE: std::sync::OnceLock<Vec<Vec<usize>>> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        ARKIT_NAMES
            .iter()
            .map(|name| {
                // jawLeft, mouthRight, ... are spelled the same in both sets.
                let single: Vec<usize> = ict_index(name)
                    .or_else(|| ict_index(&arkit_to_ict_name(name)))
                    .into_iter()
                    .collect();
                if !single.is_empty() {
                    return single;
                }
                [format!("{name}_L"), format!("{name}_R")]
                    .iter()
                    .filter_map(|n| ict_index(n))
                    .collect()
            })
            .collect()
    });
    &table[arkit]
}

/// `eyeBlinkLeft` -> `eyeBlink_L`; names without a side are unchanged.
pub fn arkit_to_ict_name(arkit: &str) -> String {
    if let Some(stem) = arkit.strip_suffix("Left") {
        format!("{stem}_L")
    } else if let Some(stem) = arkit.strip_suffix("Right") {
        format!("{stem}_R")
    } else {
        arkit.to_owned()
    }
}

/// Converts 53 ICT weights to 52 ARKit weights (split pairs averaged, `tongueOut` = 0).
pub fn ict_to_arkit(ict: &[f32; NUM_BLENDSHAPES]) -> [f32; NUM_ARKIT] {
    let mut out = [0.0; NUM_ARKIT];
    for (a, value) in out.iter_mut().enumerate() {
        let sources = arkit_sources(a);
        if !sources.is_empty() {
            *value = sources.iter().map(|&i| ict[i]).sum::<f32>() / sources.len() as f32;
        }
    }
    out
}

/// Converts 52 ARKit weights to 53 ICT weights (split shapes copied to both halves,
/// `tongueOut` dropped).
pub fn arkit_to_ict(arkit: &[f32; NUM_ARKIT]) -> [f32; NUM_BLENDSHAPES] {
    let mut out = [0.0; NUM_BLENDSHAPES];
    for (a, &value) in arkit.iter().enumerate() {
        for &i in arkit_sources(a) {
            out[i] = value;
        }
    }
    out
}

/// Resolves a user-typed name (ICT or ARKit spelling, any case) to the ICT indices it sets:
/// one index, or both halves for `browInnerUp`/`cheekPuff`.
pub fn resolve_user_name(name: &str) -> Result<Vec<usize>> {
    let lower = name.trim().to_ascii_lowercase();
    if let Some(i) = ICT_NAMES
        .iter()
        .position(|n| n.to_ascii_lowercase() == lower)
    {
        return Ok(vec![i]);
    }
    if let Some(a) = ARKIT_NAMES
        .iter()
        .position(|n| n.to_ascii_lowercase() == lower)
    {
        let sources = arkit_sources(a);
        if !sources.is_empty() {
            return Ok(sources.to_vec());
        }
    }
    Err(FaceError::UnknownBlendshape(name.to_owned()))
}

#[cfg(test)]
// Tests index parallel arrays (names, weights) by position on purpose.
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;

    #[test]
    fn every_arkit_name_but_tongue_out_has_ict_sources() {
        let mut covered = [0usize; NUM_BLENDSHAPES];
        for a in 0..NUM_ARKIT {
            let sources = arkit_sources(a);
            match ARKIT_NAMES[a] {
                "tongueOut" => assert!(sources.is_empty()),
                "browInnerUp" | "cheekPuff" => assert_eq!(sources.len(), 2),
                _ => assert_eq!(sources.len(), 1, "{}", ARKIT_NAMES[a]),
            }
            for &i in sources {
                covered[i] += 1;
            }
        }
        // Every ICT shape feeds exactly one ARKit shape.
        assert!(covered.iter().all(|&c| c == 1));
    }

    #[test]
    fn arkit_round_trip_preserves_weights() {
        let mut arkit = [0.0f32; NUM_ARKIT];
        for (a, w) in arkit.iter_mut().enumerate() {
            *w = (a as f32 * 0.37).fract();
        }
        arkit[arkit_index("tongueOut").unwrap()] = 0.0;
        let back = ict_to_arkit(&arkit_to_ict(&arkit));
        for (a, name) in ARKIT_NAMES.iter().enumerate() {
            assert!((back[a] - arkit[a]).abs() < 1e-6, "{name}");
        }
    }

    #[test]
    fn split_pair_is_averaged() {
        let mut ict = [0.0f32; NUM_BLENDSHAPES];
        ict[ict_index("browInnerUp_L").unwrap()] = 0.8;
        let arkit = ict_to_arkit(&ict);
        assert!((arkit[arkit_index("browInnerUp").unwrap()] - 0.4).abs() < 1e-6);
    }

    #[test]
    fn user_names_resolve_in_any_spelling() {
        assert_eq!(
            resolve_user_name("JAWOPEN").unwrap(),
            vec![ict_index("jawOpen").unwrap()]
        );
        assert_eq!(
            resolve_user_name("eyeBlinkLeft").unwrap(),
            vec![ict_index("eyeBlink_L").unwrap()]
        );
        assert_eq!(resolve_user_name("cheekPuff").unwrap().len(), 2);
        assert!(resolve_user_name("tongueOut").is_err());
        assert!(resolve_user_name("nonsense").is_err());
    }
}
