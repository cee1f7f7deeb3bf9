//! The corrected-blendshapes panel: the 53 blendshapes listed with the size of the person's
//! correction (mm, sortable, searchable), and for the selected one the template S_i beside
//! the personalized S_i + F(A_i dS_i) (equation 2, with the person's identity dS_0 and
//! albedo, equation 3), with a third view showing the correction |F(A_i dS_i)| in mm as a
//! heatmap with a colour bar, or the attention mask A_i on the mesh.
//!
//! It owns the personalized mesh's renderer (built once per session) and the three view
//! targets; the template renderer is the studio's and is lent for the frame.

use std::sync::Arc;

use face::{BlendshapeWeights, ICT_NAMES, NUM_BLENDSHAPES};
use renderer::{FaceRenderer, FrameParams, ViewMode};

use crate::colormap::colour_bar;
use crate::gpu_view::{ViewTarget, orbit_input, person_renderer, upload_person_albedo};
use crate::scene::{Orbit, Scene, StudioView, frame_params};
use crate::studio_panels::list_rows;
use crate::studio_session::StudioSession;

/// How the list is ordered.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ListOrder {
    /// Largest personal correction first: what the model learned most about.
    ByCorrection,
    /// The template's order (ICT FaceKit index).
    ByIndex,
}

/// The personalized mesh on the GPU, for one session.
struct PersonalGpu {
    /// Which session it was built for (the `Arc`'s address).
    session: usize,
    face: FaceRenderer,
    /// The blendshape whose correction magnitudes are uploaded as vertex scalars, and
    /// whose mask is uploaded.
    uploaded: Option<usize>,
    /// (blendshape, weight bits) of the uploaded albedo correction (equation 3).
    albedo_for: Option<(usize, u32)>,
}

pub struct BlendshapePanel {
    pub filter: String,
    pub order: ListOrder,
    /// The weight w_i the three views show the selected blendshape at.
    pub preview_weight: f32,
    /// Sweep the weight 0 -> 1 -> 0 continuously.
    pub playing: bool,
    play_secs: f64,
    /// The third view shows A_i instead of the correction heatmap.
    pub show_mask: bool,
    gpu: Option<PersonalGpu>,
    pub(crate) targets: [ViewTarget; 3],
    bar: Option<egui::TextureHandle>,
}

impl Default for BlendshapePanel {
    fn default() -> Self {
        Self {
            filter: String::new(),
            order: ListOrder::ByCorrection,
            preview_weight: 1.0,
            playing: false,
            play_secs: 0.0,
            show_mask: false,
            gpu: None,
            targets: Default::default(),
            bar: None,
        }
    }
}

/// The row label of blendshape `i` in the list (tests find rows by it).
pub fn row_label(session: &StudioSession, i: usize) -> String {
    format!("{}  {:.2} mm", ICT_NAMES[i], session.correction_mm[i])
}

/// The heatmap's top, shared by every blendshape of the session so colours compare across
/// the list: the largest correction, at least 0.1 mm.
pub fn heatmap_max_mm(session: &StudioSession) -> f32 {
    session.correction_mm.iter().copied().fold(0.1, f32::max)
}

/// The blendshapes the list shows, in order, filtered by `filter` (case-insensitive).
pub fn listed(session: &StudioSession, order: ListOrder, filter: &str) -> Vec<usize> {
    let filter = filter.trim().to_ascii_lowercase();
    let all = match order {
        ListOrder::ByCorrection => session.by_correction_size(),
        ListOrder::ByIndex => (0..NUM_BLENDSHAPES).collect(),
    };
    all.into_iter()
        .filter(|&i| filter.is_empty() || ICT_NAMES[i].to_ascii_lowercase().contains(&filter))
        .collect()
}

impl BlendshapePanel {
    /// Forgets the session's GPU state (a new session was opened).
    pub fn clear(&mut self) {
        self.gpu = None;
    }

    /// Advances the weight sweep.
    pub fn advance(&mut self, dt_secs: f64) {
        if self.playing {
            self.play_secs += dt_secs.clamp(0.0, 0.1);
            // 2 s per sweep, eased so the extremes hold briefly.
            self.preview_weight =
                (0.5 - 0.5 * (self.play_secs * std::f64::consts::PI).cos()) as f32;
        }
    }

