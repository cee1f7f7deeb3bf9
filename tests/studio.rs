//! The studio driven like a user would, through AccessKit queries, rendered with wgpu on
//! lavapipe.

use std::sync::{Arc, OnceLock};

use egui::accesskit::Role;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable;
use face::names::ict_index;
use likeness::scene::{Scene, StudioView};
use likeness::studio::StudioApp;

fn scene() -> Arc<Scene> {
    static SCENE: OnceLock<Arc<Scene>> = OnceLock::new();
    SCENE
        .get_or_init(|| {
            Arc::new(
                Scene::load(None).unwrap_or_else(|e| panic!("the studio needs the template: {e}")),
            )
        })
        .clone()
}

fn harness() -> Harness<'static, StudioApp> {
    let scene = scene();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(1100.0, 700.0))
        .wgpu()
        .build_eframe(move |cc| {
            let mut app = StudioApp::new(cc, scene);
            // Tests drive the weights themselves; the scripted loop would overwrite them.
            app.state.playing_demo = false;
            // Timings differ run to run; keep them out of the snapshots.
            app.state.show_timings = false;
            app
        });
    harness.run_steps(2);
    harness
}

#[test]
fn the_slider_list_sets_blendshape_weights() {
    let mut harness = harness();
    assert!(
        harness.state().state.error.is_none(),
        "{:?}",
        harness.state().state.error
    );
    let jaw = ict_index("jawOpen").unwrap();
    harness
        .get_by_role_and_label(Role::Slider, "jawOpen")
        .set_value_accesskit(0.8);
    harness.run_steps(2);
    assert!((harness.state().state.weights[jaw] - 0.8).abs() < 1e-6);
    // Every other weight stays at zero.
    let others: f32 = harness
        .state()
        .state
        .weights
        .iter()
        .enumerate()
        .filter(|(i, _)| *i != jaw)
        .map(|(_, w)| w)
        .sum();
    assert_eq!(others, 0.0);
}

#[test]
fn the_search_box_filters_the_list() {
    let mut harness = harness();
    assert!(
        harness
            .query_by_role_and_label(Role::Slider, "mouthSmile_L")
            .is_some()
    );
    harness.get_by_role(Role::TextInput).focus();
    harness.run_steps(1);
    harness.get_by_role(Role::TextInput).type_text("blink");
    harness.run_steps(3);
    assert_eq!(harness.state().state.filter, "blink");
    assert!(
        harness
            .query_by_role_and_label(Role::Slider, "eyeBlink_L")
            .is_some()
    );
    assert!(
        harness
            .query_by_role_and_label(Role::Slider, "eyeBlink_R")
            .is_some()
    );
    assert!(
        harness
            .query_by_role_and_label(Role::Slider, "mouthSmile_L")
            .is_none()
    );
    assert!(
        harness
            .query_by_role_and_label(Role::Slider, "jawOpen")
            .is_none()
    );
}

#[test]
fn the_view_switch_changes_the_view_and_the_picture() {
    let mut harness = harness();
    let shaded = harness.render().expect("render");
    harness.get_by_label("Albedo").click();
    harness.run_steps(3);
    assert_eq!(harness.state().state.view, StudioView::Albedo);
    let albedo = harness.render().expect("render");
    let changed = shaded
        .pixels()
        .zip(albedo.pixels())
        .filter(|(a, b)| a.0.iter().zip(b.0.iter()).any(|(x, y)| x.abs_diff(*y) > 8))
        .count();
    assert!(
        changed > 5_000,
        "switching to the albedo view must change the 3D view ({changed} pixels changed)"
    );

    harness.get_by_label("Mask").click();
    harness.run_steps(3);
    assert_eq!(
        harness.state().state.view,
        StudioView::Mask(ict_index("jawOpen").unwrap())
    );
}

#[test]
fn studio_snapshot_with_jaw_open() {
    let mut harness = harness();
    harness
        .get_by_role_and_label(Role::Slider, "jawOpen")
        .set_value_accesskit(0.8);
    harness.run_steps(3);
    harness.snapshot("studio_jaw_open");
}

