//! The template face through the GPU renderer on lavapipe, against golden PNGs.
//!
//! Tolerance: every channel within 3/255 for at least 99.5 % of the pixels
//! (`Tolerance::default()`): it absorbs rounding and a few anti-aliased edge pixels, while
//! any visible change of shape, shading or colour fails. Regenerate with
//! `LIKENESS_UPDATE_GOLDENS=1 cargo test -p likeness-tests --test face_render`.

use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};

use face::BlendshapeWeights;
use likeness::headless::{offscreen, render_view};
use likeness::scene::{Orbit, Scene, StudioView, frame_params, parse_weights};
use renderer::OffscreenRenderer;
use renderer::golden::{Tolerance, assert_matches_golden};

const SIZE: (u32, u32) = (256, 256);

struct Fixture {
    scene: Scene,
    renderer: Mutex<OffscreenRenderer>,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let scene =
            Scene::load(None).unwrap_or_else(|e| panic!("these tests need the template: {e}"));
        let renderer = offscreen(&scene).unwrap_or_else(|e| panic!("no adapter: {e:#}"));
        Fixture {
            scene,
            renderer: Mutex::new(renderer),
        }
    })
}

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("goldens")
        .join(format!("{name}.png"))
}

/// Runs `f` with the shared renderer, its overlay image cleared (tests run in parallel).
fn with_renderer<R>(f: impl FnOnce(&Scene, &mut OffscreenRenderer) -> R) -> R {
    let fixture = fixture();
    let mut guard = fixture.renderer.lock().unwrap_or_else(|e| e.into_inner());
    let renderer: &mut OffscreenRenderer = &mut guard;
    renderer
        .face
        .set_overlay_image(&renderer.device, &renderer.queue, None, 1.0)
        .expect("clear overlay");
    f(&fixture.scene, renderer)
}

fn render(view: StudioView, weights: &str, orbit: Orbit) -> image::RgbaImage {
    let (weights, _) = parse_weights(weights).expect("weights");
    with_renderer(|scene, renderer| {
        render_view(scene, renderer, view, &weights, &orbit, SIZE).expect("render")
    })
}

fn changed_pixels(a: &image::RgbaImage, b: &image::RgbaImage) -> usize {
    pixels_off_by_more_than(10, a, b)
}

/// Pixels where some channel differs by more than `tolerance`.
fn pixels_off_by_more_than(tolerance: u8, a: &image::RgbaImage, b: &image::RgbaImage) -> usize {
    a.pixels()
        .zip(b.pixels())
        .filter(|(p, q)| {
            p.0.iter()
                .zip(q.0.iter())
                .any(|(x, y)| x.abs_diff(*y) > tolerance)
        })
        .count()
}

#[test]
fn neutral_front() {
    let image = render(StudioView::Shaded, "", Orbit::default());
    assert_matches_golden(&golden("neutral_front"), &image, Tolerance::default());
}

/// Renders `weights`, checks it against the golden `name`, and that at least `min_changed`
/// pixels differ from the neutral face.
fn assert_expression(weights: &str, name: &str, min_changed: usize) {
    let neutral = render(StudioView::Shaded, "", Orbit::default());
    let expression = render(StudioView::Shaded, weights, Orbit::default());
    assert_matches_golden(&golden(name), &expression, Tolerance::default());
    let changed = changed_pixels(&neutral, &expression);
    assert!(
        changed > min_changed,
        "{weights} changed only {changed} pixels"
    );
}

#[test]
fn jaw_open_and_smile_differs_from_neutral() {
    // The mouth region is a few thousand pixels at this size; the jaw and lips must move.
    assert_expression(
        "jawOpen=0.8,mouthSmileLeft=1,mouthSmileRight=1",
        "jaw_open_smile",
        800,
    );
}

