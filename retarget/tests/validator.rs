//! The Khronos glTF validator (npm `gltf-validator`, installed into tools/gltf-validator by
//! scripts/setup.sh) on everything the crate writes: the project's puppets, an animation
//! export and the personalized rig. Errors fail the test; warnings and infos are printed.

mod common;

use common::{temp_dir, validate};

#[test]
fn exported_files_pass_the_khronos_validator() {
    let dir = temp_dir("validator");
    for style in retarget::generator::styles() {
        let path = dir.join(format!("{}.glb", style.name));
        std::fs::write(&path, retarget::generator::glb_bytes(&style).unwrap()).unwrap();
        validate(&path);
        // An animation export of it.
        let puppet = retarget::Puppet::load(&path).unwrap();
        let r = retarget::Retargeter::new(&puppet, &retarget::MappingData::default());
        let mut frames = Vec::new();
        for k in 0..5 {
            let mut arkit = [0.0f32; face::NUM_ARKIT];
            arkit[k * 7] = 0.2 * k as f32;
            frames.push(retarget::tracks::TrackedFrame {
                time_s: k as f32 / 30.0,
                arkit,
                rotation_deg: Some([k as f32, 0.0, 0.0]),
            });
        }
        let tracks = retarget::Tracks {
            frames,
            ..Default::default()
        };
        let clip = retarget::export::retarget_clip(&r, &tracks);
        let anim = dir.join(format!("{}-anim.glb", style.name));
        retarget::export::write_animation_glb(&puppet, &r, &clip, &anim).unwrap();
        validate(&anim);
    }
    // The personalized rig (template person, no corrections).
    let template = face::Template::load_default(None)
        .unwrap_or_else(|e| panic!("this test needs the template: {e}"));
    let model = face::FaceModel::new(template);
    let person = model.template_blendshapes();
    let mean = face::albedo::MeanAlbedo::generate(&model.template);
    let c = face::PersonalCorrections::zeros();
    let rig = retarget::rig::PersonalizedRig::new(&model, &person, &c, &mean, mean.face()).unwrap();
    let path = dir.join("rig.glb");
    retarget::rig::write_rig_glb(&rig, &path).unwrap();
    validate(&path);
}
