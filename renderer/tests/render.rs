//! Headless rendering tests (lavapipe here) on a synthetic mesh: a UV sphere with two
//! blendshapes (0 bulges the top, 1 moves a patch on the front-right) and a two-layer
//! checker albedo whose layer 0 has a yellow band at the north pole.
//!
//! Golden images live in `tests/goldens/` (256x256). They are compared with
//! `golden::Tolerance::default()`: every channel within 3/255 on at least 99.5 % of the
//! pixels, which absorbs driver rounding and a few anti-aliased edge pixels but fails on any
//! visible change. Regenerate with `LIKENESS_UPDATE_GOLDENS=1 cargo test -p renderer` and
//! look at the images before committing them.

use glam::{Mat4, Vec3};
use image::RgbaImage;
use renderer::golden::{Tolerance, assert_matches_golden, compare};
use renderer::synthetic::{checker_albedo, uv_sphere};
use renderer::{
    BlendPath, Camera, FrameParams, MeshData, OffscreenOptions, OffscreenRenderer, RenderError,
    TextureLayers, ViewMode, sh_ambient,
};
use std::path::PathBuf;

const SIZE: u32 = 256;

fn sphere() -> MeshData {
    uv_sphere(32, 48, 2)
}

fn camera(size: u32) -> Camera {
    // Camera on the +z axis looking at the sphere (radius 1) at the origin.
    let s = size as f32;
    Camera::from_intrinsics(
        0.98 * s,
        s / 2.0,
        s / 2.0,
        size,
        size,
        0.1,
        20.0,
        Mat4::from_translation(Vec3::new(0.0, 0.0, -3.2)),
    )
}

fn params(view: ViewMode) -> FrameParams {
    FrameParams {
        view,
        ..FrameParams::new(camera(SIZE))
    }
}

fn offscreen(mesh: &MeshData, albedo: &TextureLayers) -> OffscreenRenderer {
    let r = OffscreenRenderer::new(mesh, albedo)
        .expect("offscreen renderer (is mesa-vulkan-drivers installed?)");
    eprintln!(
        "adapter: {:?}, msaa x{}",
        r.adapter_info().name,
        r.face.sample_count()
    );
    r
}

fn golden(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/goldens")
        .join(format!("{name}.png"))
}

/// Pixels whose RGB differs by more than `threshold` in some channel.
fn changed_pixels(a: &RgbaImage, b: &RgbaImage, threshold: u8) -> usize {
    a.pixels()
        .zip(b.pixels())
        .filter(|(p, q)| (0..3).any(|c| p.0[c].abs_diff(q.0[c]) > threshold))
        .count()
}

fn pixel_at(img: &RgbaImage, cam: &Camera, p: Vec3) -> [u8; 4] {
    let px = cam
        .project_to_pixel(p, img.width(), img.height())
        .expect("in front of camera");
    img.get_pixel(px.x as u32, px.y as u32).0
}

#[test]
fn every_view_mode_matches_its_golden() {
    let mesh = sphere();
    let mut r = offscreen(&mesh, &checker_albedo(128, 8));
    r.face.set_weights(&r.queue, &[0.5, 1.0]).unwrap();
    // Mask: radial ramp around the centre of layer 0's tile.
    let (mw, mh) = (64u32, 64u32);
    let mask: Vec<f32> = (0..mw * mh)
        .map(|i| {
            let (x, y) = (
                (i % mw) as f32 / mw as f32 - 0.5,
                (i / mw) as f32 / mh as f32 - 0.5,
            );
            (1.0 - 2.0 * (x * x + y * y).sqrt()).clamp(0.0, 1.0)
        })
        .collect();
    r.face.set_uv_mask(&r.queue, Some((&mask, mw, mh))).unwrap();
    // Vertex scalars: height, so the heatmap runs blue (bottom) to red (top).
    let scalars: Vec<f32> = mesh.base_positions.iter().map(|p| p[1] + 1.0).collect();
    r.face.set_vertex_scalars(&r.queue, Some(&scalars)).unwrap();
    for view in ViewMode::ALL {
        let mut p = params(view);
        p.heatmap_max = 2.0;
        let img = r.render_image(SIZE, SIZE, &p).unwrap();
        let name = format!("{view:?}").to_lowercase();
        assert_matches_golden(&golden(&name), &img, Tolerance::default());
    }
}