#[test]
fn the_eyes_turn_with_the_gaze() {
    // Looking to the subject's left and down: both eyeballs turn (face::gaze), the lids
    // hardly move, so what changes is the irises.
    assert_expression(
        "eyeLookOutLeft=1,eyeLookInRight=1,eyeLookDownLeft=0.5,eyeLookDownRight=0.5",
        "gaze_left_down",
        150,
    );
}

#[test]
fn jaw_open_mask_heatmap() {
    let jaw = face::names::ict_index("jawOpen").expect("name");
    let image = render(StudioView::Mask(jaw), "", Orbit::default());
    assert_matches_golden(&golden("mask_jaw_open"), &image, Tolerance::default());
    // The heatmap is hot on the chin and cold on the forehead.
    let chin = image.get_pixel(128, 185).0;
    let forehead = image.get_pixel(128, 70).0;
    assert!(
        chin != forehead,
        "mask heatmap shows no difference between chin and forehead"
    );
}

#[test]
fn three_quarter_view() {
    let orbit = Orbit {
        yaw_deg: 35.0,
        pitch_deg: -8.0,
        ..Orbit::default()
    };
    let image = render(StudioView::Shaded, "", orbit);
    assert_matches_golden(&golden("three_quarter"), &image, Tolerance::default());
    let front = render(StudioView::Shaded, "", Orbit::default());
    assert!(changed_pixels(&front, &image) > 3000);
}

#[test]
fn overlay_on_an_image() {
    // A procedural background (no third-party pixels in the goldens).
    let background = image::RgbaImage::from_fn(SIZE.0, SIZE.1, |x, y| {
        let checker = ((x / 16) + (y / 16)) % 2 == 0;
        let v = if checker { 200 } else { 90 };
        image::Rgba([v, (x * 255 / SIZE.0) as u8, (y * 255 / SIZE.1) as u8, 255])
    });
    let f = fixture();
    let mut guard = f.renderer.lock().unwrap_or_else(|e| e.into_inner());
    let renderer: &mut OffscreenRenderer = &mut guard;
    renderer
        .face
        .set_overlay_image(&renderer.device, &renderer.queue, Some(&background), 0.7)
        .expect("overlay");
    renderer
        .face
        .set_weights(&renderer.queue, &BlendshapeWeights::default().0)
        .expect("weights");
    renderer
        .face
        .set_uv_mask(&renderer.queue, None)
        .expect("mask");
    let params = frame_params(StudioView::Shaded, &Orbit::default(), SIZE.0, SIZE.1);
    let image = renderer
        .render_image(SIZE.0, SIZE.1, &params)
        .expect("render");
    renderer
        .face
        .set_overlay_image(&renderer.device, &renderer.queue, None, 1.0)
        .expect("clear overlay");
    drop(guard);
    assert_matches_golden(&golden("overlay"), &image, Tolerance::default());
    // A corner far from the face shows the background image unchanged.
    for (x, y) in [(2, 2), (SIZE.0 - 3, 2)] {
        let got = image.get_pixel(x, y).0;
        let want = background.get_pixel(x, y).0;
        assert!(
            got.iter()
                .zip(want.iter())
                .all(|(a, b)| a.abs_diff(*b) <= 2),
            "{got:?} vs {want:?}"
        );
    }
}

