//! Morph-target and expression names in every convention artists bring, resolved to the
//! 52 ARKit channels the tracker writes.
//!
//! Conventions (field notes, "Conventions"): ARKit camelCase (`eyeBlinkLeft`), Live Link
//! Face PascalCase (`EyeBlinkLeft`), ICT / Maxine / iFacialMocap side suffixes
//! (`eyeBlink_L`, `eyeBlink_R`), exporter prefixes (`blendShape1.jawOpen`,
//! `Face:jawOpen`, `Mesh|jawOpen`), any letter case, `_`, `-` or spaces between words.
//! ICT's split halves (`browInnerUp_L`, `cheekPuff_R`) resolve to ARKit's symmetric
//! channel, which then drives both halves.

use face::names::{ARKIT_NAMES, NUM_ARKIT};

/// Live Link Face's spelling of an ARKit name: the same words with a capital first letter.
pub fn live_link_name(arkit: usize) -> String {
    let name = ARKIT_NAMES[arkit];
    let mut chars = name.chars();
    match chars.next() {
        Some(first) => first.to_ascii_uppercase().to_string() + chars.as_str(),
        None => String::new(),
    }
}

/// The comparable form of a name: the exporter prefix removed, side suffixes spelled out,
/// lower case without separators. `blendShape1.eyeBlink_L` -> `eyeblinkleft`.
pub fn canonical(name: &str) -> String {
    let trimmed = name.trim();
    // Exporter prefixes end with '.', ':' or '|' (Maya namespaces, Face Cap, DCC paths).
    let base = trimmed
        .rsplit(['.', ':', '|'])
        .next()
        .unwrap_or(trimmed)
        .trim();
    let lower = base.to_ascii_lowercase();
    // Side suffixes: `_L`, `-L`, ` L`, `.L` (the dot was taken as a prefix separator, so
    // Blender's `jawOpen.L` style arrives here as `L`; it is handled by the caller below).
    let side_expanded = [
        ("_l", "left"),
        ("-l", "left"),
        (" l", "left"),
        ("_r", "right"),
        ("-r", "right"),
        (" r", "right"),
    ]
    .iter()
    .find_map(|(suffix, side)| {
        lower
            .strip_suffix(suffix)
            .map(|stem| format!("{stem}{side}"))
    })
    .unwrap_or(lower);
    side_expanded
        .chars()
        .filter(|c| c.is_ascii_alphanumeric())
        .collect()
}

/// The ARKit channel a morph-target or clip name stands for, if any.
pub fn arkit_channel(name: &str) -> Option<usize> {
    let key = canonical(&blender_side_suffix(name));
    arkit_by_canonical(&key)
}

/// Blender mirrors sides as `name.L` / `name.R`; the prefix rule would otherwise keep only
/// the `L`.
fn blender_side_suffix(name: &str) -> String {
    let trimmed = name.trim();
    for (suffix, side) in [(".L", "_L"), (".R", "_R"), (".l", "_L"), (".r", "_R")] {
        if let Some(stem) = trimmed.strip_suffix(suffix) {
            return format!("{stem}{side}");
        }
    }
    trimmed.to_owned()
}

fn arkit_by_canonical(key: &str) -> Option<usize> {
    static TABLE: std::sync::OnceLock<Vec<(String, usize)>> = std::sync::OnceLock::new();
    let table = TABLE.get_or_init(|| {
        let mut t: Vec<(String, usize)> = (0..NUM_ARKIT)
            .map(|a| (canonical(ARKIT_NAMES[a]), a))
            .collect();
        // ICT's split halves drive ARKit's symmetric shapes.
        for (half, whole) in [
            ("browInnerUp_L", "browInnerUp"),
            ("browInnerUp_R", "browInnerUp"),
            ("cheekPuff_L", "cheekPuff"),
            ("cheekPuff_R", "cheekPuff"),
        ] {
            if let Some(a) = ARKIT_NAMES.iter().position(|n| *n == whole) {
                t.push((canonical(half), a));
            }
        }
        t
    });
    table.iter().find(|(k, _)| k == key).map(|&(_, a)| a)
}

#[cfg(test)]
mod tests {
    use super::*;
    use face::names::ICT_NAMES;

    #[test]
    fn every_convention_resolves_every_channel() {
        for (a, name) in ARKIT_NAMES.iter().enumerate() {
            let pascal = live_link_name(a);
            let prefixed = format!("blendShape1.{name}");
            let namespaced = format!("Face:{pascal}");
            let upper = name.to_ascii_uppercase();
            for spelling in [name.to_string(), pascal, prefixed, namespaced, upper] {
                assert_eq!(arkit_channel(&spelling), Some(a), "{spelling}");
            }
        }
    }

    #[test]
    fn ict_side_suffixes_and_split_halves_resolve() {
        for ict in ICT_NAMES {
            let a = arkit_channel(ict).unwrap_or_else(|| panic!("{ict} unresolved"));
            let arkit = ARKIT_NAMES[a];
            let stem = ict.trim_end_matches("_L").trim_end_matches("_R");
            assert!(arkit.starts_with(stem), "{ict} -> {arkit}");
        }
        assert_eq!(
            arkit_channel("eyeBlink.L").map(|a| ARKIT_NAMES[a]),
            Some("eyeBlinkLeft")
        );
        assert_eq!(
            arkit_channel("mouth_smile_r").map(|a| ARKIT_NAMES[a]),
            Some("mouthSmileRight")
        );
    }

    #[test]
    fn unrelated_names_do_not_resolve() {
        for name in [
            "",
            "_neutral",
            "Basis",
            "jaw",
            "eyeBlinkLeftt",
            "vrc.v_aa",
            "smile",
        ] {
            assert_eq!(arkit_channel(name), None, "{name}");
        }
    }
}