#[test]
fn image_is_upright_and_lit_from_upper_left() {
    let mut r = offscreen(&sphere(), &checker_albedo(128, 8));
    let cam = camera(SIZE);
    let albedo = r
        .render_image(SIZE, SIZE, &params(ViewMode::Albedo))
        .unwrap();
    // The yellow band of layer 0 (+x half) is at the tile's top, i.e. the north pole.
    let yellow = |p: [u8; 4]| p[0] > 200 && p[1] > 180 && p[2] < 100;
    // 35 degrees from the pole, 20 degrees to the +x side of the front meridian.
    let north = Vec3::new(0.196, 0.819, 0.539).normalize();
    let south = Vec3::new(0.196, -0.819, 0.539).normalize();
    assert!(
        yellow(pixel_at(&albedo, &cam, north)),
        "{:?}",
        pixel_at(&albedo, &cam, north)
    );
    assert!(!yellow(pixel_at(&albedo, &cam, south)));
    // Model +y is up in the image.
    let up = cam.project_to_pixel(Vec3::Y, SIZE, SIZE).unwrap();
    assert!(up.y < SIZE as f32 / 2.0);

    // Studio light on a white sphere: the upper-left front is brighter than the lower right.
    let mut white = offscreen(&sphere(), &TextureLayers::solid(4, 4, 2, [255; 4]));
    let shaded = white
        .render_image(SIZE, SIZE, &params(ViewMode::Shaded))
        .unwrap();
    let lum = |p: [u8; 4]| p[0] as u32 + p[1] as u32 + p[2] as u32;
    let upper_left = pixel_at(&shaded, &cam, Vec3::new(-0.5, 0.5, 0.7).normalize());
    let lower_right = pixel_at(&shaded, &cam, Vec3::new(0.5, -0.5, 0.7).normalize());
    assert!(
        lum(upper_left) > lum(lower_right) + 60,
        "{upper_left:?} vs {lower_right:?}"
    );
}

#[test]
fn blendshape_at_weight_one_changes_the_image() {
    let mut r = offscreen(&sphere(), &checker_albedo(128, 8));
    let p = params(ViewMode::Shaded);
    let rest = r.render_image(SIZE, SIZE, &p).unwrap();
    for shape in 0..2 {
        let mut w = [0.0; 2];
        w[shape] = 1.0;
        r.face.set_weights(&r.queue, &w).unwrap();
        let posed = r.render_image(SIZE, SIZE, &p).unwrap();
        let changed = changed_pixels(&rest, &posed, 8);
        assert!(
            changed >= 800,
            "shape {shape}: only {changed} pixels changed"
        );
    }
}

#[test]
fn set_weights_changes_the_image_without_reuploading_the_mesh() {
    let mut r = offscreen(&sphere(), &checker_albedo(128, 8));
    let p = params(ViewMode::Normals);
    let before = r.render_image(SIZE, SIZE, &p).unwrap();
    r.face.set_weights(&r.queue, &[0.0, 0.7]).unwrap();
    let after = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(changed_pixels(&before, &after, 8) >= 500);
    // Back to zero weights gives back the rest image: the weights are state, the mesh is untouched.
    r.face.set_weights(&r.queue, &[0.0, 0.0]).unwrap();
    let again = r.render_image(SIZE, SIZE, &p).unwrap();
    assert_eq!(changed_pixels(&before, &again, 1), 0);
}

#[test]
fn invalid_weights_are_errors() {
    let mut r = offscreen(&sphere(), &checker_albedo(16, 4));
    let nan = r.face.set_weights(&r.queue, &[0.2, f32::NAN]);
    assert!(
        matches!(nan, Err(RenderError::InvalidWeights(_))),
        "{nan:?}"
    );
    let inf = r.face.set_weights(&r.queue, &[f32::INFINITY, 0.0]);
    assert!(matches!(inf, Err(RenderError::InvalidWeights(_))));
    let count = r.face.set_weights(&r.queue, &[0.2]);
    assert!(count.unwrap_err().to_string().contains("2 blendshapes"));
}

