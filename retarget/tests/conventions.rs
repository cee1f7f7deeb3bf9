//! Every naming convention maps all 52 channels; a puppet without matching names gets a
//! report that says so; VRM expressions are driven by the documented formulas.

mod common;

use common::{Naming, tiny_puppet};
use face::names::{ARKIT_NAMES, NUM_ARKIT, arkit_index};
use retarget::mapping::{ChannelMapping, MappingData};
use retarget::names::live_link_name;
use retarget::{Puppet, Retargeter};
use serde_json::json;
use std::path::Path;

fn load(bytes: &[u8]) -> Puppet {
    Puppet::from_slice(bytes, Path::new("test.glb"), None).expect("puppet loads")
}

#[test]
fn every_convention_maps_all_52() {
    let conventions: Vec<(&str, Vec<String>, Naming)> = vec![
        (
            "ARKit camelCase in extras",
            ARKIT_NAMES.iter().map(|s| s.to_string()).collect(),
            Naming::Extras,
        ),
        (
            "Live Link PascalCase as accessor names",
            (0..NUM_ARKIT).map(live_link_name).collect(),
            Naming::Accessors,
        ),
        (
            "ICT _L/_R",
            ARKIT_NAMES
                .iter()
                .map(|s| face::names::arkit_to_ict_name(s))
                .collect(),
            Naming::Extras,
        ),
        (
            "blendShape1. prefix",
            ARKIT_NAMES
                .iter()
                .map(|s| format!("blendShape1.{s}"))
                .collect(),
            Naming::Extras,
        ),
        (
            "upper case with a namespace",
            ARKIT_NAMES
                .iter()
                .map(|s| format!("Face:{}", s.to_uppercase()))
                .collect(),
            Naming::Accessors,
        ),
    ];
    for (what, names, naming) in conventions {
        let puppet = load(&tiny_puppet(&names, naming, None));
        let r = Retargeter::new(&puppet, &MappingData::default());
        assert_eq!(r.report.mapped.len(), NUM_ARKIT, "{what}: {}", r.report);
        assert!(
            r.report.unmapped_targets.is_empty() && r.report.unused_sources.is_empty(),
            "{what}: {}",
            r.report
        );
        // Channel a drives exactly target a with weight = the tracked value.
        let mut arkit = [0.0; NUM_ARKIT];
        for (a, w) in arkit.iter_mut().enumerate() {
            *w = (a as f32 + 1.0) / 60.0;
        }
        let pose = r.pose(&arkit, None);
        for a in 0..NUM_ARKIT {
            assert!(
                (pose.morph_weights[0][a] - arkit[a]).abs() < 1e-6,
                "{what}: {}",
                names[a]
            );
        }
    }
}

