//! Exports survive a round trip: the GLB animation's weights and head rotations read back
//! equal the retargeter's poses; the Live Link Face CSV reads back the tracked weights.

mod common;

use common::temp_dir;
use face::names::{NUM_ARKIT, arkit_index};
use retarget::export::{
    ANIMATION_NAME, animation_glb_bytes, live_link_csv, live_link_header, live_link_timecode,
    parse_live_link_csv, retarget_clip, write_animation_glb,
};
use retarget::generator::{glb_bytes, styles};
use retarget::{MappingData, Puppet, Retargeter, Tracks};

fn tracks() -> Tracks {
    let mut frames = Vec::new();
    for k in 0..12 {
        let mut arkit = [0.0f32; NUM_ARKIT];
        arkit[arkit_index("jawOpen").unwrap()] = k as f32 / 11.0;
        arkit[arkit_index("eyeBlinkLeft").unwrap()] = (k % 3) as f32 / 2.0;
        arkit[arkit_index("mouthSmileRight").unwrap()] = 0.3;
        frames.push(retarget::tracks::TrackedFrame {
            time_s: 0.5 + k as f32 / 24.0,
            arkit,
            rotation_deg: Some([k as f32 * 2.0, -5.0, 1.5]),
        });
    }
    Tracks {
        frames,
        ..Tracks::default()
    }
}

#[test]
fn animation_glb_round_trips_weights_and_head_rotation() {
    let dir = temp_dir("export-glb");
    for style in styles() {
        let path = dir.join(format!("{}.glb", style.name));
        std::fs::write(&path, glb_bytes(&style).unwrap()).unwrap();
        let puppet = Puppet::load(&path).unwrap();
        let r = Retargeter::new(&puppet, &MappingData::default());
        let clip = retarget_clip(&r, &tracks());
        let out = dir.join(format!("{}-anim.glb", style.name));
        write_animation_glb(&puppet, &r, &clip, &out).unwrap();
        // What the browser makes from the dropped file's bytes is the written file.
        let from_bytes = animation_glb_bytes(
            &std::fs::read(&path).unwrap(),
            None,
            &puppet,
            &r,
            &clip,
            &out,
        )
        .unwrap();
        assert!(from_bytes == std::fs::read(&out).unwrap(), "{}", style.name);

        // Independent reader: the gltf crate's own animation API.
        let (document, buffers, _) = gltf::import(&out).unwrap();
        let animation = document
            .animations()
            .find(|a| a.name() == Some(ANIMATION_NAME))
            .expect("animation");
        let mut saw_weights = false;
        let mut saw_rotation = false;
        for channel in animation.channels() {
            let reader = channel.reader(|b| Some(&buffers[b.index()]));
            let times: Vec<f32> = reader.read_inputs().unwrap().collect();
            assert_eq!(times.len(), clip.len());
            for (t, f) in times.iter().zip(&clip) {
                assert!((t - (f.time_s - clip[0].time_s)).abs() < 1e-6);
            }
            match reader.read_outputs().unwrap() {
                gltf::animation::util::ReadOutputs::MorphTargetWeights(w) => {
                    let w: Vec<f32> = w.into_f32().collect();
                    let mesh = channel.target().node().mesh().unwrap().index();
                    let n = puppet.meshes[mesh].target_names.len();
                    for (k, f) in clip.iter().enumerate() {
                        assert_eq!(
                            &w[k * n..(k + 1) * n],
                            &f.pose.morph_weights[mesh][..],
                            "{} frame {k}",
                            style.name
                        );
                    }
                    saw_weights = true;
                }
                gltf::animation::util::ReadOutputs::Rotations(q) => {
                    let q: Vec<[f32; 4]> = q.into_f32().collect();
                    for (k, f) in clip.iter().enumerate() {
                        assert_eq!(
                            q[k],
                            f.pose.head.unwrap().1.to_array(),
                            "{} frame {k}",
                            style.name
                        );
                    }
                    assert_eq!(channel.target().node().index(), r.head_node().unwrap());
                    saw_rotation = true;
                }
                _ => panic!("unexpected channel"),
            }
        }
        assert!(saw_weights && saw_rotation, "{}", style.name);
        // The exported file is itself a puppet with the same targets.
        let again = Puppet::load(&out).unwrap();
        assert_eq!(again.meshes[0].target_names, puppet.meshes[0].target_names);
    }
}

#[test]
fn live_link_csv_round_trips() {
    let names = vec!["jawOpen".to_string()];
    let puppet = Puppet::from_slice(
        &common::tiny_puppet(&names, common::Naming::Extras, None),
        std::path::Path::new("t.glb"),
        None,
    )
    .unwrap();
    let r = Retargeter::new(&puppet, &MappingData::default());
    let t = tracks();
    let csv = live_link_csv(&r, &t);
    let header = live_link_header();
    assert_eq!(
        header.split(',').count(),
        63,
        "Timecode, BlendShapeCount and 61 values"
    );
    assert!(
        header.starts_with("Timecode,BlendShapeCount,EyeBlinkLeft,")
            && header.ends_with("RightEyeYaw,RightEyePitch,RightEyeRoll")
    );
    assert!(csv.lines().nth(1).unwrap().split(',').nth(1) == Some("61"));
    let back = parse_live_link_csv(&csv).unwrap();
    assert_eq!(back.frames.len(), t.frames.len());
    for (a, b) in back.frames.iter().zip(&t.frames) {
        assert!(
            (a.time_s - b.time_s).abs() < 1e-3,
            "{} vs {}",
            a.time_s,
            b.time_s
        );
        for k in 0..NUM_ARKIT {
            assert!((a.arkit[k] - b.arkit[k]).abs() < 1e-5);
        }
        let (ra, rb) = (a.rotation_deg.unwrap(), b.rotation_deg.unwrap());
        for k in 0..3 {
            assert!((ra[k] - rb[k]).abs() < 1e-3);
        }
    }
    assert_eq!(live_link_timecode(3723.5), "01:02:03:30.000");
}