#[test]
fn inconsistent_mesh_data_is_an_error() {
    let albedo = checker_albedo(16, 4);
    let good = sphere();

    let mut m = good.clone();
    m.base_normals.pop();
    let err = OffscreenRenderer::new(&m, &albedo).err().expect("error");
    assert!(matches!(err, RenderError::InvalidMesh(_)));
    assert!(err.to_string().contains("base_normals"), "{err}");

    let mut m = good.clone();
    m.normal_deltas.truncate(m.normal_deltas.len() - 3);
    assert!(
        OffscreenRenderer::new(&m, &albedo)
            .err()
            .unwrap()
            .to_string()
            .contains("normal_deltas")
    );

    let mut m = good.clone();
    m.indices[7] = m.corners.len() as u32;
    assert!(
        OffscreenRenderer::new(&m, &albedo)
            .err()
            .unwrap()
            .to_string()
            .contains("indices[7]")
    );

    let mut m = good.clone();
    m.base_positions[3][0] = f32::NAN;
    assert!(
        OffscreenRenderer::new(&m, &albedo)
            .err()
            .unwrap()
            .to_string()
            .contains("base_positions[3]")
    );

    // Albedo with fewer layers than the corners use.
    let one_layer = TextureLayers::solid(4, 4, 1, [255; 4]);
    let err = OffscreenRenderer::new(&good, &one_layer).err().unwrap();
    assert!(matches!(err, RenderError::InvalidTexture(_)), "{err}");

    // set_mesh_deltas with a different shape count.
    let mut r = offscreen(&good, &albedo);
    let other = uv_sphere(32, 48, 3);
    assert!(matches!(
        r.face.set_mesh_deltas(&r.queue, &other),
        Err(RenderError::InvalidMesh(_))
    ));
    // ...and with the same topology it works and changes the image.
    let before = r.render_image(64, 64, &params(ViewMode::Normals)).unwrap();
    let mut bigger = good.clone();
    bigger.base_positions.iter_mut().for_each(|p| p[0] *= 1.3);
    r.face.set_mesh_deltas(&r.queue, &bigger).unwrap();
    let after = r.render_image(64, 64, &params(ViewMode::Normals)).unwrap();
    assert!(changed_pixels(&before, &after, 8) > 50);

    // Wrong-sized side inputs are errors too, not panics.
    assert!(
        r.face
            .set_vertex_scalars(&r.queue, Some(&[1.0, 2.0]))
            .is_err()
    );
    assert!(
        r.face
            .set_uv_mask(&r.queue, Some((&[0.5; 10], 4, 4)))
            .is_err()
    );
    assert!(r.render_image(0, 10, &params(ViewMode::Shaded)).is_err());
}

#[test]
fn overlay_fills_the_background_and_the_face_is_blended_over_it() {
    let mut r = offscreen(&sphere(), &checker_albedo(128, 8));
    let overlay = RgbaImage::from_fn(SIZE, SIZE, |x, y| image::Rgba([x as u8, y as u8, 200, 255]));
    let device = r.device.clone();
    r.face
        .set_overlay_image(&device, &r.queue, Some(&overlay), 0.5)
        .unwrap();
    let img = r
        .render_image(SIZE, SIZE, &params(ViewMode::Albedo))
        .unwrap();
    // Far from the mesh (corners): exactly the background image.
    for (x, y) in [(3, 3), (250, 5), (10, 240), (200, 250)] {
        assert_eq!(
            img.get_pixel(x, y),
            overlay.get_pixel(x, y),
            "pixel ({x}, {y})"
        );
    }
    // On the face: halfway between the overlay and the albedo-only render.
    r.face
        .set_overlay_image(&device, &r.queue, None, 1.0)
        .unwrap();
    let face = r
        .render_image(SIZE, SIZE, &params(ViewMode::Albedo))
        .unwrap();
    let (x, y) = (128, 128);
    for c in 0..3 {
        let expected =
            (face.get_pixel(x, y).0[c] as f32 + overlay.get_pixel(x, y).0[c] as f32) / 2.0;
        let got = img.get_pixel(x, y).0[c] as f32;
        assert!(
            (got - expected).abs() <= 2.0,
            "channel {c}: {got} vs {expected}"
        );
    }
    assert_matches_golden(&golden("overlay"), &img, Tolerance::default());
}