/// The renderer's per-frame albedo correction (the mean albedo on the GPU plus the person's
/// 128 x 128 dR_0 + sum_i w_i A_i dR_i added in the shader) draws the same face as the
/// albedo of equation (3) computed on the CPU at full resolution and uploaded whole.
/// Tolerance: the two differ only in where the bilinear interpolations and the 8-bit
/// rounding happen, so every channel within 3/255 on 99.5 % of the pixels; and the
/// correction must matter (far more pixels change against the mean albedo).
#[test]
fn albedo_correction_matches_equation_3_on_the_cpu() {
    let (weights, _) =
        parse_weights("jawOpen=0.7,eyeBlinkLeft=1,mouthSmileRight=0.8").expect("weights");
    let [mean, cpu, gpu, cleared] = with_renderer(|scene, renderer| {
        let person = likeness::demo::synthetic_person(&scene.model, scene.albedo.face(), 7);
        let view = |r: &mut OffscreenRenderer| {
            render_view(
                scene,
                r,
                StudioView::Albedo,
                &weights,
                &Orbit::default(),
                SIZE,
            )
            .expect("render")
        };
        let mean = view(renderer);

        let albedo = scene
            .model
            .albedo(scene.albedo.face(), &person, &weights)
            .expect("equation 3");
        let face_texels = likeness::scene::rgba8_texels(&albedo);
        let face_layer = face::albedo::AlbedoLayer::Face.index();
        // Uploaded whole, then as the demo clip does, the face layer alone: the same
        // picture, to the bit.
        let mut whole = scene.textures.clone();
        whole.layers[face_layer] = face_texels.clone();
        renderer
            .face
            .set_albedo(&renderer.queue, &whole)
            .expect("albedo");
        let cpu = view(renderer);
        renderer
            .face
            .set_albedo(&renderer.queue, &scene.textures)
            .expect("mean albedo");
        renderer
            .face
            .set_albedo_layer(&renderer.queue, face_layer as u32, &face_texels)
            .expect("face layer");
        assert!(
            view(renderer) == cpu,
            "one layer uploaded draws as the whole array"
        );
        for (layer, texels) in [
            (99, face_texels.clone()),
            (face_layer as u32, face_texels[1..].to_vec()),
        ] {
            let error = renderer
                .face
                .set_albedo_layer(&renderer.queue, layer, &texels)
                .expect_err("refused");
            assert!(error.to_string().contains("albedo layer"), "{error}");
        }

        renderer
            .face
            .set_albedo(&renderer.queue, &scene.textures)
            .expect("mean albedo");
        let correction = scene
            .model
            .albedo_correction(&person, &weights)
            .expect("correction");
        renderer
            .face
            .set_albedo_correction(
                &renderer.queue,
                Some(likeness::gpu_view::face_layer_correction(&correction)),
            )
            .expect("correction");
        let gpu = view(renderer);
        renderer
            .face
            .set_albedo_correction(&renderer.queue, None)
            .expect("clear correction");
        // Removing the correction gives the mean albedo back.
        let cleared = view(renderer);
        [mean, cpu, gpu, cleared]
    });

    let within = |a: &image::RgbaImage, b: &image::RgbaImage, tol: u8| {
        a.pixels()
            .zip(b.pixels())
            .filter(|(p, q)| {
                p.0.iter()
                    .zip(q.0.iter())
                    .all(|(x, y)| x.abs_diff(*y) <= tol)
            })
            .count() as f64
            / (a.width() * a.height()) as f64
    };
    let agree = within(&cpu, &gpu, 3);
    assert!(
        agree >= 0.995,
        "GPU and CPU equation 3 agree on {:.2} % of the pixels",
        agree * 100.0
    );
    assert_eq!(
        within(&cleared, &mean, 0),
        1.0,
        "clearing the correction restores the mean"
    );
    let changed = changed_pixels(&mean, &cpu);
    assert!(
        changed > 2000,
        "the person's albedo changes only {changed} pixels"
    );
}

/// Bad corrections are errors, not a corrupted frame.
#[test]
fn albedo_correction_rejects_bad_input() {
    let f = fixture();
    let mut guard = f.renderer.lock().unwrap_or_else(|e| e.into_inner());
    let renderer: &mut OffscreenRenderer = &mut guard;
    let queue = renderer.queue.clone();
    let mut set = |rgb: &[f32], width, height, layer| {
        renderer.face.set_albedo_correction(
            &queue,
            Some(renderer::AlbedoCorrection {
                rgb,
                width,
                height,
                layer,
            }),
        )
    };
    assert!(set(&[0.0; 11], 2, 2, 0).is_err(), "wrong length");
    assert!(set(&[0.0, 0.0, f32::NAN], 1, 1, 0).is_err(), "NaN");
    assert!(set(&[0.0; 3], 1, 1, 99).is_err(), "no such layer");
    assert!(set(&[0.1; 3], 1, 1, 0).is_ok());
    renderer
        .face
        .set_albedo_correction(&queue, None)
        .expect("clear");
}

