//! The studio window: a 3D view of the face with an orbit camera, the 53 blendshape sliders
//! (searchable), a view-mode switch and the frame time.

use std::path::PathBuf;
use std::sync::Arc;
use web_time::Instant;

use face::{ICT_NAMES, NUM_BLENDSHAPES};
use renderer::FaceRenderer;

use crate::blendshape_panel::BlendshapePanel;
use crate::footage::{FootageJob, FootageRequest};
use crate::gpu_view::{VIEW_FORMAT, ViewTarget, available_pixels, orbit_input, template_options};
use crate::overlay_view::OverlayView;
use crate::puppet_panel::{DriveTarget, PersonTarget};
use crate::scene::{Orbit, Scene, StudioView, demo_weights, frame_params};
use crate::settings::{RecentFile, SETTINGS_KEY, Settings, autosave_path, with_session_extension};
use crate::studio_panels::{PlaybackState, fit_rect, list_rows, paint_overlay, timeline_ui};
use crate::studio_session::StudioSession;

/// The studio's main panels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Panel {
    /// The 3D face with the blendshape sliders.
    Face,
    /// The input frame with the tracking overlay.
    Input,
    /// The 53 blendshapes with the person's corrections: template beside personalized,
    /// the correction heatmap in mm or the attention mask.
    Blendshapes,
    /// The learned maps in UV space: albedo, dynamic albedo, masks, shape corrections.
    Maps,
    /// The frame's lighting on a sphere and the weight curves over time.
    Motion,
    /// The performance retargeted onto a puppet or another person, with the mapping editor.
    Puppet,
}

/// The studio's state, separate from GPU resources so tests can inspect it.
pub struct StudioState {
    pub weights: [f32; NUM_BLENDSHAPES],
    pub filter: String,
    pub view: StudioView,
    /// The blendshape whose mask the mask view shows.
    pub selected: usize,
    pub orbit: Orbit,
    /// Drive the weights from the scripted expression loop.
    pub playing_demo: bool,
    pub demo_time_secs: f64,
    /// Last frame's CPU time for building and submitting the 3D view, in milliseconds.
    pub frame_time_ms: f32,
    /// Time between the last two frames, in milliseconds.
    pub frame_interval_ms: f32,
    /// Show the timings in the toolbar (off in snapshot tests, where they would differ run
    /// to run).
    pub show_timings: bool,
    /// Errors (kept until dismissed) and messages (a save, a finished job), shown as
    /// toasts.
    pub notices: crate::notices::Notices,
    pub panel: Panel,
    pub playback: PlaybackState,
}

impl Default for StudioState {
    fn default() -> Self {
        Self {
            weights: [0.0; NUM_BLENDSHAPES],
            filter: String::new(),
            view: StudioView::Shaded,
            selected: face::names::ict_index("jawOpen").unwrap_or(0),
            orbit: Orbit::default(),
            playing_demo: true,
            demo_time_secs: 0.0,
            frame_time_ms: 0.0,
            frame_interval_ms: 0.0,
            show_timings: true,
            notices: crate::notices::Notices::default(),
            panel: Panel::Face,
            playback: PlaybackState::default(),
        }
    }
}

/// GPU side of the 3D view: the face renderer and the texture egui shows.
struct Viewport {
    face: FaceRenderer,
    target: ViewTarget,
    /// The blendshape whose mask A_i is on the GPU, so it is uploaded once per selection,
    /// not every frame.
    uploaded_mask: Option<usize>,
}

pub struct StudioApp {
    pub state: StudioState,
    scene: Arc<Scene>,
    viewport: Option<Viewport>,
    session: Option<Arc<StudioSession>>,
    /// The input frame on the GPU, with the index it shows.
    frame_texture: Option<(usize, egui::TextureHandle)>,
    pub uv_panel: crate::uv_panel::UvPanel,
    pub motion_panel: crate::motion_panel::MotionPanel,
    pub blendshape_panel: BlendshapePanel,
    pub puppet_panel: crate::puppet_panel::PuppetPanel,
    pub overlay: OverlayView,
    pub settings: Settings,
    /// Where the session was last opened from or saved to.
    pub session_path: Option<PathBuf>,
    /// Where a processed session is autosaved ([`autosave_path`] unless a test moves it).
    pub autosave_path: PathBuf,
    job: Option<FootageJob>,
    /// The running job's newest tracked frame.
    job_preview: Option<JobPreview>,
    /// Files being written on their own threads: saves, the autosave, exports.
    writes: Vec<(WriteKind, crate::background::BackgroundWrite)>,
    /// `studio --measure-fps`: times the window's frames, then closes it.
    pub fps_probe: Option<crate::fps_probe::FpsProbe>,
    /// The window is cleared to the panel colour before egui paints ([`eframe::App::clear_color`]),
    /// so the studio paints no background of its own. On a software rasteriser every
    /// full-window fill costs several milliseconds, so the native window saves one per
    /// frame; a headless renderer (kittest clears to transparent) leaves this off and gets
    /// one background rectangle instead of one fill per panel.
    pub window_cleared_to_panel_colour: bool,
    /// The window draws on a software rasteriser (no GPU): by default it draws shapes
    /// without anti-aliased edges (see
    /// [`StudioApp::smooth_edges`]). Set by the native window; headless pictures keep the
    /// full drawing.
    pub window_on_cpu_adapter: bool,
    /// The shape drawing last applied to the egui context.
    applied_smooth_edges: Option<bool>,
    /// The page the studio runs in, in a browser (files, downloads, video, camera).
    pub web_host: Option<std::rc::Rc<dyn crate::web_host::WebHost>>,
    /// The built-in demo being made a slice per frame (the browser; natively it is made
    /// before the window opens).
    demo_job: Option<crate::demo::SteppedDemo>,
    /// The rate the last demo or footage was tracked at in steps, for the page to report.
    pub tracking_rate: Option<crate::stepped::TrackingRate>,
    /// The video file the page is decoding for a footage job.
    decoding_video: Option<String>,
}

fn frame_image(frame: &image::RgbImage) -> egui::ColorImage {
    let size = [frame.width() as usize, frame.height() as usize];
    egui::ColorImage::from_rgb(size, frame.as_raw())
}

fn new_frame_texture(
    ctx: &egui::Context,
    name: &str,
    frame: &image::RgbImage,
) -> egui::TextureHandle {
    ctx.load_texture(name, frame_image(frame), egui::TextureOptions::LINEAR)
}

/// Shows `frame` in `texture`: overwritten in place when the size is unchanged (every frame
/// of a clip), since a whole `set` makes egui-wgpu allocate a new GPU texture each time.
fn upload_frame(
    ctx: &egui::Context,
    texture: &mut egui::TextureHandle,
    name: &str,
    frame: &image::RgbImage,
) {
    let image = frame_image(frame);
    if texture.size() == image.size {
        texture.set_partial([0, 0], image, egui::TextureOptions::LINEAR);
    } else {
        *texture = ctx.load_texture(name, image, egui::TextureOptions::LINEAR);
    }
}

/// A running job's newest tracked frame, uploaded for its panel.
pub struct JobPreview {
    /// How many frames the job had seen at this one.
    pub seen: usize,
    /// The frame's size in pixels.
    pub size: [u32; 2],
    texture: egui::TextureHandle,
    pub overlay: crate::studio_session::FrameOverlay,
}