#[test]
fn ambient_sh_on_constant_albedo_gives_that_colour() {
    let colour = [200, 120, 60, 255];
    let mut r = offscreen(&sphere(), &TextureLayers::solid(8, 8, 2, colour));
    let mut p = params(ViewMode::Shaded);
    p.sh_coefficients = sh_ambient();
    r.face.set_weights(&r.queue, &[1.0, 1.0]).unwrap();
    // Fully covered pixels are those that do not depend on the background colour (edge
    // pixels are anti-aliased blends with it).
    p.background = [0.0, 0.0, 0.0, 1.0];
    let on_black = r.render_image(SIZE, SIZE, &p).unwrap();
    p.background = [1.0, 1.0, 1.0, 1.0];
    let on_white = r.render_image(SIZE, SIZE, &p).unwrap();
    let mut covered = 0;
    for (a, b) in on_black.pixels().zip(on_white.pixels()) {
        if a == b {
            covered += 1;
            for c in 0..3 {
                assert!(a.0[c].abs_diff(colour[c]) <= 2, "{:?} vs {colour:?}", a.0);
            }
        }
    }
    assert!(covered > 10_000, "only {covered} mesh pixels");
}

#[test]
fn face_sized_mesh_fits_webgl2_default_limits() {
    // The web build runs on WebGL2 with its default limits (2D textures <= 2048, 16 KiB
    // uniform blocks). A face-sized mesh (27k vertices, 53 shapes) must fit them.
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter =
        pollster::block_on(instance.request_adapter(&Default::default())).expect("adapter");
    let limits = wgpu::Limits::downlevel_webgl2_defaults();
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        required_limits: limits.clone(),
        ..Default::default()
    }))
    .expect("device");
    let mesh = uv_sphere(164, 166, 53);
    let format = wgpu::TextureFormat::Rgba8Unorm;
    let mut face =
        renderer::FaceRenderer::new(&device, &queue, format, &mesh, &checker_albedo(1024, 16))
            .expect("fits");
    face.set_weights(&queue, &vec![0.5; 53]).unwrap();
    let target = device.create_texture(&wgpu::TextureDescriptor {
        label: None,
        size: wgpu::Extent3d {
            width: 320,
            height: 240,
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: 1,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        view_formats: &[],
    });
    let view = target.create_view(&Default::default());
    let mut encoder = device.create_command_encoder(&Default::default());
    // Two renders into one encoder (e.g. two views in one UI frame) are allowed.
    for mode in [ViewMode::Shaded, ViewMode::Landmarks] {
        let mut p = FrameParams::new(camera(240));
        p.view = mode;
        face.render(&device, &queue, &mut encoder, &view, (320, 240), &p);
    }
    queue.submit([encoder.finish()]);
    device.poll(wgpu::PollType::wait_indefinitely()).unwrap();

    // A mesh that needs more than 2048 rows is refused with a clear error, not a panic.
    // 14282 vertices x (2 + 2 * 160) texels / 2048 = 2246 rows.
    let mut huge = uv_sphere(120, 120, 0);
    huge.blend_deltas = vec![[0.0; 3]; 160 * huge.vertex_count()];
    huge.normal_deltas = huge.blend_deltas.clone();
    let err = renderer::FaceRenderer::new(&device, &queue, format, &huge, &checker_albedo(16, 4))
        .err()
        .expect("too large");
    assert!(matches!(err, RenderError::TextureTooLarge { .. }), "{err}");
    assert!(err.to_string().contains("2048"), "{err}");
}

#[test]
fn renderer_can_live_in_egui_callback_resources() {
    // egui_wgpu::CallbackResources needs Send + Sync + 'static.
    fn assert_send_sync<T: Send + Sync + 'static>() {}
    assert_send_sync::<renderer::FaceRenderer>();
}

