//! The project's puppets through the GPU renderer on lavapipe: neutral and jawOpen +
//! eyeBlinkLeft, against golden PNGs, with morph targets blended on the GPU.
//!
//! Tolerance: `Tolerance::default()` (every channel within 3/255 for 99.5 % of the pixels).
//! Regenerate with `LIKENESS_UPDATE_GOLDENS=1 cargo test -p likeness-tests --test puppet_render`.

use std::path::PathBuf;

use face::names::{NUM_ARKIT, arkit_index};
use likeness::puppet_view::{PuppetView, render_puppet};
use renderer::OffscreenRenderer;
use renderer::golden::{Tolerance, assert_matches_golden};
use retarget::{MappingData, Puppet, Retargeter};

const SIZE: (u32, u32) = (256, 256);

fn puppet_path(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../assets/puppets")
        .join(format!("{name}.glb"))
}

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("goldens")
        .join(format!("{name}.png"))
}

/// Pixels whose colour changes by more than 10/255 in some channel inside `rect`.
fn changed_in(a: &image::RgbaImage, b: &image::RgbaImage, rect: (u32, u32, u32, u32)) -> usize {
    let (x0, y0, x1, y1) = rect;
    let mut n = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            let (p, q) = (a.get_pixel(x, y), b.get_pixel(x, y));
            if p.0.iter().zip(q.0.iter()).any(|(s, t)| s.abs_diff(*t) > 10) {
                n += 1;
            }
        }
    }
    n
}

#[test]
fn puppets_at_neutral_and_jaw_open_with_left_blink() {
    for name in ["pip", "bolt"] {
        let puppet = Puppet::load(&puppet_path(name)).unwrap_or_else(|e| panic!("{e}"));
        let retargeter = Retargeter::new(&puppet, &MappingData::default());
        let view = PuppetView::new(&puppet).unwrap();
        let mut renderer = OffscreenRenderer::new(&view.mesh, &view.textures)
            .unwrap_or_else(|e| panic!("no adapter: {e}"));
        let neutral_pose = retargeter.pose(&[0.0; NUM_ARKIT], None);
        let mut arkit = [0.0; NUM_ARKIT];
        arkit[arkit_index("jawOpen").unwrap()] = 1.0;
        arkit[arkit_index("eyeBlinkLeft").unwrap()] = 1.0;
        let expressive_pose = retargeter.pose(&arkit, None);
        let neutral = render_puppet(&mut renderer, &view, &neutral_pose, 0.0, SIZE).unwrap();
        let expressive = render_puppet(&mut renderer, &view, &expressive_pose, 0.0, SIZE).unwrap();
        assert_matches_golden(
            &golden(&format!("puppet_{name}_neutral")),
            &neutral,
            Tolerance::default(),
        );
        assert_matches_golden(
            &golden(&format!("puppet_{name}_jaw_open_blink_left")),
            &expressive,
            Tolerance::default(),
        );

        // Independent of the goldens: the mouth (lower middle) and the puppet's left eye (the
        // viewer's right, upper half) change; its right eye (viewer's left) does not.
        let (w, h) = SIZE;
        let mouth = changed_in(
            &neutral,
            &expressive,
            (w * 3 / 8, h * 9 / 16, w * 5 / 8, h * 7 / 8),
        );
        let left_eye = changed_in(
            &neutral,
            &expressive,
            (w / 2 + w / 16, h / 4, w * 7 / 8, h / 2),
        );
        let right_eye = changed_in(&neutral, &expressive, (w / 8, h / 4, w / 2 - w / 16, h / 2));
        assert!(
            mouth > 100,
            "{name}: the open jaw changed only {mouth} mouth pixels"
        );
        assert!(
            left_eye > 40,
            "{name}: the left blink changed only {left_eye} pixels"
        );
        assert!(
            right_eye < left_eye / 4,
            "{name}: the right eye changed too ({right_eye} vs {left_eye})"
        );
    }
}

