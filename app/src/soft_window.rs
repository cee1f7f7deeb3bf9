//! A native window for an [`eframe::App`] drawn by a CPU adapter (Mesa's lavapipe): egui is
//! rendered offscreen with egui-wgpu, read back, and shown with `softbuffer`.
//!
//! Why not eframe's own window: lavapipe's Vulkan swapchain (Mesa 22.3, Debian 12) uses
//! MIT-SHM only when the X server also offers DRI3, which Xvfb and most remote or virtual
//! displays do not; it then sends every frame through the X socket (`xcb_put_image`), and the
//! server allocates, faults in and copies 3.7 MB per frame at 1280x720. On this machine that
//! alone holds an empty eframe window to 90-240 fps, while `softbuffer` (MIT-SHM on X11,
//! `wl_shm` on Wayland) shows the same frame in about 2 ms. The studio uses this window only
//! on a CPU adapter; a GPU adapter keeps eframe's swapchain (`likeness studio --present`).
//!
//! This module owns the event loop, egui-winit input and platform output, the offscreen
//! target and its readback, and the app's persisted settings (the same `app.ron` as
//! eframe's window). It must not know the studio: it runs any `eframe::App`.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::frame_damage::{Damage, FrameDamage};
use egui::{ViewportCommand, ViewportId};
use winit::application::ApplicationHandler;
use winit::event::WindowEvent;
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::window::{Window, WindowId};

