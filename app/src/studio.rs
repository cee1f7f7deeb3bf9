//! The studio window: a 3D view of the face with an orbit camera, the 53 blendshape sliders
//! (searchable), a view-mode switch and the frame time.

use std::sync::Arc;
use std::time::Instant;

use face::{ICT_NAMES, NUM_BLENDSHAPES};
use renderer::FaceRenderer;

use crate::blendshape_panel::BlendshapePanel;
use crate::gpu_view::{
    VIEW_FORMAT, ViewTarget, available_pixels, interactive_options, orbit_input,
};
use crate::scene::{Orbit, Scene, StudioView, demo_weights, frame_params};
use crate::studio_panels::{PlaybackState, fit_rect, paint_overlay, timeline_ui};
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
    pub error: Option<String>,
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
            error: None,
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
        };
        match cc.wgpu_render_state.as_ref() {
            Some(rs) => match FaceRenderer::with_options(
                &rs.device,
                &rs.queue,
                VIEW_FORMAT,
                interactive_options(rs),
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
                Err(e) => app.state.error = Some(format!("3D view unavailable: {e}")),
            },
            None => {
                app.state.error = Some("3D view unavailable: eframe is not running on wgpu".into())
            }
        }
        app
    }

    /// Shows a tracked session: the input panel, the timeline, and the face replaying the
    /// tracked weights.
    pub fn with_session(mut self, session: Arc<StudioSession>) -> Self {
        self.session = Some(session);
        self.frame_texture = None;
        self.uv_panel.clear();
        self.blendshape_panel.clear();
        self.state.playback = PlaybackState {
            playing: true,
            ..PlaybackState::default()
        };
        self.state.playing_demo = false;
        self.state.panel = Panel::Input;
        self
    }

    pub fn session(&self) -> Option<&Arc<StudioSession>> {
        self.session.as_ref()
    }

    /// The input frame with its overlay, fitted to the panel.
    fn input_ui(&mut self, ui: &mut egui::Ui) {
        let Some(session) = self.session.clone() else {
            ui.centered_and_justified(|ui| ui.label("No footage: open a session or run the demo"));
            return;
        };
        ui.horizontal(|ui| {
            let p = &mut self.state.playback;
            ui.checkbox(&mut p.show_detected, "Detected landmarks");
            ui.checkbox(&mut p.show_model, "Model landmarks");
            ui.checkbox(&mut p.show_boxes, "Face box and crop");
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
        if self
            .frame_texture
            .as_ref()
            .is_none_or(|(shown, _)| *shown != k)
        {
            let image =
                egui::ColorImage::from_rgb([size[0] as usize, size[1] as usize], frame.as_raw());
            match self.frame_texture.as_mut() {
                Some((shown, texture)) => {
                    texture.set(image, egui::TextureOptions::LINEAR);
                    *shown = k;
                }
                None => {
                    let texture =
                        ui.ctx()
                            .load_texture("input frame", image, egui::TextureOptions::LINEAR);
                    self.frame_texture = Some((k, texture));
                }
            }
        }
        let Some((_, texture)) = self.frame_texture.as_ref() else {
            return;
        };
        let rect = fit_rect(ui.available_rect_before_wrap(), size);
        let response = ui.allocate_rect(ui.available_rect_before_wrap(), egui::Sense::hover());
        let painter = ui.painter_at(response.rect);
        painter.image(
            texture.id(),
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
            self.state.error = Some(error);
        }
    }

    /// Space plays or pauses, the arrows step frames, Tab switches panels.
    fn shortcuts(&mut self, ctx: &egui::Context) {
        let frames = self.session.as_ref().map_or(0, |s| s.frame_count());
        if ctx.egui_wants_keyboard_input() {
            return; // typing in the search box
        }
        ctx.input(|i| {
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
                    Panel::Motion => Panel::Input,
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
        egui::ScrollArea::vertical().show(ui, |ui| {
            for (i, name) in ICT_NAMES.iter().enumerate() {
                if !filter.is_empty() && !name.to_ascii_lowercase().contains(&filter) {
                    continue;
                }
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
                    let response = ui
                        .add(egui::Slider::new(&mut self.state.weights[i], 0.0..=1.0).text(*name));
                    if response.changed() {
                        // A hand-set weight stops the scripted loop so it is not overwritten.
                        self.state.playing_demo = false;
                        self.state.selected = i;
                    }
                });
            }
        });
    }

    fn toolbar_ui(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            if self.session.is_some() {
                ui.label("Panel");
                for (panel, label) in [
                    (Panel::Input, "Input"),
                    (Panel::Face, "Face"),
                    (Panel::Blendshapes, "Blendshapes"),
                    (Panel::Maps, "Maps"),
                    (Panel::Motion, "Lighting and motion"),
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
                ui.label(
                    self.state
                        .error
                        .clone()
                        .unwrap_or_else(|| "no 3D view".into()),
                );
            });
            return;
        };
        let started = Instant::now();
        if let Err(e) = viewport.face.set_weights(&rs.queue, &self.state.weights) {
            self.state.error = Some(e.to_string());
        }
        if let StudioView::Mask(i) = self.state.view
            && viewport.uploaded_mask != Some(i)
        {
            match viewport
                .face
                .set_uv_mask(&rs.queue, Some(self.scene.mask(i)))
            {
                Ok(()) => viewport.uploaded_mask = Some(i),
                Err(e) => self.state.error = Some(e.to_string()),
            }
        }
        let (view, id) = viewport.target.prepare(rs, size, "studio 3D view");
        let params = frame_params(self.state.view, &self.state.orbit, size[0], size[1]);
        let mut encoder = rs
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("studio 3D view"),
            });
        viewport.face.render(
            &rs.device,
            &rs.queue,
            &mut encoder,
            &view,
            (size[0], size[1]),
            &params,
        );
        rs.queue.submit([encoder.finish()]);
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
            self.state.error = Some(error);
        }
        self.state.frame_time_ms = started.elapsed().as_secs_f32() * 1000.0;
    }
}