#[test]
fn no_matching_names_is_reported_not_silent() {
    let names: Vec<String> = ["Basis", "smile", "frown", "Key 3"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let puppet = load(&tiny_puppet(&names, Naming::Extras, None));
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert!(!r.report.drives_anything());
    assert_eq!(r.report.unmapped_targets.len(), 4);
    assert_eq!(r.report.unused_sources.len(), NUM_ARKIT);
    let text = r.report.to_string();
    assert!(
        text.contains("mapped 0 channel(s)") && text.contains("face/smile"),
        "{text}"
    );
    // A mapping file fixes it: "smile" driven by mouthSmileLeft with gain 0.5.
    let mut mapping = MappingData::default();
    mapping.channels.push(ChannelMapping {
        targets: vec!["smile".into()],
        gain: 0.5,
        ..ChannelMapping::identity("mouthSmileLeft")
    });
    mapping.channels.push(ChannelMapping {
        targets: vec!["grin".into()],
        ..ChannelMapping::identity("mouthSmileRight")
    });
    let r = Retargeter::new(&puppet, &mapping);
    assert_eq!(
        r.report.unresolved,
        vec!["grin (for mouthSmileRight)".to_string()]
    );
    let mut arkit = [0.0; NUM_ARKIT];
    arkit[arkit_index("mouthSmileLeft").unwrap()] = 0.8;
    assert!((r.pose(&arkit, None).morph_weights[0][1] - 0.4).abs() < 1e-6);
}

#[test]
fn ambiguous_names_are_reported_and_both_driven() {
    let names: Vec<String> = ["jawOpen", "JawOpen", "eyeBlinkLeft"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let puppet = load(&tiny_puppet(&names, Naming::Extras, None));
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert_eq!(r.report.ambiguous.len(), 1, "{}", r.report);
    let mut arkit = [0.0; NUM_ARKIT];
    arkit[arkit_index("jawOpen").unwrap()] = 0.7;
    let pose = r.pose(&arkit, None);
    assert_eq!(&pose.morph_weights[0][..2], &[0.7, 0.7]);
}

#[test]
fn mapping_response_calibration_and_curve_apply() {
    let names: Vec<String> = ARKIT_NAMES.iter().map(|s| s.to_string()).collect();
    let puppet = load(&tiny_puppet(&names, Naming::Extras, None));
    let mut mapping = MappingData::default();
    mapping.channels.push(ChannelMapping {
        curve: vec![[0.0, 0.0], [0.5, 0.8], [1.0, 1.0]],
        ..ChannelMapping::identity("JawOpen")
    });
    mapping.channels.push(ChannelMapping {
        invert: true,
        offset: -0.1,
        ..ChannelMapping::identity("eyeBlink_L")
    });
    let mut rest = [0.0; NUM_ARKIT];
    let pucker = arkit_index("mouthPucker").unwrap();
    rest[pucker] = 0.2;
    mapping.calibrate_neutral(&rest);
    let r = Retargeter::new(&puppet, &mapping);
    let mut arkit = [0.0; NUM_ARKIT];
    let (jaw, blink) = (
        arkit_index("jawOpen").unwrap(),
        arkit_index("eyeBlinkLeft").unwrap(),
    );
    arkit[jaw] = 0.25;
    arkit[blink] = 0.3;
    arkit[pucker] = 0.6;
    let w = &r.pose(&arkit, None).morph_weights[0];
    assert!((w[jaw] - 0.4).abs() < 1e-6, "curve: {}", w[jaw]);
    assert!(
        (w[blink] - 0.6).abs() < 1e-6,
        "invert + offset: {}",
        w[blink]
    );
    assert!((w[pucker] - 0.5).abs() < 1e-6, "calibration: {}", w[pucker]);
}

fn vrm_puppet(version: &str) -> Puppet {
    let names: Vec<String> = [
        "Fcl_MTH_A",
        "Fcl_EYE_Close_L",
        "Fcl_EYE_Close_R",
        "Fcl_ALL_Joy",
        "Fcl_EYE_Close",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let ext = if version == "1.0" {
        json!({"VRMC_vrm": {
            "specVersion": "1.0",
            "humanoid": {"humanBones": {"head": {"node": 0}}},
            "expressions": {"preset": {
                "aa": {"morphTargetBinds": [{"node": 0, "index": 0, "weight": 1.0}]},
                "blinkLeft": {"morphTargetBinds": [{"node": 0, "index": 1, "weight": 1.0}]},
                "blinkRight": {"morphTargetBinds": [{"node": 0, "index": 2, "weight": 1.0}]},
                "blink": {"morphTargetBinds": [{"node": 0, "index": 4, "weight": 1.0}]},
                "happy": {"morphTargetBinds": [{"node": 0, "index": 3, "weight": 0.5}], "overrideBlink": "block"}
            }}
        }})
    } else {
        json!({"VRM": {
            "humanoid": {"humanBones": [{"bone": "head", "node": 0}]},
            "blendShapeMaster": {"blendShapeGroups": [
                {"name": "A", "presetName": "a", "binds": [{"mesh": 0, "index": 0, "weight": 100}]},
                {"name": "Blink_L", "presetName": "blink_l", "binds": [{"mesh": 0, "index": 1, "weight": 100}]},
                {"name": "Blink_R", "presetName": "blink_r", "binds": [{"mesh": 0, "index": 2, "weight": 100}]},
                {"name": "Blink", "presetName": "blink", "binds": [{"mesh": 0, "index": 4, "weight": 100}]},
                {"name": "Joy", "presetName": "joy", "binds": [{"mesh": 0, "index": 3, "weight": 50}]}
            ]}
        }})
    };
    load(&tiny_puppet(&names, Naming::Extras, Some(ext)))
}

#[test]
fn vrm_presets_follow_the_formulas_in_both_versions() {
    for version in ["1.0", "0.x"] {
        let puppet = vrm_puppet(version);
        assert_eq!(
            puppet.vrm.as_ref().map(|v| v.version.as_str()),
            Some(version)
        );
        let r = Retargeter::new(&puppet, &MappingData::default());
        assert_eq!(r.head_node(), Some(0), "{version}");
        let mut arkit = [0.0; NUM_ARKIT];
        arkit[arkit_index("jawOpen").unwrap()] = 0.6;
        arkit[arkit_index("eyeBlinkLeft").unwrap()] = 0.9;
        arkit[arkit_index("eyeBlinkRight").unwrap()] = 0.4;
        let w = r.pose(&arkit, None).morph_weights[0].clone();
        // aa = jawOpen; blink = min = 0.4; blinkLeft = 0.9 - 0.4; blinkRight = 0.
        let expect = [0.6, 0.5, 0.0, 0.0, 0.4];
        for (k, e) in expect.iter().enumerate() {
            assert!(
                (w[k] - e).abs() < 1e-6,
                "{version} target {k}: {} vs {e}",
                w[k]
            );
        }
        // happy = mean(mouthSmile) with bind weight 0.5; in 1.0 it blocks the blinks.
        arkit[arkit_index("mouthSmileLeft").unwrap()] = 1.0;
        arkit[arkit_index("mouthSmileRight").unwrap()] = 1.0;
        let w = r.pose(&arkit, None).morph_weights[0].clone();
        assert!((w[3] - 0.5).abs() < 1e-6, "{version}: happy {}", w[3]);
        let blocked = version == "1.0";
        assert_eq!(w[4] == 0.0, blocked, "{version}: blink {}", w[4]);
    }
}

#[test]
fn head_rotation_turns_the_head_node_in_world_axes() {
    let names: Vec<String> = vec!["jawOpen".into()];
    let puppet = load(&tiny_puppet(&names, Naming::Extras, None));
    let r = Retargeter::new(&puppet, &MappingData::default());
    let head = r.head_node().expect("node `Head` found");
    assert_eq!(puppet.nodes[head].name, "Head");
    let pose = r.pose(&[0.0; NUM_ARKIT], Some([30.0, 0.0, 0.0]));
    let (_, q) = pose.head.unwrap();
    // Yaw 30 degrees about +y turns the face's +z towards +x.
    let forward = q * glam::Vec3::Z;
    assert!(
        (forward.x - 0.5).abs() < 1e-5 && (forward.z - 0.75f32.sqrt()).abs() < 1e-5,
        "{forward}"
    );
}

#[test]
fn perfect_sync_clips_follow_their_arkit_channel() {
    // A VRM 1.0 avatar whose custom clips carry ARKit names and bind targets named otherwise.
    let names: Vec<String> = (0..3).map(|k| format!("Shape.{k:03}")).collect();
    let ext = json!({"VRMC_vrm": {"expressions": {"custom": {
        "jawOpen": {"morphTargetBinds": [{"node": 0, "index": 0, "weight": 1.0}]},
        "EyeBlinkLeft": {"morphTargetBinds": [{"node": 0, "index": 1, "weight": 1.0}]},
        "mouthSmile_R": {"morphTargetBinds": [{"node": 0, "index": 2, "weight": 0.5}]}
    }}}});
    let puppet = load(&tiny_puppet(&names, Naming::Extras, Some(ext)));
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert_eq!(r.report.mapped.len(), 3, "{}", r.report);
    let mut arkit = [0.0; NUM_ARKIT];
    arkit[arkit_index("jawOpen").unwrap()] = 0.3;
    arkit[arkit_index("eyeBlinkLeft").unwrap()] = 0.6;
    arkit[arkit_index("mouthSmileRight").unwrap()] = 0.8;
    let w = r.pose(&arkit, None).morph_weights[0].clone();
    for (k, e) in [0.3, 0.6, 0.4].iter().enumerate() {
        assert!((w[k] - e).abs() < 1e-6, "target {k}: {} vs {e}", w[k]);
    }
}
