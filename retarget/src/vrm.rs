//! VRM expressions (1.0 `VRMC_vrm`, 0.x `VRM` extension): the presets, the 0.x -> 1.0
//! names, the humanoid head bone, and how tracked ARKit weights drive the presets.
//!
//! Preset weights from ARKit weights (all in [0, 1]; `mean` of left and right):
//!
//! | preset | formula |
//! |---|---|
//! | `blink` | `min(eyeBlinkLeft, eyeBlinkRight)` |
//! | `blinkLeft` / `blinkRight` | `eyeBlinkLeft - blink` / `eyeBlinkRight - blink` (the part of a wink `blink` does not already close) |
//! | `aa` | `jawOpen` |
//! | `ih` | `mean(mouthUpperUp)` |
//! | `ou` | `mouthPucker` |
//! | `ee` | `mean(mouthStretch)` |
//! | `oh` | `mouthFunnel` |
//! | `happy` | `mean(mouthSmile)` |
//! | `angry` | `mean(browDown)` |
//! | `sad` | `mean(mouthFrown)` |
//! | `relaxed` | `min(mean(mouthSmile), mean(eyeSquint))` |
//! | `surprised` | `(browInnerUp + mean(eyeWide)) / 2` |
//! | `lookUp` / `lookDown` | `mean(eyeLookUp)` / `mean(eyeLookDown)` |
//! | `lookLeft` | `mean(eyeLookOutLeft, eyeLookInRight)` (towards the performer's left) |
//! | `lookRight` | `mean(eyeLookInLeft, eyeLookOutRight)` |
//! | `neutral` | 0 |
//!
//! VRM "perfect sync" clips named as ARKit's are driven directly by their channel instead.

use face::names::NUM_ARKIT;
use serde_json::Value;

/// The VRM 1.0 expression presets.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum VrmPreset {
    Happy,
    Angry,
    Sad,
    Relaxed,
    Surprised,
    Aa,
    Ih,
    Ou,
    Ee,
    Oh,
    Blink,
    BlinkLeft,
    BlinkRight,
    LookUp,
    LookDown,
    LookLeft,
    LookRight,
    Neutral,
}

pub const ALL_PRESETS: [VrmPreset; 18] = [
    VrmPreset::Happy,
    VrmPreset::Angry,
    VrmPreset::Sad,
    VrmPreset::Relaxed,
    VrmPreset::Surprised,
    VrmPreset::Aa,
    VrmPreset::Ih,
    VrmPreset::Ou,
    VrmPreset::Ee,
    VrmPreset::Oh,
    VrmPreset::Blink,
    VrmPreset::BlinkLeft,
    VrmPreset::BlinkRight,
    VrmPreset::LookUp,
    VrmPreset::LookDown,
    VrmPreset::LookLeft,
    VrmPreset::LookRight,
    VrmPreset::Neutral,
];