/// What a background write was, for what its end changes in the studio.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum WriteKind {
    Session,
    Autosave,
    Export,
}

impl StudioApp {
    pub fn new(cc: &eframe::CreationContext<'_>, scene: Arc<Scene>) -> Self {
        let mut app = Self {
            state: StudioState::default(),
            scene,
            viewport: None,
            session: None,
            frame_texture: None,
            uv_panel: crate::uv_panel::UvPanel::default(),
            motion_panel: crate::motion_panel::MotionPanel::default(),
            blendshape_panel: BlendshapePanel::default(),
            puppet_panel: crate::puppet_panel::PuppetPanel::default(),
            overlay: OverlayView::default(),
            settings: Settings::default(),
            session_path: None,
            autosave_path: autosave_path(),
            job: None,
            job_preview: None,
            writes: Vec::new(),
            fps_probe: None,
            window_cleared_to_panel_colour: false,
            window_on_cpu_adapter: false,
            applied_smooth_edges: None,
            web_host: None,
            demo_job: None,
            tracking_rate: None,
            decoding_video: None,
        };
        if let Some(storage) = cc.storage {
            let settings = eframe::get_value::<Settings>(storage, SETTINGS_KEY)
                .unwrap_or_default()
                .sanitized();
            app.apply_settings(settings);
        }
        match cc.wgpu_render_state.as_ref() {
            Some(rs) => match FaceRenderer::with_options(
                &rs.device,
                &rs.queue,
                VIEW_FORMAT,
                template_options(rs),
                &app.scene.mesh,
                &app.scene.textures,
            ) {
                Ok(face) => {
                    app.viewport = Some(Viewport {
                        face,
                        target: ViewTarget::default(),
                        uploaded_mask: None,
                    })
                }
                Err(e) => app.state.notices.error(format!("3D view unavailable: {e}")),
            },
            None => app
                .state
                .notices
                .error("3D view unavailable: eframe is not running on wgpu"),
        }
        app
    }

    /// Shows a tracked session: the input panel, the timeline, and the face replaying the
    /// tracked weights.
    pub fn with_session(mut self, session: Arc<StudioSession>) -> Self {
        self.set_session(session);
        self
    }

    /// Restores what the studio remembered from the last run.
    pub fn apply_settings(&mut self, settings: Settings) {
        self.overlay.opacity = settings.overlay_opacity;
        let p = &mut self.state.playback;
        p.show_detected = settings.show_detected;
        p.show_model = settings.show_model;
        p.show_boxes = settings.show_boxes;
        self.puppet_panel.export_dir = settings.export_dir.clone();
        if let Some(path) = settings.puppet.as_ref().filter(|p| p.is_file())
            && let Err(e) = self.puppet_panel.load(path)
        {
            tracing::warn!("the last puppet could not be loaded again: {e:#}");
        }
        self.settings = settings;
    }

    /// The settings as they are now.
    pub fn current_settings(&self) -> Settings {
        let p = &self.state.playback;
        Settings {
            overlay_opacity: self.overlay.opacity,
            show_detected: p.show_detected,
            show_model: p.show_model,
            show_boxes: p.show_boxes,
            export_dir: self.puppet_panel.export_dir.clone(),
            puppet: self
                .puppet_panel
                .puppet
                .as_ref()
                .map(|p| p.path.clone())
                .filter(|p| p.as_path() != std::path::Path::new(crate::puppet_panel::DEMO_PUPPET)),
            ..self.settings.clone()
        }
    }

    /// Opens a session file in place of the current session.
    pub fn open_session(&mut self, path: &std::path::Path) {
        let recent = RecentFile::Session(path.to_owned());
        match StudioSession::load(&self.scene.model, path) {
            Ok(session) => {
                self.state.notices.message(format!(
                    "opened {} ({} frames)",
                    path.display(),
                    session.frame_count()
                ));
                self.set_session(Arc::new(session));
                self.session_path = Some(path.to_owned());
                self.settings.remember(recent);
            }
            Err(e) => {
                self.settings.forget(&recent);
                self.state.notices.error(e);
            }
        }
    }

    /// Saves the session (atomically) to `path`.
    pub fn save_session(&mut self, path: &std::path::Path) {
        let Some(session) = self.session.clone() else {
            self.state.notices.error("there is no session to save");
            return;
        };
        let path = with_session_extension(path);
        self.start_write(WriteKind::Session, "session", move || {
            session.save(&path).map(|()| path)
        });
    }

    /// Starts a background write; its end is reported by [`Self::poll_writes`].
    fn start_write(
        &mut self,
        kind: WriteKind,
        what: &str,
        job: impl FnOnce() -> Result<PathBuf, String> + Send + 'static,
    ) {
        match crate::background::BackgroundWrite::spawn(what, job) {
            Ok(write) => self.writes.push((kind, write)),
            Err(e) => self.state.notices.error(e),
        }
    }

    /// Whether a save, autosave or export is still being written.
    pub fn writes_pending(&self) -> bool {
        !self.writes.is_empty()
    }

    /// Reports the background writes that ended: saved sessions become the current
    /// session file and a recent file, exports show in the puppet panel.
    fn poll_writes(&mut self, ctx: &egui::Context) {
        let mut running = Vec::with_capacity(self.writes.len());
        for (kind, write) in std::mem::take(&mut self.writes) {
            let Some(result) = write.poll() else {
                running.push((kind, write));
                continue;
            };
            match (kind, result) {
                (WriteKind::Session, Ok(path)) => {
                    self.state
                        .notices
                        .message(format!("saved {}", path.display()));
                    self.settings.remember(RecentFile::Session(path.clone()));
                    self.session_path = Some(path);
                }
                (WriteKind::Autosave, Ok(path)) => tracing::info!("autosaved {}", path.display()),
                (WriteKind::Export, Ok(path)) => {
                    self.puppet_panel.status = Some(format!("wrote {}", path.display()));
                }
                (_, Err(e)) => self.state.notices.error(e),
            }
        }
        self.writes = running;
        if !self.writes.is_empty() {
            // Nothing else may repaint while a write runs; look again shortly.
            ctx.request_repaint_after(std::time::Duration::from_millis(50));
        }
    }

    /// Person B for the puppet panel from a session file: their own blendshapes and
    /// dynamic albedo, driven by this session's tracking.
    pub fn load_person_b(&mut self, path: &std::path::Path) {
        match StudioSession::load(&self.scene.model, path) {
            Ok(person) => {
                let mut target = PersonTarget::from_session(&person);
                target.name = format!("person B: {}", path.display());
                self.puppet_panel.person = Some(Arc::new(target));
                self.puppet_panel.drive = DriveTarget::Person;
                if self.session.is_some() {
                    self.state.panel = Panel::Puppet;
                }
            }
            Err(e) => self.state.notices.error(e),
        }
    }

    /// Starts writing the autosave of `session` on its own thread.
    fn start_autosave(&mut self, session: Arc<StudioSession>) {
        if self.web_host.is_some() {
            // A page has nowhere to autosave; File > Save session downloads the session.
            return;
        }
        let path = self.autosave_path.clone();
        self.start_write(WriteKind::Autosave, "autosave", move || {
            if let Some(Err(e)) = path.parent().map(std::fs::create_dir_all) {
                return Err(format!("autosave: cannot create {}: {e}", path.display()));
            }
            session.save(&path).map(|()| path)
        });
    }