/// Why the software-presented window stopped or could not start.
#[derive(Debug, thiserror::Error)]
pub enum SoftWindowError {
    #[error("cannot start the window system's event loop")]
    EventLoop(#[from] winit::error::EventLoopError),
    #[error("cannot open the window")]
    Window(#[from] winit::error::OsError),
    /// softbuffer's error, as text: it may hold a platform error that cannot cross threads.
    #[error("cannot show frames in the window: {0}")]
    Present(String),
    #[error("the adapter failed while drawing the window: {0}")]
    Adapter(String),
}

impl From<softbuffer::SoftBufferError> for SoftWindowError {
    fn from(e: softbuffer::SoftBufferError) -> Self {
        Self::Present(e.to_string())
    }
}

/// The texture format the offscreen target uses: softbuffer's pixels are `0x00RRGGBB`
/// words, which in little-endian memory are the bytes B, G, R, (A ignored).
pub const SOFT_WINDOW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Bgra8Unorm;

/// Makes `render_state` draw egui in [`SOFT_WINDOW_FORMAT`], as the software window reads it
/// back. Call before the app registers any texture (the renderer is replaced).
pub fn retarget_for_soft_window(
    render_state: &mut egui_wgpu::RenderState,
    options: egui_wgpu::RendererOptions,
) {
    render_state.target_format = SOFT_WINDOW_FORMAT;
    *render_state.renderer.write() =
        egui_wgpu::Renderer::new(&render_state.device, SOFT_WINDOW_FORMAT, options);
}

/// Runs `create`'s app in a window until it closes. `render_state` must have been passed
/// through [`retarget_for_soft_window`].
pub fn run_soft_window(
    app_id: &str,
    viewport: egui::ViewportBuilder,
    render_state: egui_wgpu::RenderState,
    create: impl FnOnce(&eframe::CreationContext<'_>) -> Box<dyn eframe::App>,
) -> Result<(), SoftWindowError> {
    let event_loop = EventLoop::<RepaintAt>::with_user_event().build()?;
    let ctx = egui::Context::default();
    let proxy = event_loop.create_proxy();
    // Other threads (jobs, writes) and delayed requests ask for a frame through here.
    ctx.set_request_repaint_callback(move |info| {
        // A closed loop has nobody left to wake.
        let _ = proxy.send_event(RepaintAt(Instant::now() + info.delay));
    });
    let storage = RonStorage::open(app_id);
    if let Some(memory) = eframe::get_value::<egui::Memory>(&storage, STORAGE_EGUI_MEMORY_KEY) {
        ctx.memory_mut(|m| *m = memory);
    }
    let app = {
        let mut cc = eframe::CreationContext::_new_kittest(ctx.clone());
        cc.storage = Some(&storage);
        cc.wgpu_render_state = Some(render_state.clone());
        create(&cc)
    };
    let mut frame = eframe::Frame::_new_kittest();
    frame.wgpu_render_state = Some(render_state.clone());
    let mut window = SoftWindow {
        ctx,
        app,
        frame,
        render_state,
        storage,
        viewport,
        shown: None,
        in_flight: None,
        spare: Vec::new(),
        target: None,
        damage: FrameDamage::default(),
        next_repaint: Some(Instant::now()),
        last_save: Instant::now(),
        error: None,
    };
    event_loop.run_app(&mut window)?;
    match window.error {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// A frame wanted at this instant (sent from egui's repaint callback).
#[derive(Debug)]
struct RepaintAt(Instant);

/// eframe's key for egui's memory in `app.ron`, so both windows restore the same state.
const STORAGE_EGUI_MEMORY_KEY: &str = "egui";

struct SoftWindow {
    ctx: egui::Context,
    app: Box<dyn eframe::App>,
    frame: eframe::Frame,
    render_state: egui_wgpu::RenderState,
    storage: RonStorage,
    viewport: egui::ViewportBuilder,
    shown: Option<Shown>,
    /// The frame drawn last, still being drawn or read back while the next one's UI runs.
    in_flight: Option<InFlight>,
    /// Targets whose frames have been shown, for reuse.
    spare: Vec<Readback>,
    target: Option<Target>,
    /// What changed since the frame in `target`.
    damage: FrameDamage,
    next_repaint: Option<Instant>,
    last_save: Instant,
    error: Option<SoftWindowError>,
}

/// The open window and what draws into it.
struct Shown {
    window: Arc<Window>,
    input: egui_winit::State,
    info: egui::ViewportInfo,
    surface: softbuffer::Surface<Arc<Window>, Arc<Window>>,
}

impl SoftWindow {
    fn open(&mut self, event_loop: &ActiveEventLoop) -> Result<(), SoftWindowError> {
        let window = Arc::new(egui_winit::create_window(
            &self.ctx,
            event_loop,
            &self.viewport,
        )?);
        let context = softbuffer::Context::new(window.clone())?;
        let surface = softbuffer::Surface::new(&context, window.clone())?;
        let input = egui_winit::State::new(
            self.ctx.clone(),
            ViewportId::ROOT,
            event_loop,
            Some(window.scale_factor() as f32),
            window.theme(),
            Some(self.render_state.device.limits().max_texture_dimension_2d as usize),
        );
        let mut info = egui::ViewportInfo::default();
        egui_winit::update_viewport_info(&mut info, &self.ctx, &window, true);
        window.request_redraw();
        self.shown = Some(Shown {
            window,
            input,
            info,
            surface,
        });
        Ok(())
    }

    /// One egui pass and its frame on screen; false when the app asked to close.
    fn redraw(&mut self) -> Result<bool, SoftWindowError> {
        let Some(shown) = self.shown.as_mut() else {
            return Ok(true);
        };
        egui_winit::update_viewport_info(&mut shown.info, &self.ctx, &shown.window, false);
        let mut raw_input = shown.input.take_egui_input(&shown.window);
        raw_input.viewports = std::iter::once((ViewportId::ROOT, shown.info.clone())).collect();
        shown.info.events.clear();
        self.app.raw_input_hook(&self.ctx, &mut raw_input);
        let close_requested = raw_input.viewport().close_requested();
        let (app, frame) = (&mut self.app, &mut self.frame);
        let output = self.ctx.run_ui(raw_input, |ui| {
            app.logic(ui.ctx(), frame);
            app.ui(ui, frame);
        });
        shown
            .input
            .handle_platform_output(&shown.window, output.platform_output);
        let mut cancel_close = false;
        let mut animating = false;
        if let Some(viewport) = output.viewport_output.get(&ViewportId::ROOT) {
            cancel_close = viewport.commands.contains(&ViewportCommand::CancelClose);
            // Screenshots, cut/copy/paste requests: nothing in this window asks for them.
            let mut actions = Vec::new();
            egui_winit::process_viewport_commands(
                &self.ctx,
                &mut shown.info,
                viewport.commands.iter().cloned(),
                &shown.window,
                &mut actions,
            );
            if viewport.repaint_delay < Duration::MAX {
                self.schedule(Instant::now() + viewport.repaint_delay);
            }
            animating = viewport.repaint_delay.is_zero();
        }
        let clear = self.app.clear_color(&self.ctx.global_style().visuals);
        let shapes = self.ctx.tessellate(output.shapes, output.pixels_per_point);
        let mut textures = output.textures_delta;
        let painted = self.paint(
            &shapes,
            &textures,
            output.pixels_per_point,
            clear,
            animating,
        );
        // Applied by `paint`, or abandoned with the window on its error; egui checks (in
        // debug builds) that no delta is dropped unapplied.
        textures.clear();
        painted?;
        if self.last_save.elapsed() > self.app.auto_save_interval() {
            self.save();
        }
        // A close asked for in this pass (a command) shows up as an event of the next.
        let close_now = close_requested && !cancel_close;
        if let Some(shown) = &self.shown
            && shown.info.events.contains(&egui::ViewportEvent::Close)
        {
            shown.window.request_redraw();
        }
        Ok(!close_now)
    }

    fn schedule(&mut self, at: Instant) {
        self.next_repaint = Some(self.next_repaint.map_or(at, |t| t.min(at)));
    }

    /// Draws `shapes` offscreen and shows the previous frame while the adapter draws this
    /// one. With `more_coming` (the app animates) this frame stays in flight until the next
    /// call; otherwise it is shown before returning.
    ///
    /// Why in flight: lavapipe draws on its own threads after `submit`, so the UI of the
    /// next frame and the copy of the previous one overlap the drawing instead of waiting
    /// for it (one frame of extra latency while animating, none when idle).
    fn paint(
        &mut self,
        shapes: &[egui::ClippedPrimitive],
        textures: &egui::TexturesDelta,
        pixels_per_point: f32,
        clear: [f32; 4],
        more_coming: bool,
    ) -> Result<(), SoftWindowError> {
        let Some(shown) = self.shown.as_ref() else {
            return Ok(());
        };
        let size = shown.window.inner_size();
        if size.width == 0 || size.height == 0 {
            // Minimised: nothing to show, but textures still change.
            update_textures(&self.render_state, textures);
            self.in_flight = None;
            return Ok(());
        }
        let size = [size.width, size.height];
        let rs = &self.render_state;
        if self.target.as_ref().is_none_or(|t| t.size != size) {
            self.target = Some(Target::new(&rs.device, size));
            self.damage.reset();
        }
        let Some(target) = self.target.as_ref() else {
            return Ok(());
        };
        let mut damage = self
            .damage
            .next(shapes, textures, pixels_per_point, size, clear);
        if clear[3] < 1.0 {
            // A see-through clear colour cannot be painted over the previous frame.
            damage = Damage::Full;
        }
        if damage == Damage::Rects(Vec::new()) {
            // Nothing changed: the window already shows (or is about to show) this frame.
            update_textures(rs, textures);
            free_textures(rs, textures);
            if !more_coming && let Some(frame) = self.in_flight.take() {
                self.show(frame)?;
            }
            return Ok(());
        }
        let drawn = match &damage {
            Damage::Full => None,
            Damage::Rects(rects) => Some(redraw_within(shapes, rects, pixels_per_point, clear)),
        };
        let shapes = drawn.as_deref().unwrap_or(shapes);
        let readback = match self.spare.iter().position(|r| r.size == size) {
            Some(i) => self.spare.swap_remove(i),
            None => Readback::new(&rs.device, size),
        };
        let screen = egui_wgpu::ScreenDescriptor {
            size_in_pixels: size,
            pixels_per_point,
        };
        let mut encoder = rs
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("soft window frame"),
            });
        update_textures(rs, textures);
        let user_commands = {
            let mut renderer = rs.renderer.write();
            let user_commands =
                renderer.update_buffers(&rs.device, &rs.queue, &mut encoder, shapes, &screen);
            let view = target
                .texture
                .create_view(&wgpu::TextureViewDescriptor::default());
            let [r, g, b, a] = clear.map(f64::from);
            let load = match damage {
                Damage::Full => wgpu::LoadOp::Clear(wgpu::Color { r, g, b, a }),
                // The damaged rectangles clear themselves (`redraw_within`).
                Damage::Rects(_) => wgpu::LoadOp::Load,
            };
            let mut pass = encoder
                .begin_render_pass(&wgpu::RenderPassDescriptor {
                    label: Some("soft window egui"),
                    color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                        view: &view,
                        resolve_target: None,
                        depth_slice: None,
                        ops: wgpu::Operations {
                            load,
                            store: wgpu::StoreOp::Store,
                        },
                    })],
                    ..Default::default()
                })
                .forget_lifetime();
            renderer.render(&mut pass, shapes, &screen);
            user_commands
        };
        readback.copy(target, &mut encoder);
        let submission = rs
            .queue
            .submit(user_commands.into_iter().chain([encoder.finish()]));
        free_textures(rs, textures);
        let frame = InFlight::start(readback, submission);
        if let Some(previous) = self.in_flight.replace(frame) {
            self.show(previous)?;
        }
        if !more_coming && let Some(frame) = self.in_flight.take() {
            self.show(frame)?;
        }
        Ok(())
    }

