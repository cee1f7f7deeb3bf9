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