    /// Replaces the session (the puppet, its mapping and person B stay).
    pub fn set_session(&mut self, session: Arc<StudioSession>) {
        self.session = Some(session);
        self.frame_texture = None;
        self.uv_panel.clear();
        self.blendshape_panel.clear();
        self.overlay.clear();
        self.state.playback = PlaybackState {
            playing: true,
            ..PlaybackState::default()
        };
        self.state.playing_demo = false;
        self.state.panel = Panel::Input;
    }

    /// Starts tracking and personalizing footage (an image, a folder, a video file or
    /// `webcam[:DEVICE]`) on a worker thread; the session replaces the current one when
    /// it is done.
    /// Whether File > Face locator offers MediaPipe's: always natively (a missing model is
    /// said when footage is opened), in the browser when the page served its models.
    fn mediapipe_offered(&self) -> bool {
        cfg!(not(target_arch = "wasm32"))
            || self
                .scene
                .networks
                .as_ref()
                .is_some_and(|n| n.mediapipe.is_some())
    }

    /// The locator footage is opened with: the chosen one, or OpenSeeFace's where
    /// MediaPipe's is not offered (a setting saved where it was).
    fn face_locator_choice(&self) -> tracking::pipeline::LocatorChoice {
        let chosen = self.settings.face_locator;
        if chosen == crate::settings::FaceLocator::MediaPipe && !self.mediapipe_offered() {
            crate::settings::FaceLocator::OpenSeeFace.choice()
        } else {
            chosen.choice()
        }
    }

    pub fn open_footage(&mut self, ctx: &egui::Context, input: &str) {
        if let Some(job) = &self.job {
            self.state.notices.error(format!(
                "still processing {}: cancel it before opening {input}",
                job.input
            ));
            return;
        }
        let ctx = ctx.clone();
        let request = FootageRequest {
            locator: self.face_locator_choice(),
            ..FootageRequest::new(input)
        };
        match FootageJob::start(self.scene.clone(), request, move || ctx.request_repaint()) {
            Ok(job) => {
                self.job = Some(job);
                self.settings
                    .remember(RecentFile::Footage(input.to_owned()));
            }
            Err(e) => self.state.notices.error(format!("{e:#}")),
        }
    }

    /// The running footage job, if any.
    pub fn job(&self) -> Option<&FootageJob> {
        self.job.as_ref()
    }

    /// The running job's newest tracked frame, as its panel shows it.
    pub fn job_preview(&self) -> Option<&JobPreview> {
        self.job_preview.as_ref()
    }

    /// Shows the job's newest tracked frame; takes a finished job's session or error.
    fn poll_job(&mut self, ctx: &egui::Context) {
        if let Some(frame) = self.job.as_ref().and_then(FootageJob::take_preview) {
            let size = [frame.image.width(), frame.image.height()];
            match &mut self.job_preview {
                Some(shown) => {
                    upload_frame(ctx, &mut shown.texture, "job preview", &frame.image);
                    shown.seen = frame.seen;
                    shown.size = size;
                    shown.overlay = frame.overlay;
                }
                None => {
                    self.job_preview = Some(JobPreview {
                        seen: frame.seen,
                        size,
                        texture: new_frame_texture(ctx, "job preview", &frame.image),
                        overlay: frame.overlay,
                    });
                }
            }
        }
        let Some(result) = self.job.as_mut().and_then(FootageJob::poll) else {
            return;
        };
        self.job_preview = None;
        let input = self.job.take().map(|j| j.input.clone()).unwrap_or_default();
        if let Some(host) = &self.web_host {
            // A recording has ended (or another job, which leaves the camera off).
            host.stop_camera();
        }
        match result {
            Ok(session) => {
                self.state.notices.message(format!(
                    "{input}: {} frames tracked and personalized (File > Save session keeps it)",
                    session.frame_count()
                ));
                let session: Arc<StudioSession> = Arc::from(session);
                self.set_session(session.clone());
                self.session_path = None;
                self.start_autosave(session);
            }
            Err(e) if e.ends_with("cancelled") => {
                self.state.notices.message(format!("{input}: cancelled"));
            }
            Err(e) => self.state.notices.error(e),
        }
    }

    /// The progress of the footage job with its cancel button.
    fn job_ui(&mut self, ui: &mut egui::Ui) {
        let Some(job) = &self.job else {
            return;
        };
        let p = &job.progress;
        let (fraction, text) = match p.total {
            Some(total) if total > 0 => (
                p.done as f32 / total as f32,
                format!("{}: {} / {total} frames", p.stage, p.done),
            ),
            _ if p.done > 0 => (0.0, format!("{}: {} frames", p.stage, p.done)),
            _ => (0.0, p.stage.to_string()),
        };
        let live = job.input.starts_with("webcam") || job.input.starts_with("ffmpeg:");
        let cancel = if live { "Stop recording" } else { "Cancel" };
        let cancelling = job.cancelling();
        ui.horizontal(|ui| {
            if let Some(preview) = &self.job_preview {
                // The live view: the newest tracked frame with what was found in it.
                let height = 180.0;
                let width = height * preview.size[0] as f32 / preview.size[1].max(1) as f32;
                let (rect, _) =
                    ui.allocate_exact_size(egui::vec2(width, height), egui::Sense::hover());
                ui.painter().image(
                    preview.texture.id(),
                    rect,
                    egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
                    egui::Color32::WHITE,
                );
                crate::studio_panels::paint_overlay(
                    ui.painter(),
                    rect,
                    preview.size,
                    &preview.overlay,
                    &self.state.playback,
                );
            }
            ui.label(&job.input);
            ui.add(
                egui::ProgressBar::new(fraction.clamp(0.0, 1.0))
                    .desired_width(360.0)
                    .text(text)
                    .animate(p.total.is_none()),
            );
            if ui
                .add_enabled(!cancelling, egui::Button::new(cancel))
                .clicked()
            {
                job.cancel();
            }
        });
    }