    /// Waits for `frame`'s pixels and puts them on screen.
    fn show(&mut self, frame: InFlight) -> Result<(), SoftWindowError> {
        let Some(shown) = self.shown.as_mut() else {
            return Ok(());
        };
        let readback = frame.wait(&self.render_state.device)?;
        let [width, height] = readback
            .size
            .map(|n| std::num::NonZeroU32::new(n).unwrap_or(std::num::NonZeroU32::MIN));
        shown.surface.resize(width, height)?;
        let mut buffer = shown.surface.buffer_mut()?;
        readback.read_into(&mut buffer)?;
        buffer.present()?;
        // Two are enough: one in flight, one being shown.
        self.spare.retain(|r| r.size == readback.size);
        if self.spare.len() < 2 {
            self.spare.push(readback);
        }
        Ok(())
    }

    /// What eframe saves: the app's state and egui's memory, to `app.ron`.
    fn save(&mut self) {
        if self.app.persist_egui_memory() {
            let storage = &mut self.storage;
            self.ctx
                .memory(|m| eframe::set_value(storage, STORAGE_EGUI_MEMORY_KEY, m));
        }
        self.app.save(&mut self.storage);
        eframe::Storage::flush(&mut self.storage);
        self.last_save = Instant::now();
    }

    /// Ends the loop; [`run_soft_window`] returns the first error.
    fn fail(&mut self, event_loop: &ActiveEventLoop, error: SoftWindowError) {
        self.error.get_or_insert(error);
        event_loop.exit();
    }
}