/// Renders every view mode, an overlay at opacity 0.5, and a weight change on `r`.
fn path_images(
    r: &mut OffscreenRenderer,
    mesh: &MeshData,
    k_weights: &[Vec<f32>],
) -> Vec<RgbaImage> {
    let mut out = Vec::new();
    let scalars: Vec<f32> = mesh.base_positions.iter().map(|p| p[1] + 1.0).collect();
    r.face.set_vertex_scalars(&r.queue, Some(&scalars)).unwrap();
    for w in k_weights {
        r.face.set_weights(&r.queue, w).unwrap();
        for view in ViewMode::ALL {
            let mut p = params(view);
            p.heatmap_max = 2.0;
            out.push(r.render_image(SIZE, SIZE, &p).unwrap());
        }
    }
    let overlay = RgbaImage::from_fn(SIZE, SIZE, |x, y| image::Rgba([x as u8, y as u8, 200, 255]));
    let device = r.device.clone();
    r.face
        .set_overlay_image(&device, &r.queue, Some(&overlay), 0.5)
        .unwrap();
    out.push(
        r.render_image(SIZE, SIZE, &params(ViewMode::Shaded))
            .unwrap(),
    );
    out
}

/// A renderer on `blend_path` whatever the adapter would choose (the pre-pass needs an
/// `Rgba32Float` render target, which this adapter must have).
fn forced(mesh: &MeshData, albedo: &TextureLayers, blend_path: BlendPath) -> OffscreenRenderer {
    let r = OffscreenRenderer::with_options(
        mesh,
        albedo,
        OffscreenOptions {
            blend_path: Some(blend_path),
            ..Default::default()
        },
    )
    .unwrap_or_else(|e| panic!("offscreen renderer on {blend_path:?}: {e}"));
    assert_eq!(r.face.blend_path(), blend_path);
    r
}

#[test]
fn per_vertex_and_cpu_blends_draw_what_the_blend_prepass_draws() {
    // The per-vertex fallback is what WebGL2 without EXT_color_buffer_float runs, the CPU
    // blend what a CPU adapter runs; force each here. All paths compute the same sums in
    // the same order, so only float rounding may differ.
    let albedo = checker_albedo(128, 8);
    for (mesh, weights) in [
        (
            sphere(),
            vec![vec![0.5, 1.0], vec![0.0, 0.0], vec![-0.3, 0.8]],
        ),
        // More shapes, and V large enough that the blended texture spans several rows.
        (
            uv_sphere(48, 64, 12),
            vec![(0..12).map(|k| 0.9 - 0.15 * k as f32).collect()],
        ),
    ] {
        let force = |blend_path| forced(&mesh, &albedo, blend_path);
        let prepass = path_images(&mut force(BlendPath::PrePass), &mesh, &weights);
        for other in [BlendPath::PerVertex, BlendPath::Cpu] {
            let images = path_images(&mut force(other), &mesh, &weights);
            assert_eq!(images.len(), prepass.len());
            for (i, (a, b)) in prepass.iter().zip(&images).enumerate() {
                let cmp = compare(a, b, Tolerance::default()).expect("same size");
                eprintln!(
                    "{other:?} image {i}: max diff {}, {} pixels outside tolerance",
                    cmp.max_diff, cmp.pixels_outside
                );
                assert!(
                    cmp.passes(Tolerance::default()),
                    "{other:?} image {i}: {}",
                    cmp.pixels_outside
                );
            }
        }
    }
    // And the fallback on its own still matches the goldens.
    let mut r = forced(&sphere(), &albedo, BlendPath::PerVertex);
    r.face.set_weights(&r.queue, &[0.5, 1.0]).unwrap();
    for view in [ViewMode::Shaded, ViewMode::Normals, ViewMode::Wireframe] {
        let img = r.render_image(SIZE, SIZE, &params(view)).unwrap();
        let name = format!("{view:?}").to_lowercase();
        assert_matches_golden(&golden(&name), &img, Tolerance::default());
    }
}