    /// The File menu: footage in.
    fn file_menu_ui(&mut self, ui: &mut egui::Ui) {
        ui.menu_button("File", |ui| {
            #[cfg(target_arch = "wasm32")]
            if ui
                .button("Open images, video, puppet or session...")
                .clicked()
            {
                ui.close();
                self.pick_files();
            }
            #[cfg(not(target_arch = "wasm32"))]
            if ui.button("Open image or video...").clicked() {
                ui.close();
                if let Some(path) = rfd::FileDialog::new()
                    .add_filter(
                        "Images and videos",
                        &[
                            "png", "jpg", "jpeg", "bmp", "webp", "tif", "tiff", "mp4", "mov",
                            "mkv", "avi", "webm", "m4v",
                        ],
                    )
                    .add_filter("All files", &["*"])
                    .pick_file()
                {
                    self.open_footage(ui.ctx(), &path.display().to_string());
                }
            }
            #[cfg(not(target_arch = "wasm32"))]
            if ui.button("Open folder of images...").clicked() {
                ui.close();
                if let Some(path) = rfd::FileDialog::new().pick_folder() {
                    self.open_footage(ui.ctx(), &path.display().to_string());
                }
            }
            if ui
                .button("Record from webcam")
                .on_hover_text("Records until Stop recording (at most 600 frames)")
                .clicked()
            {
                ui.close();
                self.open_webcam(ui.ctx());
            }
            if self.mediapipe_offered() {
                ui.menu_button("Face locator", |ui| {
                    use crate::settings::FaceLocator;
                    for locator in [FaceLocator::OpenSeeFace, FaceLocator::MediaPipe] {
                        ui.radio_value(&mut self.settings.face_locator, locator, locator.label())
                            .on_hover_text("Used for footage opened from now on");
                    }
                });
            }
            ui.separator();
            #[cfg(not(target_arch = "wasm32"))]
            if ui.button("Open session...").clicked() {
                ui.close();
                self.open_session_dialog();
            }
            let has_session = self.session.is_some();
            if ui
                .add_enabled(has_session, egui::Button::new("Save session"))
                .on_hover_text("Ctrl+S")
                .clicked()
            {
                ui.close();
                self.save_session_shortcut();
            }
            if ui
                .add_enabled(has_session, egui::Button::new("Save session as..."))
                .clicked()
            {
                ui.close();
                self.save_session_dialog();
            }
            #[cfg(not(target_arch = "wasm32"))]
            ui.menu_button("Recent", |ui| {
                if self.settings.recent.is_empty() {
                    ui.label("Nothing opened yet");
                }
                for file in self.settings.recent.clone() {
                    if ui.button(file.label()).clicked() {
                        ui.close();
                        match file {
                            RecentFile::Session(path) => self.open_session(&path),
                            RecentFile::Footage(input) => self.open_footage(ui.ctx(), &input),
                        }
                    }
                }
            });
            #[cfg(not(target_arch = "wasm32"))]
            let autosave = self.autosave_path.clone();
            #[cfg(not(target_arch = "wasm32"))]
            if ui
                .add_enabled(
                    autosave.is_file(),
                    egui::Button::new("Recover the last processed session"),
                )
                .on_hover_text(autosave.display().to_string())
                .clicked()
            {
                ui.close();
                self.open_session(&autosave);
            }
            ui.separator();
            let mut smooth = self.smooth_edges();
            if ui
                .checkbox(&mut smooth, "Smooth shape edges")
                .on_hover_text(
                    "Anti-aliased shapes; off by default without a \
                     GPU, where they cost much of each frame",
                )
                .changed()
            {
                self.settings.smooth_edges = Some(smooth);
            }
            let mut reduce = self.reduce_3d_while_playing();
            if ui
                .checkbox(&mut reduce, "Half-size 3D view while playing")
                .on_hover_text(
                    "The puppet view is rendered at half width and height while a clip \
                     plays and sharp when paused; on by default without a GPU",
                )
                .changed()
            {
                self.settings.reduce_3d_while_playing = Some(reduce);
            }
            #[cfg(not(target_arch = "wasm32"))]
            ui.separator();
            #[cfg(not(target_arch = "wasm32"))]
            if ui
                .button("Load person B from a session...")
                .on_hover_text("Drive another person's own blendshapes and dynamic albedo")
                .clicked()
            {
                ui.close();
                if let Some(path) = session_dialog().pick_file() {
                    self.load_person_b(&path);
                }
            }
        });
    }

    #[cfg(not(target_arch = "wasm32"))]
    fn open_session_dialog(&mut self) {
        if let Some(path) = session_dialog().pick_file() {
            self.open_session(&path);
        }
    }

    #[cfg(not(target_arch = "wasm32"))]
    fn save_session_dialog(&mut self) {
        if let Some(path) = session_dialog()
            .set_file_name("person.likeness")
            .save_file()
        {
            self.save_session(&path);
        }
    }

    /// In the browser a saved session is a download.
    #[cfg(target_arch = "wasm32")]
    fn save_session_dialog(&mut self) {
        let Some(session) = self.session.clone() else {
            self.state.notices.error("there is no session to save");
            return;
        };
        let Some(host) = self.web_host.clone() else {
            self.state.notices.error("saving needs the page");
            return;
        };
        match session
            .to_bytes()
            .and_then(|bytes| host.download("person.likeness", "application/octet-stream", &bytes))
        {
            Ok(()) => self
                .state
                .notices
                .message("saved person.likeness (a download)"),
            Err(e) => self
                .state
                .notices
                .error(format!("cannot save the session: {e}")),
        }
    }

    /// Ctrl+S: where the session came from, else ask.
    fn save_session_shortcut(&mut self) {
        match self.session_path.clone() {
            // The autosave is the studio's own copy; saving goes to a file of the user's.
            Some(path) if path != self.autosave_path => self.save_session(&path),
            _ => self.save_session_dialog(),
        }
    }

    /// Whether shapes are drawn with anti-aliased (feathered) edges: the user's choice, else
    /// on except in a window on a software rasteriser. There every feathered edge is a
    /// strip of extra triangles, and they were the largest part of a frame of the side
    /// lists (README, "Studio frame rate"); text is drawn the same either way.
    pub fn smooth_edges(&self) -> bool {
        self.settings
            .smooth_edges
            .unwrap_or(!self.window_on_cpu_adapter)
    }

    /// Whether the puppet view renders at half size while a clip plays: the user's choice,
    /// else on in a window on a software rasteriser, where the 3D view's cost follows the
    /// pixels it fills (README, "Studio frame rate").
    pub fn reduce_3d_while_playing(&self) -> bool {
        self.settings
            .reduce_3d_while_playing
            .unwrap_or(self.window_on_cpu_adapter)
    }

    fn apply_smooth_edges(&mut self, ctx: &egui::Context) {
        let smooth = self.smooth_edges();
        if self.applied_smooth_edges == Some(smooth) {
            return;
        }
        self.applied_smooth_edges = Some(smooth);
        ctx.tessellation_options_mut(|o| o.feathering = smooth);
    }

    /// How many times the studio's 3D views have been drawn (each [`ViewTarget::render`]
    /// that did not reuse its last picture).
    pub fn view_renders(&self) -> u64 {
        self.viewport.as_ref().map_or(0, |v| v.target.renders)
            + self.overlay.target.renders
            + self.puppet_panel.target.renders
            + self
                .blendshape_panel
                .targets
                .iter()
                .map(|t| t.renders)
                .sum::<u64>()
    }

    /// The size in pixels the puppet view was last rendered at.
    pub fn puppet_view_pixels(&self) -> Option<[u32; 2]> {
        self.puppet_panel.target.size()
    }

    pub fn session(&self) -> Option<&Arc<StudioSession>> {
        self.session.as_ref()
    }