    /// The searchable list, with the correction size of each row; clicking selects.
    pub fn list_ui(&mut self, ui: &mut egui::Ui, session: &StudioSession, selected: &mut usize) {
        ui.horizontal(|ui| {
            let label = ui.label("Search");
            ui.text_edit_singleline(&mut self.filter)
                .labelled_by(label.id);
        });
        ui.horizontal(|ui| {
            ui.label("Sort");
            ui.selectable_value(&mut self.order, ListOrder::ByCorrection, "by correction");
            ui.selectable_value(&mut self.order, ListOrder::ByIndex, "by index");
        });
        ui.label("Largest |F(A_i dS_i)| over the vertices");
        ui.separator();
        let max = heatmap_max_mm(session);
        let rows = listed(session, self.order, &self.filter);
        list_rows(ui, rows.len(), |ui, row| {
            let i = rows[row];
            ui.horizontal(|ui| {
                // A bar in proportion to the correction, so the list reads at a glance.
                let (rect, _) =
                    ui.allocate_exact_size(egui::vec2(40.0, 10.0), egui::Sense::hover());
                let filled = rect.width() * (session.correction_mm[i] / max).clamp(0.0, 1.0);
                ui.painter()
                    .rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
                ui.painter().rect_filled(
                    egui::Rect::from_min_size(rect.min, egui::vec2(filled, rect.height())),
                    2.0,
                    egui::Color32::from_rgb(230, 150, 60),
                );
                if ui
                    .selectable_label(*selected == i, row_label(session, i))
                    .clicked()
                {
                    *selected = i;
                }
            });
        });
    }

    /// Template, personalized and heatmap (or mask) views of blendshape `i`. Returns an
    /// error message for the studio's notices (toasts).
    #[allow(clippy::too_many_arguments)]
    pub fn views_ui(
        &mut self,
        ui: &mut egui::Ui,
        rs: &egui_wgpu::RenderState,
        template_face: &mut FaceRenderer,
        scene: &Scene,
        session: &Arc<StudioSession>,
        i: usize,
        orbit: &mut Orbit,
    ) -> Option<String> {
        let i = i.min(NUM_BLENDSHAPES - 1);
        // Measured before the header: a header wider than the panel would widen the ui.
        let panel_width = ui.available_width();
        ui.horizontal_wrapped(|ui| {
            ui.strong(ICT_NAMES[i]);
            ui.label(format!(
                "personal correction up to {:.2} mm",
                session.correction_mm[i]
            ));
            ui.separator();
            ui.add(egui::Slider::new(&mut self.preview_weight, 0.0..=1.0).text("Weight"));
            ui.checkbox(&mut self.playing, "Sweep the weight");
            ui.checkbox(&mut self.show_mask, "Show the attention mask");
        });
        if self.playing {
            ui.ctx().request_repaint();
        }
        if let Err(e) = self.prepare(rs, scene, session, i) {
            return Some(e);
        }
        let gpu = self.gpu.as_mut()?;
        let mut weights = [0.0f32; NUM_BLENDSHAPES];
        weights[i] = self.preview_weight.clamp(0.0, 1.0);
        if let Err(e) = template_face.set_weights(&rs.queue, &weights) {
            return Some(e.to_string());
        }
        if let Err(e) = gpu.face.set_weights(&rs.queue, &weights) {
            return Some(e.to_string());
        }

        let captions = [
            "Template S_i".to_owned(),
            "Personalized S_i + F(A_i dS_i)".to_owned(),
            if self.show_mask {
                "Attention mask A_i".to_owned()
            } else {
                "Correction |F(A_i dS_i)| at weight 1".to_owned()
            },
        ];
        let spacing = ui.spacing().item_spacing.x;
        let bar_height = 22.0;
        let width = ((panel_width - 2.0 * spacing) / 3.0).floor().max(16.0);
        let height = (ui.available_height()
            - ui.text_style_height(&egui::TextStyle::Body)
            - bar_height
            - 12.0)
            .max(16.0);
        let size = [width as u32, height as u32];
        let max_mm = heatmap_max_mm(session);
        let base = frame_params(StudioView::Shaded, orbit, size[0], size[1]);
        let third = FrameParams {
            view: if self.show_mask {
                ViewMode::MaskHeatmap
            } else {
                ViewMode::VertexHeatmap
            },
            heatmap_max: max_mm,
            ..base.clone()
        };
        let mut ids = [egui::TextureId::default(); 3];
        for (k, (face, params)) in [
            (&*template_face, &base),
            (&gpu.face, &base),
            (&gpu.face, &third),
        ]
        .into_iter()
        .enumerate()
        {
            ids[k] = self.targets[k].render(rs, face, size, params, "blendshape view");
        }

        ui.horizontal(|ui| {
            for (k, id) in ids.into_iter().enumerate() {
                ui.vertical(|ui| {
                    ui.set_width(width);
                    ui.label(&captions[k]);
                    let response = ui.add(
                        egui::Image::new((id, egui::vec2(width, height)))
                            .sense(egui::Sense::drag()),
                    );
                    orbit_input(ui, &response, orbit);
                    if k == 2 {
                        self.colour_bar_ui(ui, max_mm);
                    }
                });
            }
        });
        None
    }

