//! The studio's panels as PNG files without a display (`demo --headless`, and `studio` on a
//! machine without one): the real [`StudioApp`] on a session, drawn frame by frame by
//! egui's headless harness on whatever wgpu adapter there is (lavapipe without a GPU).
//!
//! `egui_kittest` is egui's own headless runner: it drives an eframe app without a window
//! and reads back what egui-wgpu drew, custom wgpu textures included. Writing that loop by
//! hand would repeat it, and the files would then not be what the studio shows.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, anyhow};
use egui_kittest::Harness;
use egui_kittest::wgpu::WgpuTestRenderer;

use crate::headless::save_png;
use crate::puppet_panel::DriveTarget;
use crate::scene::{Scene, StudioView};
use crate::studio::{Panel, StudioApp};
use crate::studio_session::StudioSession;
use crate::uv_panel::UvLayer;

/// Window size of the written panels, in points (one pixel per point).
pub const SHOT_SIZE: [f32; 2] = [1280.0, 800.0];

/// One written panel: its file stem and how the studio is set up for it.
struct Shot {
    name: &'static str,
    setup: fn(&mut StudioApp, &Scene) -> Result<()>,
}

fn input_panel(app: &mut StudioApp, overlays: bool) -> Result<()> {
    app.state.panel = Panel::Input;
    let p = &mut app.state.playback;
    p.show_detected = overlays;
    p.show_model = overlays;
    p.show_boxes = overlays;
    app.overlay.opacity = if overlays { 0.6 } else { 0.0 };
    Ok(())
}

fn maps_panel(app: &mut StudioApp, layer: UvLayer) -> Result<()> {
    app.state.panel = Panel::Maps;
    app.uv_panel.layer = Some(layer);
    // Each written map fills its colour range (the legend gives its own scale).
    app.uv_panel.scale_per_map = true;
    Ok(())
}

const SHOTS: &[Shot] = &[
    Shot {
        name: "input",
        setup: |app, _| input_panel(app, false),
    },
    Shot {
        name: "overlay",
        setup: |app, _| input_panel(app, true),
    },
    Shot {
        name: "face",
        setup: |app, _| {
            app.state.panel = Panel::Face;
            app.state.view = StudioView::Shaded;
            Ok(())
        },
    },
    Shot {
        name: "blendshapes",
        setup: |app, _| {
            app.state.panel = Panel::Blendshapes;
            app.blendshape_panel.show_mask = false;
            Ok(())
        },
    },
    Shot {
        name: "static_albedo",
        setup: |app, _| maps_panel(app, UvLayer::StaticAlbedo),
    },
    Shot {
        name: "dynamic_albedo",
        setup: |app, _| maps_panel(app, UvLayer::DynamicAlbedo),
    },
    Shot {
        name: "frame_albedo",
        setup: |app, _| maps_panel(app, UvLayer::FrameAlbedo),
    },
    Shot {
        name: "attention_mask",
        setup: |app, _| maps_panel(app, UvLayer::Mask),
    },
    Shot {
        name: "attention_mask_on_mesh",
        setup: |app, _| {
            app.state.panel = Panel::Blendshapes;
            app.blendshape_panel.show_mask = true;
            Ok(())
        },
    },
    Shot {
        name: "shape_correction",
        setup: |app, _| maps_panel(app, UvLayer::ShapeCorrection),
    },
    Shot {
        name: "lighting_and_motion",
        setup: |app, _| {
            app.state.panel = Panel::Motion;
            Ok(())
        },
    },
    Shot {
        name: "puppet",
        setup: |app, _| {
            app.state.panel = Panel::Puppet;
            app.puppet_panel.drive = DriveTarget::Puppet;
            app.puppet_panel.ensure_demo_puppet()
        },
    },
    Shot {
        name: "person_b",
        setup: |app, scene| {
            app.state.panel = Panel::Puppet;
            app.puppet_panel.drive_person_b(scene)
        },
    },
];

/// egui-wgpu on the preferred software or hardware adapter, created here rather than by
/// the harness's `wgpu()` so a machine without any adapter gets an error, not a panic.
fn headless_renderer() -> Result<WgpuTestRenderer> {
    Ok(WgpuTestRenderer::from_render_state(headless_render_state(
        egui_wgpu::RendererOptions::PREDICTABLE,
    )?))
}