    /// The input frame with its overlay, fitted to the panel.
    fn input_ui(&mut self, ui: &mut egui::Ui, eframe_frame: &eframe::Frame) {
        let Some(session) = self.session.clone() else {
            ui.centered_and_justified(|ui| ui.label("No footage: open a session or run the demo"));
            return;
        };
        ui.horizontal(|ui| {
            let p = &mut self.state.playback;
            ui.checkbox(&mut p.show_detected, "Detected landmarks");
            ui.checkbox(&mut p.show_model, "Model landmarks");
            ui.checkbox(&mut p.show_boxes, "Face box and crop");
            ui.separator();
            ui.add(
                egui::Slider::new(&mut self.overlay.opacity, 0.0..=1.0)
                    .text("Reconstruction opacity"),
            )
            .on_hover_text(
                "The personalized face under the tracked pose, weights and lighting, over the frame",
            );
        });
        let k = self
            .state
            .playback
            .frame
            .min(session.frame_count().saturating_sub(1));
        let Some(frame) = session.frames.get(k) else {
            ui.label("The session has no frames");
            return;
        };
        let size = [frame.width(), frame.height()];
        let Some(id) = self.frame_texture_id(ui.ctx(), &session, k) else {
            return;
        };
        let rect = fit_rect(ui.available_rect_before_wrap(), size);
        let response = ui.allocate_rect(ui.available_rect_before_wrap(), egui::Sense::hover());
        let painter = ui.painter_at(response.rect);
        // The composite is rendered at the size it is shown, so it stays sharp.
        let pixels = (rect.size() * ui.pixels_per_point()).round();
        let composite = match eframe_frame.wgpu_render_state() {
            Some(rs) if pixels.x >= 1.0 && pixels.y >= 1.0 => self.overlay.render(
                rs,
                &self.scene,
                &session,
                k,
                [pixels.x as u32, pixels.y as u32],
            ),
            _ => Ok(None),
        };
        self.overlay.frame_rect = Some(rect);
        let id = match composite {
            Ok(Some(composite)) => composite,
            Ok(None) => id,
            Err(e) => {
                self.state.notices.error(e);
                self.overlay.opacity = 0.0;
                id
            }
        };
        painter.image(
            id,
            rect,
            egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
            egui::Color32::WHITE,
        );
        paint_overlay(
            &painter,
            rect,
            size,
            &session.overlay(k),
            &self.state.playback,
        );
    }

    /// Frame `k` of the session as an egui texture (uploaded when the frame changes).
    fn frame_texture_id(
        &mut self,
        ctx: &egui::Context,
        session: &StudioSession,
        k: usize,
    ) -> Option<egui::TextureId> {
        let frame = session.frames.get(k)?;
        match &mut self.frame_texture {
            Some((shown, _)) if *shown == k => {}
            Some((shown, texture)) => {
                upload_frame(ctx, texture, "input frame", frame);
                *shown = k;
            }
            None => self.frame_texture = Some((k, new_frame_texture(ctx, "input frame", frame))),
        }
        self.frame_texture.as_ref().map(|(_, t)| t.id())
    }

