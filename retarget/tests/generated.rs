//! The project's puppets: regenerated deterministically, equal to the committed files, every
//! ARKit channel mapped, each target moving its feature.

use face::names::NUM_ARKIT;
use retarget::generator::{glb_bytes, styles};
use retarget::{MappingData, Puppet, Retargeter};
use std::path::Path;

fn assets() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/puppets")
}

#[test]
fn regeneration_is_deterministic_and_matches_the_committed_files() {
    for style in styles() {
        let a = glb_bytes(&style).unwrap();
        let b = glb_bytes(&style).unwrap();
        assert_eq!(a, b, "{}: two generations differ", style.name);
        let committed = assets().join(format!("{}.glb", style.name));
        let on_disk = std::fs::read(&committed).unwrap_or_else(|e| {
            panic!(
                "{}: {e}; run `likeness generate-puppets`",
                committed.display()
            )
        });
        assert!(
            a == on_disk,
            "{} differs from a fresh generation; run `likeness generate-puppets` and commit",
            committed.display()
        );
    }
}

#[test]
fn generated_puppets_map_all_52_and_every_target_moves_something() {
    for style in styles() {
        let puppet =
            Puppet::from_slice(&glb_bytes(&style).unwrap(), Path::new("gen.glb"), None).unwrap();
        let r = Retargeter::new(&puppet, &MappingData::default());
        assert_eq!(
            r.report.mapped.len(),
            NUM_ARKIT,
            "{}: {}",
            style.name,
            r.report
        );
        assert!(r.head_node().is_some(), "{}", style.name);
        for t in 0..NUM_ARKIT {
            let largest = puppet.meshes[0]
                .primitives
                .iter()
                .flat_map(|p| p.targets[t].positions.iter())
                .map(|d| glam::Vec3::from(*d).length())
                .fold(0.0f32, f32::max);
            assert!(
                largest > 1e-3,
                "{} target {} moves at most {largest} m",
                style.name,
                puppet.meshes[0].target_names[t]
            );
        }
    }
}