impl VrmPreset {
    /// The VRM 1.0 name.
    pub fn name(self) -> &'static str {
        match self {
            VrmPreset::Happy => "happy",
            VrmPreset::Angry => "angry",
            VrmPreset::Sad => "sad",
            VrmPreset::Relaxed => "relaxed",
            VrmPreset::Surprised => "surprised",
            VrmPreset::Aa => "aa",
            VrmPreset::Ih => "ih",
            VrmPreset::Ou => "ou",
            VrmPreset::Ee => "ee",
            VrmPreset::Oh => "oh",
            VrmPreset::Blink => "blink",
            VrmPreset::BlinkLeft => "blinkLeft",
            VrmPreset::BlinkRight => "blinkRight",
            VrmPreset::LookUp => "lookUp",
            VrmPreset::LookDown => "lookDown",
            VrmPreset::LookLeft => "lookLeft",
            VrmPreset::LookRight => "lookRight",
            VrmPreset::Neutral => "neutral",
        }
    }

    /// A 1.0 name or a 0.x preset name (`a` -> `aa`, `joy` -> `happy`, `sorrow` -> `sad`,
    /// `fun` -> `relaxed`, `blink_l` -> `blinkLeft`, ...), any case.
    pub fn parse(name: &str) -> Option<Self> {
        let key: String = name
            .trim()
            .to_ascii_lowercase()
            .chars()
            .filter(|c| c.is_ascii_alphanumeric())
            .collect();
        let legacy = match key.as_str() {
            "a" => Some(VrmPreset::Aa),
            "i" => Some(VrmPreset::Ih),
            "u" => Some(VrmPreset::Ou),
            "e" => Some(VrmPreset::Ee),
            "o" => Some(VrmPreset::Oh),
            "joy" => Some(VrmPreset::Happy),
            "sorrow" => Some(VrmPreset::Sad),
            "fun" => Some(VrmPreset::Relaxed),
            "blinkl" => Some(VrmPreset::BlinkLeft),
            "blinkr" => Some(VrmPreset::BlinkRight),
            _ => None,
        };
        legacy.or_else(|| {
            ALL_PRESETS
                .into_iter()
                .find(|p| p.name().to_ascii_lowercase() == key)
        })
    }

    /// The preset's weight from ARKit weights (the module's table).
    pub fn weight(self, arkit: &[f32; NUM_ARKIT]) -> f32 {
        // Runs per frame and preset: name lookups only, no allocation.
        let w = |name: &str| face::names::arkit_index(name).map_or(0.0, |a| arkit[a]);
        let mean = |left: &str, right: &str| 0.5 * (w(left) + w(right));
        let blink = w("eyeBlinkLeft").min(w("eyeBlinkRight"));
        let value = match self {
            VrmPreset::Blink => blink,
            VrmPreset::BlinkLeft => w("eyeBlinkLeft") - blink,
            VrmPreset::BlinkRight => w("eyeBlinkRight") - blink,
            VrmPreset::Aa => w("jawOpen"),
            VrmPreset::Ih => mean("mouthUpperUpLeft", "mouthUpperUpRight"),
            VrmPreset::Ou => w("mouthPucker"),
            VrmPreset::Ee => mean("mouthStretchLeft", "mouthStretchRight"),
            VrmPreset::Oh => w("mouthFunnel"),
            VrmPreset::Happy => mean("mouthSmileLeft", "mouthSmileRight"),
            VrmPreset::Angry => mean("browDownLeft", "browDownRight"),
            VrmPreset::Sad => mean("mouthFrownLeft", "mouthFrownRight"),
            VrmPreset::Relaxed => mean("mouthSmileLeft", "mouthSmileRight")
                .min(mean("eyeSquintLeft", "eyeSquintRight")),
            VrmPreset::Surprised => 0.5 * (w("browInnerUp") + mean("eyeWideLeft", "eyeWideRight")),
            VrmPreset::LookUp => mean("eyeLookUpLeft", "eyeLookUpRight"),
            VrmPreset::LookDown => mean("eyeLookDownLeft", "eyeLookDownRight"),
            VrmPreset::LookLeft => 0.5 * (w("eyeLookOutLeft") + w("eyeLookInRight")),
            VrmPreset::LookRight => 0.5 * (w("eyeLookInLeft") + w("eyeLookOutRight")),
            VrmPreset::Neutral => 0.0,
        };
        value.clamp(0.0, 1.0)
    }

    /// The ARKit channels the preset's formula reads.
    pub fn inputs(self) -> &'static [&'static str] {
        match self {
            VrmPreset::Blink | VrmPreset::BlinkLeft | VrmPreset::BlinkRight => {
                &["eyeBlinkLeft", "eyeBlinkRight"]
            }
            VrmPreset::Aa => &["jawOpen"],
            VrmPreset::Ih => &["mouthUpperUpLeft", "mouthUpperUpRight"],
            VrmPreset::Ou => &["mouthPucker"],
            VrmPreset::Ee => &["mouthStretchLeft", "mouthStretchRight"],
            VrmPreset::Oh => &["mouthFunnel"],
            VrmPreset::Happy => &["mouthSmileLeft", "mouthSmileRight"],
            VrmPreset::Angry => &["browDownLeft", "browDownRight"],
            VrmPreset::Sad => &["mouthFrownLeft", "mouthFrownRight"],
            VrmPreset::Relaxed => &[
                "mouthSmileLeft",
                "mouthSmileRight",
                "eyeSquintLeft",
                "eyeSquintRight",
            ],
            VrmPreset::Surprised => &["browInnerUp", "eyeWideLeft", "eyeWideRight"],
            VrmPreset::LookUp => &["eyeLookUpLeft", "eyeLookUpRight"],
            VrmPreset::LookDown => &["eyeLookDownLeft", "eyeLookDownRight"],
            VrmPreset::LookLeft => &["eyeLookOutLeft", "eyeLookInRight"],
            VrmPreset::LookRight => &["eyeLookInLeft", "eyeLookOutRight"],
            VrmPreset::Neutral => &[],
        }
    }

    /// Which override group the preset belongs to (VRM 1.0 `overrideBlink`, `overrideLookAt`,
    /// `overrideMouth` act on these).
    pub fn group(self) -> Option<OverrideGroup> {
        match self {
            VrmPreset::Blink | VrmPreset::BlinkLeft | VrmPreset::BlinkRight => {
                Some(OverrideGroup::Blink)
            }
            VrmPreset::LookUp
            | VrmPreset::LookDown
            | VrmPreset::LookLeft
            | VrmPreset::LookRight => Some(OverrideGroup::LookAt),
            VrmPreset::Aa | VrmPreset::Ih | VrmPreset::Ou | VrmPreset::Ee | VrmPreset::Oh => {
                Some(OverrideGroup::Mouth)
            }
            _ => None,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum OverrideGroup {
    Blink,
    LookAt,
    Mouth,
}

/// VRM 1.0 override settings: how an active expression suppresses a group.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Override {
    #[default]
    None,
    Block,
    Blend,
}

impl Override {
    fn parse(v: Option<&Value>) -> Self {
        match v.and_then(Value::as_str) {
            Some("block") => Override::Block,
            Some("blend") => Override::Blend,
            _ => Override::None,
        }
    }
}

/// One morph-target bind of an expression: mesh index in the document, target index, weight
/// in [0, 1] (VRM 0.x's 0-100 is divided by 100).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MorphBind {
    pub mesh: usize,
    pub target: usize,
    pub weight: f32,
}