/// The personalized rig (the template person) loads in the renderer: textured base colour
/// from the GLB's images, and its jawOpen target opens the mouth on the GPU.
#[test]
fn personalized_rig_renders_with_its_textures_and_targets() {
    let template = face::Template::load_default(None)
        .unwrap_or_else(|e| panic!("this test needs the template: {e}"));
    let model = face::FaceModel::new(template);
    let person = model.template_blendshapes();
    let mean = face::albedo::MeanAlbedo::generate(&model.template);
    let corrections = face::PersonalCorrections::zeros();
    let rig =
        retarget::rig::PersonalizedRig::new(&model, &person, &corrections, &mean, mean.face())
            .unwrap();
    let dir = std::env::temp_dir().join(format!("likeness-rig-render-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("rig.glb");
    retarget::rig::write_rig_glb(&rig, &path).unwrap();
    let puppet = Puppet::load(&path).unwrap();
    let retargeter = Retargeter::new(&puppet, &MappingData::default());
    let view = PuppetView::new(&puppet).unwrap();
    assert_eq!(
        view.textures.width, 512,
        "the rig's 512 px albedo tiles are uploaded"
    );
    let mut renderer = OffscreenRenderer::new(&view.mesh, &view.textures)
        .unwrap_or_else(|e| panic!("no adapter: {e}"));
    let neutral = render_puppet(
        &mut renderer,
        &view,
        &retargeter.pose(&[0.0; NUM_ARKIT], None),
        0.0,
        SIZE,
    )
    .unwrap();
    let mut arkit = [0.0; NUM_ARKIT];
    arkit[arkit_index("jawOpen").unwrap()] = 1.0;
    let open = render_puppet(
        &mut renderer,
        &view,
        &retargeter.pose(&arkit, None),
        0.0,
        SIZE,
    )
    .unwrap();
    // Skin-coloured pixels (R > G > B, not the grey background) cover a good part of the view.
    let skin = neutral
        .pixels()
        .filter(|p| p[0] > 90 && p[0] > p[1] && p[1] > p[2])
        .count();
    assert!(
        skin > (SIZE.0 * SIZE.1 / 10) as usize,
        "only {skin} skin pixels"
    );
    let (w, h) = SIZE;
    let mouth = changed_in(&neutral, &open, (w / 4, h / 2, w * 3 / 4, h));
    assert!(
        mouth > 200,
        "jawOpen changed only {mouth} pixels of the lower face"
    );
}

/// The project's puppets have single-sided materials (glTF's default), so the studio culls
/// their back faces: the culled pictures must be the pictures, posed and turned.
#[test]
fn culling_the_back_faces_of_single_sided_puppets_changes_no_picture() {
    for name in ["pip", "bolt"] {
        let puppet = Puppet::load(&puppet_path(name)).unwrap_or_else(|e| panic!("{e}"));
        assert!(puppet.materials.iter().all(|m| !m.double_sided));
        let retargeter = Retargeter::new(&puppet, &MappingData::default());
        let view = PuppetView::new(&puppet).unwrap();
        assert!(view.cull_back_faces, "{name}: single-sided materials");
        let renderer_with = |cull_back_faces| {
            OffscreenRenderer::with_options(
                &view.mesh,
                &view.textures,
                renderer::OffscreenOptions {
                    cull_back_faces,
                    ..Default::default()
                },
            )
            .unwrap_or_else(|e| panic!("no adapter: {e}"))
        };
        let (mut all, mut culled) = (renderer_with(false), renderer_with(true));
        let mut arkit = [0.0; NUM_ARKIT];
        arkit[arkit_index("jawOpen").unwrap()] = 0.8;
        arkit[arkit_index("mouthSmileRight").unwrap()] = 0.6;
        let pose = retargeter.pose(&arkit, None);
        for yaw in [0.0, 35.0, -70.0] {
            let a = render_puppet(&mut all, &view, &pose, yaw, SIZE).unwrap();
            let b = render_puppet(&mut culled, &view, &pose, yaw, SIZE).unwrap();
            let cmp = renderer::golden::compare(&a, &b, Tolerance::default()).unwrap();
            assert!(
                cmp.passes(Tolerance::default()),
                "{name} at yaw {yaw}: {} pixels differ",
                cmp.pixels_outside
            );
        }
    }
}