/// egui-wgpu's state on the preferred adapter with `options` (kittest's predictable
/// filtering for written panels, the window's defaults for the benchmark).
/// A wgpu adapter and egui renderer without a window: the harness's, `bench-studio`'s and
/// the software window's (`soft_window`).
pub fn headless_render_state(
    options: egui_wgpu::RendererOptions,
) -> Result<egui_wgpu::RenderState> {
    let setup = egui_kittest::wgpu::default_wgpu_setup();
    let instance = pollster::block_on(setup.new_instance());
    let render_state = pollster::block_on(egui_wgpu::RenderState::create(
        &egui_wgpu::WgpuConfiguration {
            wgpu_setup: setup,
            ..Default::default()
        },
        &instance,
        None,
        options,
    ))
    .map_err(|e| {
        anyhow!(
            "no GPU adapter for drawing the studio's panels ({e}; on Debian install mesa-vulkan-drivers for lavapipe)"
        )
    })?;
    Ok(render_state)
}

/// Sets `app` up as for the written panel `name` (see [`panel_file_names`]; "overlay",
/// "face", "puppet" and "person_b" are the live ones).
pub fn set_up_panel(app: &mut StudioApp, scene: &Scene, name: &str) -> Result<()> {
    let shot = SHOTS.iter().find(|s| s.name == name).ok_or_else(|| {
        let names: Vec<&str> = SHOTS.iter().map(|s| s.name).collect();
        anyhow!("no panel `{name}`; the panels are {}", names.join(", "))
    })?;
    (shot.setup)(app, scene)
}

/// The names of the files [`write_studio_panels`] writes, in order.
pub fn panel_file_names() -> Vec<String> {
    SHOTS
        .iter()
        .map(|s| format!("panel_{}.png", s.name))
        .collect()
}

/// Writes every panel of the studio on `session` to `out_dir/panel_<name>.png`, paused on
/// `frame` (default: the middle of the clip) with the blendshape of the largest personal
/// correction selected.
pub fn write_studio_panels(
    scene: Arc<Scene>,
    session: Arc<StudioSession>,
    frame: Option<usize>,
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let frames = session.frame_count();
    if frames == 0 {
        anyhow::bail!("the session has no frames to show");
    }
    let frame = frame.unwrap_or(frames / 2).min(frames - 1);
    let selected = session.by_correction_size().first().copied();
    let app_scene = scene.clone();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(SHOT_SIZE[0], SHOT_SIZE[1]))
        .with_pixels_per_point(1.0)
        .renderer(headless_renderer()?)
        .build_eframe(move |cc| {
            let mut app = StudioApp::new(cc, app_scene).with_session(session);
            app.state.show_timings = false;
            app.state.playback.playing = false;
            app.state.playback.frame = frame;
            if let Some(i) = selected {
                app.state.selected = i;
            }
            app
        });
    let mut written = Vec::new();
    for shot in SHOTS {
        (shot.setup)(harness.state_mut(), &scene)
            .with_context(|| format!("setting up the {} panel", shot.name))?;
        // Textures (frames, maps, the puppet) upload on the first frame a panel is drawn;
        // the later frames show them.
        harness.run_steps(3);
        no_error_shown(&harness, &format!("the {} panel", shot.name))?;
        let image = harness
            .render()
            .map_err(|e| anyhow!("cannot render the {} panel: {e}", shot.name))?;
        let path = out_dir.join(format!("panel_{}.png", shot.name));
        save_png(&image, &path)?;
        written.push(path);
    }
    Ok(written)
}

/// The panels [`bench_studio`] times by default: the ones that render 3D views while the
/// clip plays, set up as for the written panels.
pub const LIVE_PANELS: [&str; 4] = ["overlay", "face", "puppet", "person_b"];

/// The renderer options of the studio's window (see `run_studio` in main.rs): eframe's
/// defaults without dithering.
pub fn window_renderer_options() -> egui_wgpu::RendererOptions {
    egui_wgpu::RendererOptions {
        dithering: false,
        ..Default::default()
    }
}

/// The native window's wgpu configuration: the studio's and `examples/present_floor.rs`'s,
/// so the floor measures the same presentation.
pub fn window_wgpu_configuration(vsync: bool) -> egui_wgpu::WgpuConfiguration {
    egui_wgpu::WgpuConfiguration {
        surface: egui_wgpu::SurfaceConfig {
            present_mode: if vsync {
                wgpu::PresentMode::AutoVsync
            } else {
                wgpu::PresentMode::AutoNoVsync
            },
            ..egui_wgpu::WgpuConfiguration::default().surface
        },
        ..Default::default()
    }
}