impl eframe::App for StudioApp {
    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        self.state.frame_interval_ms = ui.input(|i| i.unstable_dt) * 1000.0;
        self.shortcuts(ui.ctx());
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
        egui::Panel::top("toolbar").show(ui, |ui| self.toolbar_ui(ui));
        egui::Panel::left("blendshapes")
            .default_size(330.0)
            .show(ui, |ui| match self.session.clone() {
                Some(session) if self.state.panel == Panel::Blendshapes => {
                    self.blendshape_panel
                        .list_ui(ui, &session, &mut self.state.selected);
                }
                _ => self.blendshape_list_ui(ui),
            });
        if let Some(error) = self.state.error.clone() {
            egui::Panel::bottom("errors").show(ui, |ui| {
                ui.horizontal(|ui| {
                    ui.colored_label(egui::Color32::LIGHT_RED, &error);
                    if ui.button("Dismiss").clicked() {
                        self.state.error = None;
                    }
                });
            });
        }
        if let Some(session) = self.session.clone() {
            egui::Panel::bottom("timeline")
                .show(ui, |ui| timeline_ui(ui, &mut self.state.playback, &session));
        }
        match self.state.panel {
            Panel::Input if self.session.is_some() => {
                egui::CentralPanel::default().show(ui, |ui| self.input_ui(ui));
            }
            Panel::Blendshapes if self.session.is_some() => {
                let dt = f64::from(ui.input(|i| i.stable_dt));
                self.blendshape_panel.advance(dt);
                egui::CentralPanel::default().show(ui, |ui| self.blendshapes_ui(ui, frame));
            }
            Panel::Maps if self.session.is_some() => {
                egui::CentralPanel::default().show(ui, |ui| self.maps_ui(ui));
            }
            Panel::Motion => {
                if let Some(session) = self.session.clone() {
                    egui::CentralPanel::default().show(ui, |ui| {
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
                egui::CentralPanel::default().show(ui, |ui| self.viewport_ui(ui, frame));
            }
        }
    }
}