/// One expression of a VRM file.
#[derive(Clone, Debug, PartialEq)]
pub struct VrmExpression {
    /// The name as written (a preset key, a custom name, or a 0.x group name).
    pub name: String,
    pub preset: Option<VrmPreset>,
    pub binds: Vec<MorphBind>,
    pub is_binary: bool,
    pub override_blink: Override,
    pub override_look_at: Override,
    pub override_mouth: Override,
}

/// What a VRM extension tells the retargeter.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VrmInfo {
    /// "1.0" or "0.x".
    pub version: String,
    pub expressions: Vec<VrmExpression>,
    /// The humanoid `head` bone's node index.
    pub head_node: Option<usize>,
    pub neck_node: Option<usize>,
}

/// Reads `VRMC_vrm` (1.0) first, then `VRM` (0.x), as three-vrm's loaders do. `node_mesh`
/// gives each node's mesh index (1.0 binds name nodes, 0.x binds name meshes). Malformed
/// entries are skipped with a warning rather than refusing the whole puppet; an
/// out-of-range index is reported as an error by the caller's check of `binds`.
pub fn read_vrm(extensions: Option<&Value>, node_mesh: &[Option<usize>]) -> Option<VrmInfo> {
    let ext = extensions?;
    if let Some(v1) = ext.get("VRMC_vrm") {
        return Some(read_v1(v1, node_mesh));
    }
    ext.get("VRM").map(read_v0)
}

fn index(v: Option<&Value>) -> Option<usize> {
    v.and_then(Value::as_u64)
        .and_then(|i| usize::try_from(i).ok())
}