/// Fails with the studio's latest error, if it shows one, naming `what` was being drawn.
fn no_error_shown(harness: &Harness<'_, StudioApp>, what: &str) -> Result<()> {
    match harness.state().state.notices.latest_error() {
        Some(error) => anyhow::bail!("{what} reported an error: {error}"),
        None => Ok(()),
    }
}

/// egui's tessellation of the harness's last frame: what a software rasteriser draws for
/// the UI, measured by [`egui_triangles`] and [`covered_megapixels`].
pub fn last_frame_primitives(harness: &Harness<'_, StudioApp>) -> Vec<egui::ClippedPrimitive> {
    harness.ctx.tessellate(harness.output().shapes.clone(), 1.0)
}

/// How many triangles egui tessellates for the harness's last frame: the studio's own
/// drawing cost on a software rasteriser, which `bench-studio` reports.
pub fn egui_triangles(harness: &Harness<'_, StudioApp>) -> usize {
    triangles(&last_frame_primitives(harness))
}

fn triangles(primitives: &[egui::ClippedPrimitive]) -> usize {
    primitives
        .iter()
        .map(|p| match &p.primitive {
            egui::epaint::Primitive::Mesh(m) => m.indices.len() / 3,
            egui::epaint::Primitive::Callback(_) => 0,
        })
        .sum()
}

/// How many pixels `primitives` cover, counting overlaps (each triangle's area within its
/// clip rectangle's bounds): the fragment work a software rasteriser does for the UI, in
/// megapixels. A window-sized panel is 0.92 at 1280x720.
fn covered_megapixels(primitives: &[egui::ClippedPrimitive]) -> f64 {
    let mut pixels = 0.0f64;
    for p in primitives {
        let egui::epaint::Primitive::Mesh(m) = &p.primitive else {
            continue;
        };
        for t in m.indices.chunks_exact(3) {
            let [a, b, c] = [t[0], t[1], t[2]].map(|i| m.vertices[i as usize].pos);
            let bounds = egui::Rect::from_points(&[a, b, c]);
            let shown = bounds.intersect(p.clip_rect);
            if !shown.is_positive() {
                continue;
            }
            let area = 0.5 * ((b - a).x * (c - a).y - (b - a).y * (c - a).x).abs() as f64;
            // Scaled by how much of the bounding box the clip keeps: exact for the
            // axis-aligned rectangles that carry most of the area.
            pixels += area * f64::from(shown.area()) / f64::from(bounds.area().max(1e-6));
        }
    }
    pixels / 1e6
}

/// One line of [`bench_studio`]'s table.
#[derive(Clone, Debug)]
pub struct BenchRow {
    pub panel: String,
    pub frames: usize,
    /// Mean and 95th percentile time of one studio frame (all the parts below),
    /// milliseconds.
    pub mean_ms: f64,
    pub p95_ms: f64,
    /// Mean of the parts: the app's UI code (which records and submits the 3D views), the
    /// wait for those 3D views on the device, and egui's tessellation, paint and read-back.
    pub ui_ms: f64,
    pub views_ms: f64,
    pub paint_ms: f64,
    /// How many frames rendered at least one 3D view (the rest reused the last picture).
    pub frames_with_3d: usize,
    /// egui triangles of the last frame.
    pub triangles: usize,
    /// Pixels those triangles cover, overlaps counted (`covered_megapixels`).
    pub covered_megapixels: f64,
    /// Clipped primitives of the last frame: egui-wgpu issues one draw (with its own
    /// scissor rectangle) for each, and on lavapipe each costs about 0.1 ms whatever its
    /// size (`examples/present_floor.rs`).
    pub draw_calls: usize,
}

impl BenchRow {
    pub fn fps(&self) -> f64 {
        1000.0 / self.mean_ms.max(1e-9)
    }
}