#[test]
fn blend_prepass_runs_only_after_a_change() {
    // Forced: a CPU adapter's default is the CPU blend (tested below).
    let mut r = forced(&sphere(), &checker_albedo(64, 4), BlendPath::PrePass);
    let p = params(ViewMode::Normals);
    assert!(r.face.blend_pending(), "the first frame blends");
    let rest = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(!r.face.blend_pending());
    // Re-setting the same weights (a UI doing it every frame) is not a change.
    r.face.set_weights(&r.queue, &[0.0, 0.0]).unwrap();
    assert!(!r.face.blend_pending());
    r.face.set_weights(&r.queue, &[0.0, 0.9]).unwrap();
    assert!(r.face.blend_pending());
    let posed = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(changed_pixels(&rest, &posed, 8) >= 500);
    // Frames without a change reuse the blended geometry.
    let again = r.render_image(SIZE, SIZE, &p).unwrap();
    assert_eq!(changed_pixels(&posed, &again, 0), 0);
    // New geometry re-blends too.
    let mut moved = sphere();
    moved.base_positions.iter_mut().for_each(|p| p[0] *= 1.3);
    r.face.set_mesh_deltas(&r.queue, &moved).unwrap();
    assert!(r.face.blend_pending());
    let wider = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(changed_pixels(&again, &wider, 8) > 500);
}

#[test]
fn cpu_blend_follows_weight_and_geometry_changes() {
    let mut r = forced(&sphere(), &checker_albedo(64, 4), BlendPath::Cpu);
    assert!(!r.face.blend_pending(), "the CPU blend records no pass");
    let p = params(ViewMode::Normals);
    let rest = r.render_image(SIZE, SIZE, &p).unwrap();
    r.face.set_weights(&r.queue, &[0.0, 0.9]).unwrap();
    let posed = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(changed_pixels(&rest, &posed, 8) >= 500);
    // Back to the rest weights: the rest picture again.
    r.face.set_weights(&r.queue, &[0.0, 0.0]).unwrap();
    let back = r.render_image(SIZE, SIZE, &p).unwrap();
    assert_eq!(changed_pixels(&rest, &back, 0), 0);
    // New geometry is blended under the current weights.
    r.face.set_weights(&r.queue, &[0.0, 0.9]).unwrap();
    let mut moved = sphere();
    moved.base_positions.iter_mut().for_each(|p| p[0] *= 1.3);
    r.face.set_mesh_deltas(&r.queue, &moved).unwrap();
    let wider = r.render_image(SIZE, SIZE, &p).unwrap();
    assert!(changed_pixels(&posed, &wider, 8) > 500);
}

/// The sphere as "the left eyeball" (every vertex, turning about its centre, the origin)
/// with its shapes' deltas zeroed, so only the gaze moves it.
fn eyeball() -> MeshData {
    let mut mesh = uv_sphere(32, 48, face::NUM_BLENDSHAPES);
    mesh.blend_deltas.fill([0.0; 3]);
    mesh.normal_deltas.fill([0.0; 3]);
    let v = mesh.vertex_count();
    mesh.eyes = Some(face::gaze::Eyes {
        ranges: [0..v, v..v],
        centres: [Vec3::ZERO; 2],
    });
    mesh
}

#[test]
fn a_turned_eye_is_the_still_eye_seen_from_a_turned_camera() {
    // Turning the eyeball by R before the camera V is the camera V R on the still eyeball:
    // the same positions, and the same view-space normals, so the same shading. An
    // expectation that needs no golden, on every blend path.
    let mesh = eyeball();
    let albedo = checker_albedo(128, 8);
    let mut gaze = vec![0.0; face::NUM_BLENDSHAPES];
    let set = |w: &mut Vec<f32>, name: &str, v: f32| {
        w[face::names::ict_index(name).expect("ICT name")] = v;
    };
    set(&mut gaze, "eyeLookOut_L", 1.0);
    set(&mut gaze, "eyeLookDown_L", 0.6);
    // The right eye's channels turn nothing here: its range is empty.
    set(&mut gaze, "eyeLookUp_R", 1.0);
    let weights: [f32; face::NUM_BLENDSHAPES] = gaze.clone().try_into().expect("53");
    let rotation = face::gaze::eye_rotation(face::gaze::eye_angles(&weights)[0]);
    let turned_camera = {
        let c = camera(SIZE);
        Camera::from_intrinsics(
            0.98 * SIZE as f32,
            SIZE as f32 / 2.0,
            SIZE as f32 / 2.0,
            SIZE,
            SIZE,
            0.1,
            20.0,
            c.view_from_model * Mat4::from_mat3(rotation),
        )
    };
    for path in [BlendPath::PrePass, BlendPath::PerVertex, BlendPath::Cpu] {
        let mut r = forced(&mesh, &albedo, path);
        let still = r
            .render_image(SIZE, SIZE, &params(ViewMode::Shaded))
            .unwrap();
        r.face.set_weights(&r.queue, &gaze).unwrap();
        let turned = r
            .render_image(SIZE, SIZE, &params(ViewMode::Shaded))
            .unwrap();
        r.face
            .set_weights(&r.queue, &vec![0.0; face::NUM_BLENDSHAPES])
            .unwrap();
        let mut seen = params(ViewMode::Shaded);
        seen.camera = turned_camera;
        let expected = r.render_image(SIZE, SIZE, &seen).unwrap();
        let cmp = compare(&turned, &expected, Tolerance::default()).expect("same size");
        assert!(
            cmp.passes(Tolerance::default()),
            "{path:?}: {} pixels off, max diff {}",
            cmp.pixels_outside,
            cmp.max_diff
        );
        // And the gaze did move the eye: the checker's squares moved across the disc.
        let moved = changed_pixels(&still, &turned, 40);
        assert!(moved > 3000, "{path:?}: only {moved} pixels changed");
    }
}