fn read_v1(v1: &Value, node_mesh: &[Option<usize>]) -> VrmInfo {
    let mut info = VrmInfo {
        version: "1.0".into(),
        ..VrmInfo::default()
    };
    let bones = v1.pointer("/humanoid/humanBones");
    info.head_node = index(bones.and_then(|b| b.pointer("/head/node")));
    info.neck_node = index(bones.and_then(|b| b.pointer("/neck/node")));
    let Some(expressions) = v1.get("expressions") else {
        return info;
    };
    for (group, is_preset) in [("preset", true), ("custom", false)] {
        let Some(map) = expressions.get(group).and_then(Value::as_object) else {
            continue;
        };
        for (name, e) in map {
            let mut binds = Vec::new();
            for b in e
                .get("morphTargetBinds")
                .and_then(Value::as_array)
                .into_iter()
                .flatten()
            {
                let (Some(node), Some(target)) = (index(b.get("node")), index(b.get("index")))
                else {
                    tracing::warn!(
                        "VRM expression {name}: a bind without node or index is skipped"
                    );
                    continue;
                };
                let Some(mesh) = node_mesh.get(node).copied().flatten() else {
                    tracing::warn!(
                        "VRM expression {name}: bind to node {node}, which has no mesh, is skipped"
                    );
                    continue;
                };
                let weight = b.get("weight").and_then(Value::as_f64).unwrap_or(1.0) as f32;
                binds.push(MorphBind {
                    mesh,
                    target,
                    weight: weight.clamp(0.0, 1.0),
                });
            }
            info.expressions.push(VrmExpression {
                name: name.clone(),
                preset: if is_preset {
                    VrmPreset::parse(name)
                } else {
                    None
                },
                binds,
                is_binary: e.get("isBinary").and_then(Value::as_bool).unwrap_or(false),
                override_blink: Override::parse(e.get("overrideBlink")),
                override_look_at: Override::parse(e.get("overrideLookAt")),
                override_mouth: Override::parse(e.get("overrideMouth")),
            });
        }
    }
    info
}

fn read_v0(v0: &Value) -> VrmInfo {
    let mut info = VrmInfo {
        version: "0.x".into(),
        ..VrmInfo::default()
    };
    for bone in v0
        .pointer("/humanoid/humanBones")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        match bone.get("bone").and_then(Value::as_str) {
            Some("head") => info.head_node = index(bone.get("node")),
            Some("neck") => info.neck_node = index(bone.get("node")),
            _ => {}
        }
    }
    for g in v0
        .pointer("/blendShapeMaster/blendShapeGroups")
        .and_then(Value::as_array)
        .into_iter()
        .flatten()
    {
        let name = g
            .get("name")
            .and_then(Value::as_str)
            .unwrap_or_default()
            .to_owned();
        let preset_name = g
            .get("presetName")
            .and_then(Value::as_str)
            .unwrap_or("unknown");
        let preset = if preset_name == "unknown" {
            None
        } else {
            VrmPreset::parse(preset_name)
        };
        let mut binds = Vec::new();
        for b in g
            .get("binds")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
        {
            let (Some(mesh), Some(target)) = (index(b.get("mesh")), index(b.get("index"))) else {
                tracing::warn!("VRM 0.x group {name}: a bind without mesh or index is skipped");
                continue;
            };
            // 0.x weights are percentages.
            let weight = b.get("weight").and_then(Value::as_f64).unwrap_or(100.0) as f32 / 100.0;
            binds.push(MorphBind {
                mesh,
                target,
                weight: weight.clamp(0.0, 1.0),
            });
        }
        info.expressions.push(VrmExpression {
            name: if name.is_empty() {
                preset_name.to_owned()
            } else {
                name
            },
            preset,
            binds,
            is_binary: g.get("isBinary").and_then(Value::as_bool).unwrap_or(false),
            override_blink: Override::None,
            override_look_at: Override::None,
            override_mouth: Override::None,
        });
    }
    info
}

#[cfg(test)]
mod tests {
    use super::*;
    use face::names::{ARKIT_NAMES, arkit_index};

    fn arkit(pairs: &[(&str, f32)]) -> [f32; NUM_ARKIT] {
        let mut w = [0.0; NUM_ARKIT];
        for (n, v) in pairs {
            w[arkit_index(n).unwrap()] = *v;
        }
        w
    }

    #[test]
    fn legacy_names_map_to_1_0() {
        for (old, new) in [
            ("A", "aa"),
            ("Joy", "happy"),
            ("Sorrow", "sad"),
            ("Fun", "relaxed"),
            ("Blink_L", "blinkLeft"),
            ("blink_r", "blinkRight"),
            ("LookUp", "lookUp"),
            ("O", "oh"),
        ] {
            assert_eq!(
                VrmPreset::parse(old).map(VrmPreset::name),
                Some(new),
                "{old}"
            );
        }
        for p in ALL_PRESETS {
            assert_eq!(VrmPreset::parse(p.name()), Some(p));
        }
        assert_eq!(VrmPreset::parse("smirk"), None);
    }