fn free_textures(rs: &egui_wgpu::RenderState, textures: &egui::TexturesDelta) {
    let mut renderer = rs.renderer.write();
    for id in &textures.free {
        renderer.free_texture(id);
    }
}

/// What to draw over the previous frame so that `rects` (physical pixels) show this one:
/// per rectangle, the clear colour, then every primitive that reaches into it, clipped to
/// it, in painting order.
fn redraw_within(
    shapes: &[egui::ClippedPrimitive],
    rects: &[egui::Rect],
    pixels_per_point: f32,
    clear: [f32; 4],
) -> Vec<egui::ClippedPrimitive> {
    // The clear colour as the bytes LoadOp::Clear would store (gamma-space, opaque or not).
    let [r, g, b, a] = clear.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8);
    let background = egui::Color32::from_rgba_premultiplied(r, g, b, a);
    let mut drawn = Vec::new();
    for rect in rects {
        let area = *rect / pixels_per_point;
        let mut clear_mesh = egui::epaint::Mesh::default();
        clear_mesh.add_colored_rect(area, background);
        drawn.push(egui::ClippedPrimitive {
            clip_rect: area,
            primitive: egui::epaint::Primitive::Mesh(clear_mesh),
        });
        for shape in shapes {
            let clip = shape.clip_rect.intersect(area);
            let reaches = match &shape.primitive {
                egui::epaint::Primitive::Mesh(mesh) => mesh.calc_bounds().intersects(clip),
                egui::epaint::Primitive::Callback(callback) => callback.rect.intersects(clip),
            };
            if clip.is_positive() && reaches {
                drawn.push(egui::ClippedPrimitive {
                    clip_rect: clip,
                    primitive: shape.primitive.clone(),
                });
            }
        }
    }
    drawn
}

fn update_textures(rs: &egui_wgpu::RenderState, textures: &egui::TexturesDelta) {
    let mut renderer = rs.renderer.write();
    for (id, deltas) in &textures.set {
        for delta in deltas {
            renderer.update_texture(&rs.device, &rs.queue, *id, delta);
        }
    }
}