    /// The performance driving a puppet or person B, beside the input.
    fn puppet_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        let Some(session) = self.session.clone() else {
            return;
        };
        let k = self
            .state
            .playback
            .frame
            .min(session.frame_count().saturating_sub(1));
        let input = self
            .frame_texture_id(ui.ctx(), &session, k)
            .zip(session.frames.get(k).map(|f| [f.width(), f.height()]));
        self.puppet_panel.render_scale = crate::gpu_view::view_render_scale(
            self.state.playback.playing,
            self.reduce_3d_while_playing(),
        );
        let started = Instant::now();
        if let Some(error) = self.puppet_panel.ui(
            ui,
            frame.wgpu_render_state(),
            &self.scene,
            &session,
            k,
            input,
        ) {
            self.state.notices.error(error);
        }
        if let Some(request) = self.puppet_panel.requested_export.take() {
            match self.web_host.clone() {
                Some(host) => {
                    self.puppet_panel.status =
                        Some(self.web_export(request.kind, &session, &*host));
                }
                None => {
                    let job = self.puppet_panel.export_job(
                        request.kind,
                        self.scene.clone(),
                        session.clone(),
                        request.dir,
                    );
                    let label = request.label;
                    self.start_write(WriteKind::Export, label, move || {
                        job().map_err(|e| format!("{label}: {e:#}"))
                    });
                }
            }
        }
        self.state.frame_time_ms = started.elapsed().as_secs_f32() * 1000.0;
    }

    /// An export in the browser, as a download; says what happened for the panel.
    fn web_export(
        &mut self,
        kind: crate::puppet_panel::ExportKind,
        session: &StudioSession,
        host: &dyn crate::web_host::WebHost,
    ) -> String {
        let puppet = self.puppet_panel.puppet.as_ref();
        let name = kind.file_name(puppet.map(|p| p.path.as_path()));
        let made = crate::puppet_panel::export_bytes(kind, puppet, &self.scene, session, &name)
            .and_then(|(bytes, mime)| {
                host.download(&name, mime, &bytes)
                    .map_err(anyhow::Error::msg)
            });
        match made {
            Ok(()) => format!("downloaded {name}"),
            Err(e) => {
                self.state.notices.error(format!("{name}: {e:#}"));
                format!("{name} failed")
            }
        }
    }

    /// Makes the built-in demo a slice per frame on the studio's own GPU device (the
    /// browser, where nothing may block): the template face plays meanwhile, and the
    /// session replaces it when it is ready.
    pub fn start_demo_in_steps(&mut self, render_state: &egui_wgpu::RenderState) {
        let Some(networks) = self.scene.networks.clone() else {
            self.state
                .notices
                .error("the demo needs the networks, which were not loaded");
            return;
        };
        let options = renderer::RenderOptions {
            sample_count: 1,
            // Blending on the CPU is the path every WebGL2 implementation can draw.
            blend_path: renderer::BlendPath::Cpu,
            cull_back_faces: false,
        };
        let made = crate::demo::SteppedDemo::new(
            self.scene.clone(),
            networks,
            crate::demo::DemoConfig::default(),
            |mesh, textures| {
                Ok(renderer::OffscreenRenderer::on_device(
                    render_state.adapter.clone(),
                    render_state.device.clone(),
                    render_state.queue.clone(),
                    options,
                    mesh,
                    textures,
                )?)
            },
        );
        match made {
            Ok(mut job) => {
                // The demo tracks with the default locator (its tracker's config).
                job.remote_locator = self.web_host.as_ref().and_then(|host| {
                    host.face_locator(tracking::pipeline::TrackerConfig::default().locator)
                });
                self.demo_job = Some(job);
            }
            Err(e) => self
                .state
                .notices
                .error(format!("the demo could not be built: {e:#}")),
        }
    }

    /// The demo being made, if it is.
    pub fn demo_job(&self) -> Option<&crate::demo::SteppedDemo> {
        self.demo_job.as_ref()
    }

    fn poll_demo_job(&mut self, ctx: &egui::Context) {
        let Some(job) = self.demo_job.as_mut() else {
            return;
        };
        // Rendering and tracking take a slice of each frame; the UI keeps drawing.
        ctx.request_repaint();
        // A larger slice than a footage job's: the demo is what a visitor waits for, and
        // the studio has nothing else to show meanwhile but the template.
        let Some(result) = job.step(web_time::Duration::from_millis(100)) else {
            return;
        };
        self.demo_job = None;
        match result {
            Ok((demo, rate)) => {
                if let Some(fps) = rate.fps() {
                    self.state.notices.message(format!(
                        "demo tracked at {fps:.1} frames per second ({} frames)",
                        rate.frames
                    ));
                }
                self.tracking_rate = Some(rate);
                let session = StudioSession::from_demo(&self.scene.model, demo);
                self.set_session(Arc::new(session));
            }
            Err(e) => self
                .state
                .notices
                .error(format!("the demo could not be built: {e:#}")),
        }
    }

    /// Opens the page's file picker (the browser).
    pub fn pick_files(&mut self) {
        match &self.web_host {
            Some(host) => host.pick_files("image/*,video/*,.glb,.gltf,.vrm,.likeness"),
            None => self.state.notices.error("opening files needs the page"),
        }
    }

    /// Records from the webcam: natively through ffmpeg, in the browser through the page.
    pub fn open_webcam(&mut self, ctx: &egui::Context) {
        let Some(host) = self.web_host.clone() else {
            self.open_footage(ctx, "webcam");
            return;
        };
        if let Some(job) = &self.job {
            self.state.notices.error(format!(
                "still processing {}: cancel it before recording",
                job.input
            ));
            return;
        }
        host.start_camera();
        let camera = host.clone();
        let next = move || match camera.camera_frame() {
            crate::web_host::CameraFrame::Frame(image) => crate::stepped::LiveFrame::Frame(image),
            crate::web_host::CameraFrame::Starting | crate::web_host::CameraFrame::Waiting => {
                crate::stepped::LiveFrame::Waiting
            }
            crate::web_host::CameraFrame::Failed(reason) => {
                crate::stepped::LiveFrame::Ended(Some(reason))
            }
        };
        self.start_feed(
            "webcam",
            crate::stepped::FrameFeed::Live {
                next: Box::new(next),
                fps: 30.0,
            },
        );
    }

    /// Starts a footage job on frames the page supplies (the browser).
    #[cfg(target_arch = "wasm32")]
    fn start_feed(&mut self, input: &str, feed: crate::stepped::FrameFeed) {
        let locator = self.face_locator_choice();
        let remote = self
            .web_host
            .as_ref()
            .and_then(|host| host.face_locator(locator));
        match FootageJob::start_feed(self.scene.clone(), input.to_owned(), feed, locator, remote) {
            Ok(job) => {
                self.job = Some(job);
                self.stop_demo_for("your footage");
            }
            Err(e) => self.state.notices.error(format!("{input}: {e:#}")),
        }
    }

    /// The user's own footage or session comes first: a demo still being made would
    /// replace it when it ends, so it stops.
    fn stop_demo_for(&mut self, what: &str) {
        if self.demo_job.take().is_some() {
            self.state
                .notices
                .message(format!("stopped making the demo for {what}"));
        }
    }

    #[cfg(not(target_arch = "wasm32"))]
    fn start_feed(&mut self, input: &str, _feed: crate::stepped::FrameFeed) {
        self.state.notices.error(format!(
            "{input}: frames from a page are tracked only in the browser build"
        ));
    }

    /// Files that came as bytes (picked or dropped in the browser): puppets load into the
    /// puppet panel, a `.likeness` file opens as the session, a video is decoded by the
    /// page and tracked, and images are tracked as one clip in name order.
    pub fn open_files(&mut self, mut files: Vec<crate::web_host::PickedFile>) {
        use crate::web_host::{is_puppet_name, is_video_name};
        files.sort_by(|a, b| a.name.cmp(&b.name));
        let mut images = Vec::new();
        let mut unreadable = Vec::new();
        for file in files {
            let lower = file.name.to_ascii_lowercase();
            if is_puppet_name(&file.name) {
                match self.puppet_panel.load_bytes(&file.name, &file.bytes) {
                    Ok(()) if self.session.is_some() => self.state.panel = Panel::Puppet,
                    Ok(()) => {}
                    Err(e) => self.state.notices.error(format!("{e:#}")),
                }
            } else if lower.ends_with(".likeness") {
                match StudioSession::from_bytes(&self.scene.model, &file.name, &file.bytes) {
                    Ok(session) => {
                        self.state.notices.message(format!(
                            "opened {} ({} frames)",
                            file.name,
                            session.frame_count()
                        ));
                        self.set_session(Arc::new(session));
                        self.stop_demo_for(&file.name);
                    }
                    Err(e) => self.state.notices.error(e),
                }
            } else if is_video_name(&file.name) {
                match &self.web_host {
                    Some(host) if self.job.is_none() && self.decoding_video.is_none() => {
                        host.decode_video(
                            &file,
                            crate::footage::FootageRequest::new("").max_frames,
                        );
                        self.decoding_video = Some(file.name.clone());
                    }
                    Some(_) => self.state.notices.error(format!(
                        "{}: still processing other footage; open it when that has ended",
                        file.name
                    )),
                    None => self
                        .state
                        .notices
                        .error(format!("{}: videos are decoded by the page", file.name)),
                }
            } else {
                match image::load_from_memory(&file.bytes) {
                    Ok(image) => images.push(image.to_rgb8()),
                    Err(e) => unreadable.push(format!("{} ({e})", file.name)),
                }
            }
        }
        if !unreadable.is_empty() {
            self.state.notices.error(format!(
                "not an image, video, puppet or session: {}",
                unreadable.join(", ")
            ));
        }
        if !images.is_empty() {
            let name = if images.len() == 1 {
                "dropped image".to_owned()
            } else {
                format!("{} dropped images", images.len())
            };
            self.start_feed(&name, crate::stepped::FrameFeed::clip(images, 30.0));
        }
    }

    /// Takes what the page has for the studio: picked files, a puppet request, a decoded
    /// video.
    fn poll_web(&mut self, ctx: &egui::Context) {
        let Some(host) = self.web_host.clone() else {
            return;
        };
        if std::mem::take(&mut self.puppet_panel.pick_requested) {
            host.pick_files(".glb,.gltf,.vrm");
        }
        let picked = host.take_picked_files();
        if !picked.is_empty() {
            self.open_files(picked);
        }
        if let Some(name) = self.decoding_video.clone() {
            ctx.request_repaint();
            match host.video_frames() {
                Some(crate::web_host::VideoFrames::Done { frames, fps }) => {
                    self.decoding_video = None;
                    self.start_feed(&name, crate::stepped::FrameFeed::clip(frames, fps));
                }
                Some(crate::web_host::VideoFrames::Failed(reason)) => {
                    self.decoding_video = None;
                    self.state.notices.error(format!("{name}: {reason}"));
                }
                Some(crate::web_host::VideoFrames::Decoding { .. }) => {}
                None => self.decoding_video = None,
            }
        }
        if self.job.is_some() {
            // The job advances only when the studio draws.
            ctx.request_repaint();
        }
    }

    /// Where the page is with a video it decodes, for the job bar.
    pub fn video_decoding(&self) -> Option<(String, Option<crate::web_host::VideoFrames>)> {
        let name = self.decoding_video.clone()?;
        Some((name, self.web_host.as_ref().and_then(|h| h.video_frames())))
    }

    /// Puppet files dropped on the window are loaded into the puppet panel; images, videos
    /// and folders are opened as footage.
    fn dropped_files(&mut self, ctx: &egui::Context) {
        let dropped = ctx.input(|i| i.raw.dropped_files.clone());
        // A browser reads dropped files asynchronously: the page reads them and hands them
        // back as picked files.
        if let Some(host) = &self.web_host {
            if !dropped.is_empty() {
                host.read_dropped(dropped);
            }
            return;
        }
        for file in dropped {
            let path = file.path().to_owned();
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            match ext.as_deref() {
                Some("glb" | "gltf" | "vrm") => match self.puppet_panel.load(&path) {
                    Ok(()) => {
                        if self.session.is_some() {
                            self.state.panel = Panel::Puppet;
                        }
                    }
                    Err(e) => self.state.notices.error(format!("{e:#}")),
                },
                // Anything else is footage: an image, a video or a folder; what cannot be
                // read is reported by the job.
                _ => self.open_footage(ctx, &path.display().to_string()),
            }
        }
    }

    /// The person's learned maps in UV space, for the selected blendshape and frame.
    fn maps_ui(&mut self, ui: &mut egui::Ui) {
        let Some(session) = self.session.clone() else {
            return;
        };
        let frame = self.state.playback.frame;
        let weights = session.weights(frame);
        if let Some(error) = self.uv_panel.ui(
            ui,
            &self.scene.model,
            self.scene.albedo.face(),
            &session.corrections,
            self.state.selected,
            frame,
            &weights,
        ) {
            self.state.notices.error(error);
        }
    }

    /// Space plays or pauses, the arrows step frames, Tab switches panels.
    fn shortcuts(&mut self, ctx: &egui::Context) {
        let frames = self.session.as_ref().map_or(0, |s| s.frame_count());
        if ctx.egui_wants_keyboard_input() {
            return; // typing in the search box
        }
        let (save, open) = ctx.input(|i| {
            (
                i.modifiers.command && i.key_pressed(egui::Key::S),
                i.modifiers.command && i.key_pressed(egui::Key::O),
            )
        });
        if save && self.session.is_some() {
            self.save_session_shortcut();
        }
        if open {
            #[cfg(not(target_arch = "wasm32"))]
            self.open_session_dialog();
            #[cfg(target_arch = "wasm32")]
            self.pick_files();
        }
        ctx.input(|i| {
            if i.modifiers.command {
                return;
            }
            if i.key_pressed(egui::Key::Space) {
                self.state.playback.playing = !self.state.playback.playing;
            }
            if i.key_pressed(egui::Key::ArrowRight) {
                self.state.playback.step(1, frames);
            }
            if i.key_pressed(egui::Key::ArrowLeft) {
                self.state.playback.step(-1, frames);
            }
            if i.key_pressed(egui::Key::Tab) && frames > 0 {
                self.state.panel = match self.state.panel {
                    Panel::Input => Panel::Face,
                    Panel::Face => Panel::Blendshapes,
                    Panel::Blendshapes => Panel::Maps,
                    Panel::Maps => Panel::Motion,
                    Panel::Motion => Panel::Puppet,
                    Panel::Puppet => Panel::Input,
                };
            }
        });
    }

    /// Sliders for the 53 blendshapes, filtered by the search text.
    fn blendshape_list_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            let label = ui.label("Search");
            ui.text_edit_singleline(&mut self.state.filter)
                .labelled_by(label.id);
        });
        ui.horizontal(|ui| {
            ui.checkbox(&mut self.state.playing_demo, "Play expression loop");
            if ui.button("Reset").clicked() {
                self.state.weights = [0.0; NUM_BLENDSHAPES];
                self.state.playing_demo = false;
            }
        });
        ui.separator();
        let filter = self.state.filter.to_ascii_lowercase();
        let listed: Vec<usize> = (0..NUM_BLENDSHAPES)
            .filter(|&i| filter.is_empty() || ICT_NAMES[i].to_ascii_lowercase().contains(&filter))
            .collect();
        list_rows(ui, listed.len(), |ui, row| {
            let i = listed[row];
            let name = &ICT_NAMES[i];
            ui.horizontal(|ui| {
                let selected = self.state.selected == i;
                // "A" for the paper's attention mask A_i; only default-font glyphs are safe here.
                let pick = ui.selectable_label(selected, "A");
                if pick
                    .on_hover_text(format!("Show the attention mask of {name}"))
                    .clicked()
                {
                    self.state.selected = i;
                    if matches!(self.state.view, StudioView::Mask(_)) {
                        self.state.view = StudioView::Mask(i);
                    }
                }
                let response =
                    ui.add(egui::Slider::new(&mut self.state.weights[i], 0.0..=1.0).text(*name));
                if response.changed() {
                    // A hand-set weight stops the scripted loop so it is not overwritten.
                    self.state.playing_demo = false;
                    self.state.selected = i;
                }
            });
        });
    }

    fn toolbar_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            self.file_menu_ui(ui);
            ui.separator();
            if self.session.is_some() {
                ui.label("Panel");
                for (panel, label) in [
                    (Panel::Input, "Input"),
                    (Panel::Face, "Face"),
                    (Panel::Blendshapes, "Blendshapes"),
                    (Panel::Maps, "Maps"),
                    (Panel::Motion, "Lighting and motion"),
                    (Panel::Puppet, "Puppet"),
                ] {
                    if ui
                        .selectable_label(self.state.panel == panel, label)
                        .clicked()
                    {
                        self.state.panel = panel;
                    }
                }
                ui.separator();
            }
            // The view modes belong to the face view; other panels have their own controls.
            let face_shown = self.session.is_none() || self.state.panel == Panel::Face;
            if face_shown {
                ui.label("View");
                let selected = self.state.selected;
                for view in [
                    StudioView::Shaded,
                    StudioView::Albedo,
                    StudioView::Normals,
                    StudioView::Wireframe,
                    StudioView::Landmarks,
                    StudioView::Mask(selected),
                ] {
                    let label = if matches!(view, StudioView::Mask(_)) {
                        "Mask".to_owned()
                    } else {
                        view.label()
                    };
                    if ui
                        .selectable_label(self.state.view == view, label)
                        .clicked()
                    {
                        self.state.view = view;
                    }
                }
            }
            if self.state.show_timings {
                ui.separator();
                ui.label(format!(
                    "frame {:.1} ms ({:.0} fps), 3D view {:.1} ms",
                    self.state.frame_interval_ms,
                    1000.0 / self.state.frame_interval_ms.max(1e-3),
                    self.state.frame_time_ms
                ));
            }
            if let StudioView::Mask(i) = self.state.view
                && face_shown
            {
                ui.separator();
                ui.label(format!("mask A of {}", ICT_NAMES[i]));
            }
        });
    }

    fn viewport_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        let size = available_pixels(ui);
        let (Some(viewport), Some(rs)) = (self.viewport.as_mut(), frame.wgpu_render_state()) else {
            ui.centered_and_justified(|ui| {
                ui.label(self.state.notices.latest_error().unwrap_or("no 3D view"));
            });
            return;
        };
        let started = Instant::now();
        if let Err(e) = viewport.face.set_weights(&rs.queue, &self.state.weights) {
            self.state.notices.error(e.to_string());
        }
        if let StudioView::Mask(i) = self.state.view
            && viewport.uploaded_mask != Some(i)
        {
            match viewport
                .face
                .set_uv_mask(&rs.queue, Some(self.scene.mask(i)))
            {
                Ok(()) => viewport.uploaded_mask = Some(i),
                Err(e) => self.state.notices.error(e.to_string()),
            }
        }
        let params = frame_params(self.state.view, &self.state.orbit, size[0], size[1]);
        let id = viewport
            .target
            .render(rs, &viewport.face, size, &params, "studio 3D view");
        self.state.frame_time_ms = started.elapsed().as_secs_f32() * 1000.0;

        let response = ui.add(
            egui::Image::new((id, egui::vec2(size[0] as f32, size[1] as f32)))
                .sense(egui::Sense::drag()),
        );
        orbit_input(ui, &response, &mut self.state.orbit);
    }

    /// The selected blendshape: template, personalized and correction views.
    fn blendshapes_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        let (Some(session), Some(viewport), Some(rs)) = (
            self.session.clone(),
            self.viewport.as_mut(),
            frame.wgpu_render_state(),
        ) else {
            ui.label("No 3D view or no session");
            return;
        };
        let started = Instant::now();
        if let Some(error) = self.blendshape_panel.views_ui(
            ui,
            rs,
            &mut viewport.face,
            &self.scene,
            &session,
            self.state.selected,
            &mut self.state.orbit,
        ) {
            self.state.notices.error(error);
        }
        self.state.frame_time_ms = started.elapsed().as_secs_f32() * 1000.0;
    }
}