/// Renderers `a` and `b` draw the same `views` of the template with `weights` from
/// `yaw`/`pitch`: at most 0.5 % of the pixels off by more than 3 levels (the goldens'
/// tolerance).
fn assert_same_pictures(
    scene: &Scene,
    a: &mut OffscreenRenderer,
    b: &mut OffscreenRenderer,
    weights: &str,
    yaw: f32,
    pitch: f32,
    views: &[StudioView],
) {
    let (w, _) = parse_weights(weights).expect("weights");
    let orbit = Orbit {
        yaw_deg: yaw,
        pitch_deg: pitch,
        ..Orbit::default()
    };
    let adapter = b.adapter_info().backend;
    for &view in views {
        let pa = render_view(scene, a, view, &w, &orbit, SIZE).expect("render");
        let pb = render_view(scene, b, view, &w, &orbit, SIZE).expect("render");
        let off = pixels_off_by_more_than(3, &pa, &pb);
        assert!(
            off as f64 <= 0.005 * (SIZE.0 * SIZE.1) as f64,
            "{weights:?} yaw {yaw} pitch {pitch} {view:?} ({adapter:?}): {off} pixels differ"
        );
    }
}

/// Culling back faces (what the studio's template views do) leaves the template's
/// pictures as they are: its triangles face outwards everywhere that can be seen, the
/// mouth's inside and the eyes included. Same tolerance as the goldens, from the front,
/// three-quarter, profile, below and above, neutral and with the mouth wide open.
#[test]
fn culling_back_faces_leaves_the_template_pictures_unchanged() {
    with_renderer(|scene, full| {
        let options = renderer::OffscreenOptions {
            cull_back_faces: true,
            ..Default::default()
        };
        let mut culled = OffscreenRenderer::with_options(&scene.mesh, &scene.textures, options)
            .unwrap_or_else(|e| panic!("no adapter: {e:#}"));
        for (weights, yaw, pitch) in [
            ("", 0.0, 0.0),
            ("jawOpen=1,mouthSmileLeft=1,mouthFunnel=0.5", 0.0, 0.0),
            ("jawOpen=0.8", 40.0, -15.0),
            ("eyeBlinkLeft=1,jawOpen=0.5", 90.0, 0.0),
            ("jawOpen=1", -30.0, 35.0),
            ("", -90.0, -40.0),
        ] {
            let views = [StudioView::Shaded, StudioView::Normals];
            assert_same_pictures(scene, full, &mut culled, weights, yaw, pitch, &views);
        }
    });
}

/// The OpenGL backend (what WebGL2 browsers and the headless browser test run) draws the
/// template's pictures as the default backend does: shaded, albedo and normals from two
/// poses, same tolerance as the culling test. (A square albedo texture with six layers was
/// once taken for a cube map on OpenGL and read black.)
#[test]
fn the_opengl_backend_draws_what_the_default_backend_draws() {
    with_renderer(|scene, default| {
        let options = renderer::OffscreenOptions {
            backends: Some(wgpu::Backends::GL),
            ..Default::default()
        };
        let mut gl = OffscreenRenderer::with_options(&scene.mesh, &scene.textures, options)
            .unwrap_or_else(|e| panic!("no OpenGL adapter (Mesa's EGL, libegl1): {e:#}"));
        assert_eq!(gl.adapter_info().backend, wgpu::Backend::Gl);
        for (weights, yaw) in [("", 0.0), ("jawOpen=0.8,mouthSmileLeft=1", 35.0)] {
            let views = [StudioView::Shaded, StudioView::Albedo, StudioView::Normals];
            assert_same_pictures(scene, default, &mut gl, weights, yaw, 0.0, &views);
        }
    });
}