/// A small built-in demo session (12 frames), made once for the tests that need one.
fn demo_session() -> Arc<likeness::studio_session::StudioSession> {
    static SESSION: OnceLock<Arc<likeness::studio_session::StudioSession>> = OnceLock::new();
    SESSION
        .get_or_init(|| {
            let scene = scene();
            let face = Arc::new(face::FaceModel::new(scene.model.template.clone()));
            let config = likeness::demo::DemoConfig {
                frames: 12,
                personalize_frames: 2,
                ..likeness::demo::DemoConfig::default()
            };
            let demo = likeness::demo::build_demo(&scene, face, config, |_| {})
                .unwrap_or_else(|e| panic!("demo: {e:#}"));
            Arc::new(likeness::studio_session::StudioSession::from_demo(
                &scene.model,
                demo,
            ))
        })
        .clone()
}

fn session_harness() -> Harness<'static, StudioApp> {
    let scene = scene();
    let session = demo_session();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(1100.0, 700.0))
        .wgpu()
        .build_eframe(move |cc| {
            let mut app = StudioApp::new(cc, scene).with_session(session);
            app.state.show_timings = false;
            app.state.playback.playing = false;
            app
        });
    harness.run_steps(2);
    harness
}

#[test]
fn the_timeline_steps_plays_and_drives_the_face_with_the_tracked_weights() {
    let mut harness = session_harness();
    let session = demo_session();
    assert_eq!(
        harness.state().state.panel,
        likeness::studio::Panel::Input,
        "a session opens on its input"
    );
    harness.get_by_label("Next").click();
    harness.run_steps(2);
    assert_eq!(harness.state().state.playback.frame, 1);
    harness.get_by_label("Previous").click();
    harness.get_by_label("Previous").click();
    harness.run_steps(2);
    assert_eq!(
        harness.state().state.playback.frame,
        11,
        "wraps to the last frame"
    );
    // The face shows the tracked weights of the current frame.
    assert_eq!(harness.state().state.weights, session.weights(11).0);
    // Play: frames advance at the footage's rate.
    harness.get_by_label("Play").click();
    harness.run_steps(1);
    assert!(harness.state().state.playback.playing);
    for _ in 0..10 {
        harness.step();
    }
    assert_ne!(
        harness.state().state.playback.frame,
        11,
        "playback moved on"
    );
    // Keyboard: space pauses.
    harness.key_press(egui::Key::Space);
    harness.run_steps(1);
    assert!(!harness.state().state.playback.playing);
    // Switching to the face panel and back.
    harness.get_by_label("Face").click();
    harness.run_steps(2);
    assert_eq!(harness.state().state.panel, likeness::studio::Panel::Face);
    harness.get_by_label("Input").click();
    harness.run_steps(2);
    assert_eq!(harness.state().state.panel, likeness::studio::Panel::Input);
    assert!(harness.state().state.error.is_none());
}

#[test]
fn the_input_panel_draws_the_frame_with_its_overlay() {
    let mut harness = session_harness();
    harness.run_steps(2);
    // Overlay off, then on: the picture must change where the landmarks are.
    let with_overlay = harness.render().expect("render");
    // The golden: the demo's first frame with detected (amber) and model (cyan) landmarks,
    // the face box with its confidence and the crop (grey).
    harness.snapshot("studio_input_overlay");
    harness.get_by_label("Detected landmarks").click();
    harness.get_by_label("Model landmarks").click();
    harness.get_by_label("Face box and crop").click();
    harness.run_steps(2);
    let without = harness.render().expect("render");
    let changed = with_overlay
        .pixels()
        .zip(without.pixels())
        .filter(|(a, b)| a != b)
        .count();
    assert!(changed > 500, "the overlay changed only {changed} pixels");
}