    #[test]
    fn formulas_match_the_table() {
        let w = arkit(&[
            ("eyeBlinkLeft", 0.9),
            ("eyeBlinkRight", 0.3),
            ("jawOpen", 0.7),
            ("mouthSmileLeft", 0.6),
            ("mouthSmileRight", 0.2),
            ("eyeSquintLeft", 0.1),
            ("eyeSquintRight", 0.1),
            ("eyeLookOutLeft", 0.8),
            ("eyeLookInRight", 0.6),
        ]);
        let close = |p: VrmPreset, v: f32| {
            assert!(
                (p.weight(&w) - v).abs() < 1e-6,
                "{}: {} vs {v}",
                p.name(),
                p.weight(&w)
            )
        };
        close(VrmPreset::Blink, 0.3);
        close(VrmPreset::BlinkLeft, 0.6);
        close(VrmPreset::BlinkRight, 0.0);
        close(VrmPreset::Aa, 0.7);
        close(VrmPreset::Happy, 0.4);
        close(VrmPreset::Relaxed, 0.1);
        close(VrmPreset::LookLeft, 0.7);
        close(VrmPreset::LookRight, 0.0);
        close(VrmPreset::Neutral, 0.0);
    }

    #[test]
    fn inputs_are_exactly_what_the_formulas_read() {
        for p in ALL_PRESETS {
            for (a, name) in ARKIT_NAMES.iter().enumerate() {
                // Every channel at 0.5 except this one at 1: the formula changes only if it reads it.
                let mut w = [0.5f32; NUM_ARKIT];
                let base = p.weight(&w);
                w[a] = 1.0;
                let reads = (p.weight(&w) - base).abs() > 1e-6;
                // `blink*` read both eyes through a min, which one eye alone may not move.
                let listed = p.inputs().contains(name);
                if reads {
                    assert!(listed, "{} reads {name} but does not list it", p.name());
                } else if listed
                    && !matches!(
                        p,
                        VrmPreset::Blink
                            | VrmPreset::BlinkLeft
                            | VrmPreset::BlinkRight
                            | VrmPreset::Relaxed
                    )
                {
                    panic!("{} lists {name} but does not read it", p.name());
                }
            }
        }
    }

    #[test]
    fn reads_both_versions() {
        let v1: Value = serde_json::json!({"VRMC_vrm": {
            "humanoid": {"humanBones": {"head": {"node": 3}, "neck": {"node": 2}}},
            "expressions": {
                "preset": {"happy": {"morphTargetBinds": [{"node": 1, "index": 4, "weight": 0.5}], "overrideBlink": "block"}},
                "custom": {"jawOpen": {"morphTargetBinds": [{"node": 1, "index": 7}], "isBinary": true}}
            }
        }});
        let node_mesh = [None, Some(0), None, None];
        let info = read_vrm(Some(&v1), &node_mesh).unwrap();
        assert_eq!(
            (info.version.as_str(), info.head_node, info.neck_node),
            ("1.0", Some(3), Some(2))
        );
        let happy = info.expressions.iter().find(|e| e.name == "happy").unwrap();
        assert_eq!(happy.preset, Some(VrmPreset::Happy));
        assert_eq!(
            happy.binds,
            vec![MorphBind {
                mesh: 0,
                target: 4,
                weight: 0.5
            }]
        );
        assert_eq!(happy.override_blink, Override::Block);
        let jaw = info
            .expressions
            .iter()
            .find(|e| e.name == "jawOpen")
            .unwrap();
        assert!(jaw.is_binary && jaw.preset.is_none());

        let v0: Value = serde_json::json!({"VRM": {
            "humanoid": {"humanBones": [{"bone": "head", "node": 5}]},
            "blendShapeMaster": {"blendShapeGroups": [
                {"name": "Joy", "presetName": "joy", "binds": [{"mesh": 2, "index": 1, "weight": 100}]},
                {"name": "A", "presetName": "a", "binds": [{"mesh": 2, "index": 0, "weight": 50}]}
            ]}
        }});
        let info = read_vrm(Some(&v0), &[]).unwrap();
        assert_eq!((info.version.as_str(), info.head_node), ("0.x", Some(5)));
        assert_eq!(info.expressions[0].preset, Some(VrmPreset::Happy));
        assert_eq!(info.expressions[1].preset, Some(VrmPreset::Aa));
        assert_eq!(info.expressions[1].binds[0].weight, 0.5);
    }
}