/// The file dialog for session files.
#[cfg(not(target_arch = "wasm32"))]
fn session_dialog() -> rfd::FileDialog {
    rfd::FileDialog::new().add_filter("Likeness session", &["likeness"])
}

/// The panels' frames without their fill: the studio's background is painted once for the
/// whole window (see `StudioApp::window_cleared_to_panel_colour`), not once per panel.
fn side_frame(ui: &egui::Ui) -> egui::Frame {
    egui::Frame::side_top_panel(ui.style()).fill(egui::Color32::TRANSPARENT)
}

fn central_frame(ui: &egui::Ui) -> egui::Frame {
    egui::Frame::central_panel(ui.style()).fill(egui::Color32::TRANSPARENT)
}

impl eframe::App for StudioApp {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        eframe::set_value(storage, SETTINGS_KEY, &self.current_settings());
    }

    /// A save or export still being written when the window closes is finished first:
    /// the process would otherwise end its thread halfway and the file would be lost.
    fn on_exit(&mut self) {
        for (_, write) in std::mem::take(&mut self.writes) {
            tracing::info!("finishing {} before exit", write.what);
            match write.wait() {
                Ok(path) => tracing::info!("wrote {}", path.display()),
                Err(e) => tracing::error!("{e}"),
            }
        }
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.state.frame_interval_ms = ui.input(|i| i.unstable_dt) * 1000.0;
        if !self.window_cleared_to_panel_colour {
            let rect = ui.ctx().content_rect();
            ui.painter().rect_filled(rect, 0.0, ui.visuals().panel_fill);
        }
        if let Some(probe) = &mut self.fps_probe {
            ui.ctx().request_repaint();
            if probe.frame(Instant::now()) {
                self.fps_probe = None;
                ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close);
            }
        }
        self.apply_smooth_edges(ui.ctx());
        self.poll_demo_job(ui.ctx());
        self.poll_web(ui.ctx());
        self.poll_job(ui.ctx());
        self.poll_writes(ui.ctx());
        self.shortcuts(ui.ctx());
        self.dropped_files(ui.ctx());
        if let Some(session) = self.session.clone() {
            let dt = f64::from(ui.input(|i| i.stable_dt));
            self.state
                .playback
                .advance(dt, session.fps, session.frame_count());
            if self.state.playback.playing {
                ui.ctx().request_repaint();
            }
            // The face replays the tracked performance unless the user holds a slider.
            if !self.state.playing_demo {
                self.state.weights = session.weights(self.state.playback.frame).0;
            }
        } else if self.state.playing_demo {
            let dt = ui.input(|i| i.stable_dt) as f64;
            self.state.demo_time_secs += dt.min(0.1);
            self.state.weights = demo_weights(self.state.demo_time_secs);
            ui.ctx().request_repaint();
        }
        // The panels are unfilled (see `side_frame`), but egui reads the background colour
        // from the frames of the enclosing UIs (scroll areas fade into it): this scope
        // carries the panel colour without painting it.
        let background = egui::UiStackInfo::new(egui::UiKind::Frame)
            .with_frame(egui::Frame::NONE.fill(ui.visuals().panel_fill));
        ui.scope_builder(egui::UiBuilder::new().ui_stack_info(background), |ui| {
            self.panels_ui(ui, frame)
        });
    }
}