    /// Builds the personalized renderer for a new session and uploads what the selection
    /// and weight need.
    fn prepare(
        &mut self,
        rs: &egui_wgpu::RenderState,
        scene: &Scene,
        session: &Arc<StudioSession>,
        i: usize,
    ) -> Result<(), String> {
        let id = Arc::as_ptr(session) as usize;
        if self.gpu.as_ref().is_none_or(|g| g.session != id) {
            let face = person_renderer(rs, scene, &session.blendshapes, "personalized view")?;
            self.gpu = Some(PersonalGpu {
                session: id,
                face,
                uploaded: None,
                albedo_for: None,
            });
        }
        let Some(gpu) = self.gpu.as_mut() else {
            return Ok(());
        };
        if gpu.uploaded != Some(i) {
            let mm: Vec<f32> = session
                .blendshapes
                .correction_magnitude(&scene.model.template, i)
                .into_iter()
                .map(|cm| cm * 10.0)
                .collect();
            gpu.face
                .set_vertex_scalars(&rs.queue, Some(&mm))
                .map_err(|e| e.to_string())?;
            gpu.face
                .set_uv_mask(&rs.queue, Some(scene.mask(i)))
                .map_err(|e| e.to_string())?;
            gpu.uploaded = Some(i);
        }
        let weight = self.preview_weight.clamp(0.0, 1.0);
        if gpu.albedo_for != Some((i, weight.to_bits())) {
            let mut weights = BlendshapeWeights::default();
            weights.0[i] = weight;
            upload_person_albedo(rs, &mut gpu.face, scene, &session.corrections, &weights)
                .map_err(|e| format!("personal albedo: {e}"))?;
            gpu.albedo_for = Some((i, weight.to_bits()));
        }
        Ok(())
    }

    fn colour_bar_ui(&mut self, ui: &mut egui::Ui, max_mm: f32) {
        let bar = self.bar.get_or_insert_with(|| {
            // The renderer's heatmaps use turbo.
            let image = colour_bar(256, 12, |t| {
                colorous::TURBO.eval_continuous(f64::from(t)).as_array()
            });
            ui.ctx().load_texture(
                "colour bar turbo",
                egui::ColorImage::from_rgba_unmultiplied([256, 12], image.as_raw()),
                egui::TextureOptions::LINEAR,
            )
        });
        ui.horizontal(|ui| {
            if self.show_mask {
                ui.label("0");
                ui.add(egui::Image::new((bar.id(), egui::vec2(160.0, 12.0))));
                ui.label("1");
            } else {
                ui.label("0 mm");
                ui.add(egui::Image::new((bar.id(), egui::vec2(160.0, 12.0))));
                ui.label(format!("{max_mm:.2} mm"));
            }
        });
    }
}