impl ApplicationHandler<RepaintAt> for SoftWindow {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.shown.is_none()
            && let Err(e) = self.open(event_loop)
        {
            self.fail(event_loop, e);
        }
    }

    fn user_event(&mut self, _event_loop: &ActiveEventLoop, RepaintAt(at): RepaintAt) {
        self.schedule(at);
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _id: WindowId, event: WindowEvent) {
        let Some(shown) = self.shown.as_mut() else {
            return;
        };
        match &event {
            WindowEvent::RedrawRequested => {
                match self.redraw() {
                    Ok(true) => {}
                    Ok(false) => event_loop.exit(),
                    Err(e) => self.fail(event_loop, e),
                }
                return;
            }
            // As eframe does: the app sees the request in its next pass and may cancel it.
            WindowEvent::CloseRequested => {
                shown.info.events.push(egui::ViewportEvent::Close);
                shown.window.request_redraw();
            }
            WindowEvent::Resized(_) | WindowEvent::ScaleFactorChanged { .. } => {
                shown.window.request_redraw();
            }
            _ => {}
        }
        if shown.input.on_window_event(&shown.window, &event).repaint {
            shown.window.request_redraw();
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        match self.next_repaint {
            Some(at) if at <= Instant::now() => {
                self.next_repaint = None;
                if let Some(shown) = &self.shown {
                    shown.window.request_redraw();
                }
                event_loop.set_control_flow(ControlFlow::Wait);
            }
            Some(at) => event_loop.set_control_flow(ControlFlow::WaitUntil(at)),
            None => event_loop.set_control_flow(ControlFlow::Wait),
        }
    }

    fn exiting(&mut self, _event_loop: &ActiveEventLoop) {
        self.save();
        self.app.on_exit();
    }
}

/// The offscreen picture of the window. It is kept from frame to frame: a frame redraws
/// only what changed ([`crate::frame_damage`]) over the previous one.
struct Target {
    size: [u32; 2],
    texture: wgpu::Texture,
}

impl Target {
    fn new(device: &wgpu::Device, size: [u32; 2]) -> Self {
        let texture = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("soft window target"),
            size: wgpu::Extent3d {
                width: size[0],
                height: size[1],
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: SOFT_WINDOW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        Self { size, texture }
    }
}

/// A buffer the target's pixels are copied into for the CPU.
struct Readback {
    size: [u32; 2],
    buffer: wgpu::Buffer,
    /// Bytes per row in `buffer`: wgpu copies rows at 256-byte strides.
    padded_row_bytes: u32,
}

impl Readback {
    fn new(device: &wgpu::Device, size: [u32; 2]) -> Self {
        let padded_row_bytes = (size[0] * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
        let buffer = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("soft window readback"),
            size: u64::from(padded_row_bytes) * u64::from(size[1]),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        Self {
            size,
            buffer,
            padded_row_bytes,
        }
    }

    fn copy(&self, target: &Target, encoder: &mut wgpu::CommandEncoder) {
        encoder.copy_texture_to_buffer(
            target.texture.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &self.buffer,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row_bytes),
                    rows_per_image: None,
                },
            },
            wgpu::Extent3d {
                width: self.size[0],
                height: self.size[1],
                depth_or_array_layers: 1,
            },
        );
    }

    /// Writes the mapped frame into `pixels` (`0x00RRGGBB` words, row-major, `size[0]` per
    /// row) and unmaps the buffer for its next use.
    fn read_into(&self, pixels: &mut [u32]) -> Result<(), SoftWindowError> {
        {
            let mapped = self
                .buffer
                .slice(..)
                .get_mapped_range()
                .map_err(|e| SoftWindowError::Adapter(e.to_string()))?;
            bgra_rows_to_words(
                &mapped,
                self.padded_row_bytes as usize,
                self.size[0] as usize,
                pixels,
            );
        }
        self.buffer.unmap();
        Ok(())
    }
}

/// A submitted frame whose readback buffer is being mapped.
struct InFlight {
    readback: Readback,
    submission: wgpu::SubmissionIndex,
    mapped: std::sync::mpsc::Receiver<Result<(), wgpu::BufferAsyncError>>,
}