impl StudioApp {
    /// The toolbar, side panel, bottom bars and the current main panel.
    fn panels_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        egui::Panel::top("toolbar")
            .frame(side_frame(ui))
            .show(ui, |ui| self.toolbar_ui(ui));
        egui::Panel::left("blendshapes")
            .frame(side_frame(ui))
            .default_size(330.0)
            .show(ui, |ui| match self.session.clone() {
                Some(session) if self.state.panel == Panel::Blendshapes => {
                    self.blendshape_panel
                        .list_ui(ui, &session, &mut self.state.selected);
                }
                Some(session) if self.state.panel == Panel::Puppet => {
                    self.puppet_panel
                        .channels_ui(ui, &session, self.state.playback.frame);
                }
                _ => self.blendshape_list_ui(ui),
            });
        if self.job.is_some() {
            egui::Panel::bottom("footage job")
                .frame(side_frame(ui))
                .show(ui, |ui| self.job_ui(ui));
        }
        if let Some(session) = self.session.clone() {
            egui::Panel::bottom("timeline")
                .frame(side_frame(ui))
                .show(ui, |ui| timeline_ui(ui, &mut self.state.playback, &session));
        }
        // What the panels above left: the main panel, where the toasts go.
        let main_rect = ui.available_rect_before_wrap();
        self.main_panel_ui(ui, frame);
        self.state.notices.ui(ui.ctx(), main_rect);
    }

    fn main_panel_ui(&mut self, ui: &mut egui::Ui, frame: &eframe::Frame) {
        match self.state.panel {
            Panel::Input if self.session.is_some() => {
                egui::CentralPanel::default()
                    .frame(central_frame(ui))
                    .show(ui, |ui| self.input_ui(ui, frame));
            }
            Panel::Blendshapes if self.session.is_some() => {
                let dt = f64::from(ui.input(|i| i.stable_dt));
                self.blendshape_panel.advance(dt);
                egui::CentralPanel::default()
                    .frame(central_frame(ui))
                    .show(ui, |ui| self.blendshapes_ui(ui, frame));
            }
            Panel::Puppet if self.session.is_some() => {
                egui::CentralPanel::default()
                    .frame(central_frame(ui))
                    .show(ui, |ui| self.puppet_ui(ui, frame));
            }
            Panel::Maps if self.session.is_some() => {
                egui::CentralPanel::default()
                    .frame(central_frame(ui))
                    .show(ui, |ui| self.maps_ui(ui));
            }
            Panel::Motion => {
                if let Some(session) = self.session.clone() {
                    egui::CentralPanel::default()
                        .frame(central_frame(ui))
                        .show(ui, |ui| {
                            let frame = self.state.playback.frame;
                            if let Some(k) = self.motion_panel.ui(ui, &session, frame) {
                                self.state
                                    .playback
                                    .step(k as isize - frame as isize, session.frame_count());
                            }
                        });
                }
            }
            _ => {
                egui::CentralPanel::default()
                    .frame(central_frame(ui))
                    .show(ui, |ui| self.viewport_ui(ui, frame));
            }
        }
    }
}