/// Times the studio playing `session` at `size` pixels on each of `panels`, one after the
/// other in one process, as a 60 Hz display would (each step advances 1/60 s of the clip):
/// every frame runs the whole UI, waits for the 3D views it rendered, then tessellates and
/// paints the window through egui-wgpu with the window's options and reads the picture
/// back. A window presents instead of reading back; `studio --measure-fps` measures that.
pub fn bench_studio(
    scene: Arc<Scene>,
    session: Arc<StudioSession>,
    size: [u32; 2],
    frames: usize,
    panels: &[String],
) -> Result<Vec<BenchRow>> {
    if session.frame_count() == 0 {
        anyhow::bail!("the session has no frames to play");
    }
    let render_state = headless_render_state(window_renderer_options())?;
    let device = render_state.device.clone();
    // Drawn as the window would be on this adapter (`StudioApp::smooth_edges`).
    let on_cpu = render_state.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    let app_scene = scene.clone();
    let mut harness = Harness::builder()
        .with_size(egui::vec2(size[0] as f32, size[1] as f32))
        .with_pixels_per_point(1.0)
        .with_step_dt(1.0 / 60.0)
        .renderer(WgpuTestRenderer::from_render_state(render_state))
        .build_eframe(move |cc| {
            let mut app = StudioApp::new(cc, app_scene).with_session(session);
            app.state.show_timings = false;
            app.window_on_cpu_adapter = on_cpu;
            app
        });
    let mut rows = Vec::new();
    for panel in panels {
        // `puppet:full` is the puppet panel with its 3D view at full size while playing,
        // for a side-by-side comparison with the default half size on a CPU adapter.
        let (base, full_3d) = match panel.strip_suffix(":full") {
            Some(base) => (base, true),
            None => (panel.as_str(), false),
        };
        set_up_panel(harness.state_mut(), &scene, base)?;
        harness.state_mut().settings.reduce_3d_while_playing = full_3d.then_some(false);
        harness.state_mut().state.playback.playing = true;
        // Warm-up: the first frames upload textures and build pipelines.
        for _ in 0..5 {
            harness.step();
            harness.render().map_err(|e| anyhow!("{panel}: {e}"))?;
        }
        let mut times = Vec::with_capacity(frames);
        let (mut ui_ms, mut views_ms, mut paint_ms) = (0.0, 0.0, 0.0);
        let mut frames_with_3d = 0;
        let ms = |t: std::time::Instant| t.elapsed().as_secs_f64() * 1000.0;
        for _ in 0..frames.max(1) {
            let renders_before = harness.state().view_renders();
            let started = std::time::Instant::now();
            harness.step();
            let ui = ms(started);
            device
                .poll(wgpu::PollType::wait_indefinitely())
                .map_err(|e| anyhow!("{panel}: {e}"))?;
            let views = ms(started) - ui;
            harness.render().map_err(|e| anyhow!("{panel}: {e}"))?;
            let total = ms(started);
            times.push(total);
            ui_ms += ui;
            views_ms += views;
            paint_ms += total - ui - views;
            if harness.state().view_renders() != renders_before {
                frames_with_3d += 1;
            }
        }
        no_error_shown(&harness, panel)?;
        let primitives = last_frame_primitives(&harness);
        let n = times.len() as f64;
        times.sort_by(f64::total_cmp);
        rows.push(BenchRow {
            panel: panel.clone(),
            frames: times.len(),
            mean_ms: times.iter().sum::<f64>() / n,
            p95_ms: times[((n * 0.95) as usize).min(times.len() - 1)],
            ui_ms: ui_ms / n,
            views_ms: views_ms / n,
            paint_ms: paint_ms / n,
            frames_with_3d,
            triangles: triangles(&primitives),
            covered_megapixels: covered_megapixels(&primitives),
            draw_calls: primitives.len(),
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covered_pixels_of_a_clipped_rectangle_and_an_overlap() {
        let mut mesh = egui::Mesh::default();
        mesh.add_colored_rect(
            egui::Rect::from_min_size(egui::pos2(0.0, 0.0), egui::vec2(1000.0, 500.0)),
            egui::Color32::WHITE,
        );
        let clipped = |clip: egui::Rect| egui::ClippedPrimitive {
            clip_rect: clip,
            primitive: egui::epaint::Primitive::Mesh(mesh.clone()),
        };
        // Clipped to 600 x 500, then drawn again unclipped: 0.3 + 0.5 megapixels.
        let prims = [
            clipped(egui::Rect::from_min_size(
                egui::Pos2::ZERO,
                egui::vec2(600.0, 800.0),
            )),
            clipped(egui::Rect::EVERYTHING),
        ];
        let covered = covered_megapixels(&prims);
        assert!((covered - 0.8).abs() < 1e-9, "{covered}");
        let outside = clipped(egui::Rect::from_min_size(
            egui::pos2(2000.0, 0.0),
            egui::vec2(10.0, 10.0),
        ));
        assert_eq!(covered_megapixels(&[outside]), 0.0);
    }
}