#[test]
fn eyes_follow_new_centres_from_set_mesh_deltas() {
    // Moving the centre off the sphere's: the turn then also shifts the sphere.
    let mesh = eyeball();
    let albedo = checker_albedo(128, 8);
    let mut gaze = vec![0.0; face::NUM_BLENDSHAPES];
    gaze[face::names::ict_index("eyeLookIn_L").expect("ICT name")] = 1.0;
    for path in [BlendPath::PrePass, BlendPath::Cpu] {
        let mut r = forced(&mesh, &albedo, path);
        r.face.set_weights(&r.queue, &gaze).unwrap();
        let about_origin = r
            .render_image(SIZE, SIZE, &params(ViewMode::Shaded))
            .unwrap();
        let mut moved = mesh.clone();
        if let Some(eyes) = moved.eyes.as_mut() {
            eyes.centres[0] = Vec3::new(0.0, 0.0, -1.0);
        }
        r.face.set_mesh_deltas(&r.queue, &moved).unwrap();
        let about_back = r
            .render_image(SIZE, SIZE, &params(ViewMode::Shaded))
            .unwrap();
        // Yaw -30 degrees about (0, 0, -1) carries the sphere's centre to
        // (-sin 30, 0, cos 30 - 1): half a radius sideways, ~40 px at this size.
        let shift = changed_pixels(&about_origin, &about_back, 40);
        assert!(shift > 2000, "{path:?}: only {shift} pixels changed");
        let expected_centre = Vec3::new(
            -(30f32.to_radians().sin()),
            0.0,
            30f32.to_radians().cos() - 1.0,
        );
        let cam = camera(SIZE);
        // The sphere's new centre is covered, and the far side of the old disc is empty.
        let background = FrameParams::new(cam).background;
        let is_background =
            |p: [u8; 4]| (0..3).all(|c| (p[c] as f32 - background[c] * 255.0).abs() < 3.0);
        let centre = pixel_at(&about_back, &cam, expected_centre + Vec3::Z);
        assert!(
            !is_background(centre),
            "{path:?}: the new centre shows {centre:?}"
        );
        let far_edge = pixel_at(&about_back, &cam, Vec3::new(0.95, 0.0, 0.0));
        assert!(
            is_background(far_edge),
            "{path:?}: {far_edge:?} is not the background"
        );
        assert!(!is_background(pixel_at(
            &about_origin,
            &cam,
            Vec3::new(0.95, 0.0, 0.0)
        )));
    }
}

#[test]
fn eyes_on_a_mesh_without_icts_shapes_are_refused() {
    let mut mesh = sphere();
    mesh.eyes = eyeball().eyes;
    let err = OffscreenRenderer::new(&mesh, &checker_albedo(128, 8))
        .err()
        .expect("refused");
    assert!(matches!(err, RenderError::InvalidMesh(_)), "{err}");
}
