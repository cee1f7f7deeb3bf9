//! The personalized rig: its morph targets are the person's corrected blendshapes under
//! ARKit names, it follows the glTF structure rules (accessor bounds recomputed here), and it
//! loads back as a puppet that maps all 52 channels.

mod common;

use common::temp_dir;
use face::albedo::MeanAlbedo;
use face::names::{ARKIT_NAMES, NUM_ARKIT, arkit_sources};
use face::uv::UvMap;
use face::{FaceModel, PersonalCorrections, Template};
use retarget::rig::{PersonalizedRig, decode_dynamic_albedo, rig_glb_bytes, write_rig_glb};
use retarget::{MappingData, Puppet, Retargeter};

/// Smooth, person-like corrections: a few millimetres of shape, a tint, folds.
fn corrections() -> PersonalCorrections {
    let mut c = PersonalCorrections::zeros();
    let field = |phase: f32, amp: f32| {
        UvMap::from_fn(128, 128, 3, |uv| {
            (0..3)
                .map(|ch| amp * ((uv.x * 6.4 + phase).sin() * (uv.y * 5.1 + ch as f32).cos()))
                .collect()
        })
    };
    c.identity_shape = field(0.3, 0.2);
    for i in 0..face::NUM_BLENDSHAPES {
        c.expression_shapes[i] = field(i as f32, 0.15);
        c.dynamic_albedo[i] = field(2.0 * i as f32, 0.05);
    }
    c.static_albedo = field(1.0, 0.03);
    c
}

#[test]
fn rig_targets_are_the_personalized_blendshapes_and_the_file_is_well_formed() {
    let template = Template::load_default(None)
        .unwrap_or_else(|e| panic!("this test needs the template: {e}"));
    let model = FaceModel::new(template);
    let c = corrections();
    let person = model.personalize(&c).unwrap();
    let mean = MeanAlbedo::generate(&model.template);
    let rig = PersonalizedRig::new(&model, &person, &c, &mean, mean.face()).unwrap();
    let dir = temp_dir("rig");
    let out = dir.join("person.glb");
    write_rig_glb(&rig, &out).unwrap();
    // The browser's download is the written file.
    assert!(rig_glb_bytes(&rig, &out).unwrap() == std::fs::read(&out).unwrap());

    // Structure, as the glTF crate validates it, and every accessor's min/max recomputed.
    let (document, buffers, images) = gltf::import(&out).unwrap();
    for accessor in document.accessors() {
        let json = accessor.min().zip(accessor.max());
        let Some((min, max)) = json else { continue };
        let view = accessor.view().unwrap();
        let data = &buffers[view.buffer().index()][view.offset() + accessor.offset()..];
        let width = accessor.dimensions().multiplicity();
        let floats: Vec<f32> = data[..accessor.count() * width * 4]
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        for k in 0..width {
            let lo = floats
                .iter()
                .skip(k)
                .step_by(width)
                .copied()
                .fold(f32::INFINITY, f32::min);
            let hi = floats
                .iter()
                .skip(k)
                .step_by(width)
                .copied()
                .fold(f32::NEG_INFINITY, f32::max);
            assert_eq!(
                min[k].as_f64().unwrap() as f32,
                lo,
                "accessor {} min",
                accessor.index()
            );
            assert_eq!(
                max[k].as_f64().unwrap() as f32,
                hi,
                "accessor {} max",
                accessor.index()
            );
        }
    }
    assert!(document.meshes().all(|m| m.primitives().all(|p| {
        p.get(&gltf::Semantic::Positions)
            .is_some_and(|a| a.min().is_some())
    })));
    assert_eq!(
        images.len(),
        retarget::rig::RIG_LAYERS.len() + NUM_ARKIT - 1,
        "a static albedo per tile, a dynamic one per ARKit shape but tongueOut"
    );

    // Loads as a puppet; every target is the person's delta at its vertex, in metres.
    let puppet = Puppet::load(&out).unwrap();
    let mesh = &puppet.meshes[0];
    assert_eq!(mesh.target_names, ARKIT_NAMES.map(str::to_owned).to_vec());
    let r = Retargeter::new(&puppet, &MappingData::default());
    assert_eq!(r.report.mapped.len(), NUM_ARKIT);
    let face_prim = &mesh.primitives[0];
    let v_count = model.template.vertex_count();
    // Find each corner's template vertex by its rest position (unique on the face tile).
    let mut checked = 0;
    for (corner, p) in face_prim.positions.iter().enumerate().step_by(97) {
        let p = glam::Vec3::from(*p) * 100.0;
        let v = person
            .base
            .iter()
            .position(|b| (*b - p).length() < 1e-4)
            .expect("corner is a template vertex");
        for a in [0, 10, 17, 24, 40] {
            let expect: glam::Vec3 = arkit_sources(a)
                .iter()
                .map(|&i| person.deltas[i * v_count + v])
                .sum::<glam::Vec3>()
                * 0.01;
            let got = glam::Vec3::from(face_prim.targets[a].positions[corner]);
            assert!(
                (got - expect).length() < 1e-6,
                "{} at vertex {v}: {got} vs {expect}",
                ARKIT_NAMES[a]
            );
        }
        checked += 1;
    }
    assert!(checked > 20);

    // Dynamic albedo images decode back to A_i dR_i within the 8-bit step.
    let root: serde_json::Value = serde_json::from_slice(
        &gltf::Glb::from_slice(&std::fs::read(&out).unwrap())
            .unwrap()
            .json,
    )
    .unwrap();
    let jaw = face::names::arkit_index("jawOpen").unwrap();
    let image_index = root["extras"]["likeness"]["dynamic_albedo"]["images"]["jawOpen"]
        .as_u64()
        .unwrap() as usize;
    let img = &images[image_index];
    let i = arkit_sources(jaw)[0];
    let step = 2.0 * retarget::rig::DYNAMIC_ALBEDO_RANGE / 255.0;
    for (x, y) in [(64, 100), (40, 90), (90, 110)] {
        let expect = rig.dynamic_albedo[i].texel(x, y)[0];
        let got = decode_dynamic_albedo(img.pixels[(y * 128 + x) * 3]);
        assert!(
            (got - expect.clamp(-0.25, 0.25)).abs() <= step,
            "texel ({x}, {y}): {got} vs {expect}"
        );
    }
}