#[test]
fn the_maps_panel_shows_each_learned_map() {
    let mut harness = session_harness();
    harness.get_by_label("Maps").click();
    harness.run_steps(2);
    assert_eq!(harness.state().state.panel, likeness::studio::Panel::Maps);
    let mut pictures = Vec::new();
    for label in [
        "Static albedo",
        "Dynamic albedo",
        "Frame albedo",
        "Attention mask",
        "Shape correction",
    ] {
        harness.get_by_label(label).click();
        harness.run_steps(2);
        assert!(
            harness.state().state.error.is_none(),
            "{label}: {:?}",
            harness.state().state.error
        );
        pictures.push(harness.render().expect("render"));
    }
    // The golden: the shape correction map of the selected blendshape with its colour bar.
    harness.snapshot("studio_maps_shape_correction");
    // Every map looks different from the one before it.
    for (k, pair) in pictures.windows(2).enumerate() {
        let changed = pair[0]
            .pixels()
            .zip(pair[1].pixels())
            .filter(|(a, b)| a != b)
            .count();
        assert!(changed > 1000, "map {k} -> {}: {changed} pixels", k + 1);
    }
}

#[test]
fn the_lighting_and_motion_panel_plots_curves_and_switches_names() {
    let mut harness = session_harness();
    harness.get_by_label("Lighting and motion").click();
    harness.run_steps(2);
    assert_eq!(harness.state().state.panel, likeness::studio::Panel::Motion);
    harness.get_by_label("ARKit").click();
    harness.run_steps(2);
    let panel = &harness.state().motion_panel;
    assert!(panel.arkit);
    assert_eq!(
        panel.channels.len(),
        4,
        "the same four curves under ARKit names"
    );
    assert!(harness.state().state.error.is_none());
    // The golden: the lit sphere of frame 0 and four weight curves with the playhead.
    harness.snapshot("studio_lighting_and_motion");
}

#[test]
fn the_blendshapes_panel_selects_searches_and_shows_the_correction() {
    use likeness::blendshape_panel::row_label;
    let mut harness = session_harness();
    let session = demo_session();
    harness.get_by_label("Blendshapes").click();
    harness.run_steps(2);
    assert_eq!(
        harness.state().state.panel,
        likeness::studio::Panel::Blendshapes
    );
    let before = harness.render().expect("render");
    // Select the blendshape with the largest personal correction, listed first.
    let largest = session.by_correction_size()[0];
    assert_ne!(
        harness.state().state.selected,
        largest,
        "pick a different one"
    );
    harness.get_by_label(&row_label(&session, largest)).click();
    harness.run_steps(3);
    assert_eq!(harness.state().state.selected, largest);
    assert!(
        harness.state().state.error.is_none(),
        "{:?}",
        harness.state().state.error
    );
    let selected = harness.render().expect("render");
    let changed = before
        .pixels()
        .zip(selected.pixels())
        .filter(|(a, b)| a.0.iter().zip(b.0.iter()).any(|(x, y)| x.abs_diff(*y) > 8))
        .count();
    assert!(
        changed > 2_000,
        "selecting another blendshape must change the views ({changed} pixels)"
    );
    // The golden: template beside personalized at weight 1 and the correction heatmap (mm)
    // with its colour bar.
    harness.snapshot("studio_blendshapes");

    // The mask toggle swaps the heatmap for A_i on the mesh.
    harness.get_by_label("Show the attention mask").click();
    harness.run_steps(3);
    assert!(harness.state().blendshape_panel.show_mask);
    let mask = harness.render().expect("render");
    let changed = selected
        .pixels()
        .zip(mask.pixels())
        .filter(|(a, b)| a != b)
        .count();
    assert!(changed > 2_000, "the mask view changed {changed} pixels");

    // Searching narrows the list to matching names.
    harness.get_by_role(Role::TextInput).focus();
    harness.run_steps(1);
    harness.get_by_role(Role::TextInput).type_text("blink");
    harness.run_steps(3);
    let blink_l = ict_index("eyeBlink_L").unwrap();
    let jaw = ict_index("jawOpen").unwrap();
    assert!(
        harness
            .query_by_label(&row_label(&session, blink_l))
            .is_some()
    );
    assert!(harness.query_by_label(&row_label(&session, jaw)).is_none());
}