impl InFlight {
    fn start(readback: Readback, submission: wgpu::SubmissionIndex) -> Self {
        let (sender, mapped) = std::sync::mpsc::channel();
        readback
            .buffer
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |r| {
                // The receiver is gone only if the frame was dropped (window minimised).
                let _ = sender.send(r);
            });
        Self {
            readback,
            submission,
            mapped,
        }
    }

    /// Blocks until this frame (not any later one) is drawn and mapped.
    fn wait(self, device: &wgpu::Device) -> Result<Readback, SoftWindowError> {
        let adapter_error = |e: &dyn std::fmt::Display| SoftWindowError::Adapter(e.to_string());
        device
            .poll(wgpu::PollType::Wait {
                submission_index: Some(self.submission),
                timeout: None,
            })
            .map_err(|e| adapter_error(&e))?;
        self.mapped
            .recv()
            .map_err(|e| adapter_error(&e))?
            .map_err(|e| adapter_error(&e))?;
        Ok(self.readback)
    }
}

/// Copies rows of BGRA bytes (`stride` bytes apart) into `0x00RRGGBB` words, `width` per row.
/// The byte order is the word's in little-endian memory, so there it is a plain copy.
fn bgra_rows_to_words(bgra: &[u8], stride: usize, width: usize, words: &mut [u32]) {
    for (row, out) in bgra.chunks(stride).zip(words.chunks_mut(width)) {
        let row = &row[..(width * 4).min(row.len())];
        for (px, word) in row.chunks_exact(4).zip(out.iter_mut()) {
            *word = u32::from_le_bytes([px[0], px[1], px[2], 0]);
        }
    }
}

/// eframe's persisted key-value store, read from and written to the same `app.ron`, so the
/// studio keeps its settings whichever window shows it. Written whole to a temporary file
/// and renamed, so a crash mid-write leaves the previous settings.
struct RonStorage {
    path: Option<PathBuf>,
    values: HashMap<String, String>,
    dirty: bool,
}

impl RonStorage {
    fn open(app_id: &str) -> Self {
        let path = eframe::storage_dir(app_id).map(|dir| dir.join("app.ron"));
        let values = path
            .as_ref()
            .and_then(|p| match std::fs::read_to_string(p) {
                Ok(text) => match ron::from_str(&text) {
                    Ok(values) => Some(values),
                    Err(e) => {
                        tracing::warn!("ignoring unreadable settings {}: {e}", p.display());
                        None
                    }
                },
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => None,
                Err(e) => {
                    tracing::warn!("cannot read settings {}: {e}", p.display());
                    None
                }
            })
            .unwrap_or_default();
        Self {
            path,
            values,
            dirty: false,
        }
    }

    fn write(&self) -> Result<(), String> {
        let Some(path) = &self.path else {
            return Err("no folder for settings on this system".into());
        };
        let text = ron::ser::to_string_pretty(&self.values, ron::ser::PrettyConfig::default())
            .map_err(|e| e.to_string())?;
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
        }
        files::write_atomically(path, text.as_bytes()).map_err(|e| e.to_string())
    }
}

impl eframe::Storage for RonStorage {
    fn get_string(&self, key: &str) -> Option<String> {
        self.values.get(key).cloned()
    }

    fn set_string(&mut self, key: &str, value: String) {
        if self.values.get(key) != Some(&value) {
            self.values.insert(key.to_owned(), value);
            self.dirty = true;
        }
    }

    fn remove_string(&mut self, key: &str) {
        self.dirty |= self.values.remove(key).is_some();
    }

    fn flush(&mut self) {
        if !self.dirty {
            return;
        }
        match self.write() {
            Ok(()) => self.dirty = false,
            Err(e) => tracing::warn!("settings not saved: {e}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bgra_rows_become_xrgb_words_without_the_row_padding() {
        // Two rows of two pixels, each row padded to 12 bytes.
        let bgra = [
            0x10, 0x20, 0x30, 0xff, 0x11, 0x21, 0x31, 0xff, 9, 9, 9, 9, //
            0x12, 0x22, 0x32, 0x80, 0x13, 0x23, 0x33, 0x00, 9, 9, 9, 9,
        ];
        let mut words = [0u32; 4];
        bgra_rows_to_words(&bgra, 12, 2, &mut words);
        assert_eq!(words, [0x302010, 0x312111, 0x322212, 0x332313]);
    }
}
