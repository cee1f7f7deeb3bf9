//! The studio's lighting and motion panel: the frame's spherical-harmonics lighting gamma
//! shown on a grey sphere, and the tracked weight curves over time (chosen channels, ICT
//! or ARKit names) with the playhead; clicking the plot moves the playhead.

use face::{ARKIT_NAMES, ICT_NAMES};
use glam::Vec3;
use image::{Rgba, RgbaImage};

use crate::studio_session::StudioSession;

/// Albedo of the sphere the lighting is shown on (mid grey, display-encoded).
const SPHERE_ALBEDO: f32 = 0.7;

/// A sphere lit by `gamma` (27 SH coefficients, the renderer's and tracker's convention),
/// `size` pixels across, seen from +z with y up; transparent outside the disc.
pub fn sh_sphere_image(gamma: &[f32; 27], size: u32) -> RgbaImage {
    let size = size.max(2);
    let mut out = RgbaImage::new(size, size);
    let half = size as f32 / 2.0;
    for (x, y, px) in out.enumerate_pixels_mut() {
        let u = (x as f32 + 0.5 - half) / half;
        let v = (half - (y as f32 + 0.5)) / half;
        let r2 = u * u + v * v;
        if r2 > 1.0 {
            *px = Rgba([0, 0, 0, 0]);
            continue;
        }
        let normal = Vec3::new(u, v, (1.0 - r2).sqrt());
        let c = face::sh::shade(Vec3::splat(SPHERE_ALBEDO), normal, gamma);
        let q = |x: f32| (x.clamp(0.0, 1.0) * 255.0).round() as u8;
        *px = Rgba([q(c.x), q(c.y), q(c.z), 255]);
    }
    out
}

/// Which curves the plot shows.
pub struct MotionPanel {
    /// Show ARKit's 52 channels instead of ICT's 53.
    pub arkit: bool,
    /// Selected channels, indices into the chosen name list.
    pub channels: Vec<usize>,
    sphere: Option<(usize, egui::TextureHandle)>,
}

impl Default for MotionPanel {
    fn default() -> Self {
        let channels = ["jawOpen", "mouthSmile_L", "eyeBlink_L", "browInnerUp_L"]
            .iter()
            .filter_map(|n| face::names::ict_index(n))
            .collect();
        Self {
            arkit: false,
            channels,
            sphere: None,
        }
    }
}

impl MotionPanel {
    pub fn names(&self) -> &'static [&'static str] {
        if self.arkit { &ARKIT_NAMES } else { &ICT_NAMES }
    }

    /// Switches the name list, keeping the channels that exist in both.
    pub fn set_arkit(&mut self, arkit: bool) {
        if arkit == self.arkit {
            return;
        }
        // ARKit channel a is driven by the ICT shapes `arkit_sources(a)`.
        self.channels = self
            .channels
            .iter()
            .filter_map(|&c| {
                if arkit {
                    (0..face::NUM_ARKIT).find(|&a| face::names::arkit_sources(a).contains(&c))
                } else {
                    face::names::arkit_sources(c).first().copied()
                }
            })
            .collect();
        self.channels.dedup();
        self.arkit = arkit;
    }

    /// The curve of channel `c` (of the current name list): (time s, weight) per frame with
    /// a face.
    pub fn curve(&self, session: &StudioSession, c: usize) -> Vec<[f64; 2]> {
        session
            .records
            .iter()
            .filter_map(|r| {
                let t = r.track.as_ref()?;
                let values = if self.arkit {
                    &t.arkit_weights
                } else {
                    &t.weights
                };
                Some([r.time_s, f64::from(*values.get(c)?)])
            })
            .collect()
    }

    /// Returns a frame to jump to when the plot is clicked.
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        session: &StudioSession,
        frame: usize,
    ) -> Option<usize> {
        let mut jump = None;
        // Wrapped: many chosen channels must not widen the panel past the window.
        ui.horizontal_wrapped(|ui| {
            let mut arkit = self.arkit;
            ui.label("Names");
            ui.selectable_value(&mut arkit, false, "ICT");
            ui.selectable_value(&mut arkit, true, "ARKit");
            self.set_arkit(arkit);
            ui.separator();
            let names = self.names();
            egui::ComboBox::from_label("Add channel")
                .selected_text("choose")
                .show_ui(ui, |ui| {
                    for (i, name) in names.iter().enumerate() {
                        if !self.channels.contains(&i)
                            && ui.selectable_label(false, *name).clicked()
                        {
                            self.channels.push(i);
                        }
                    }
                });
            let mut removed = None;
            for (k, &c) in self.channels.iter().enumerate() {
                if ui
                    .button(format!("{} x", names.get(c).copied().unwrap_or("?")))
                    .on_hover_text("Remove this curve")
                    .clicked()
                {
                    removed = Some(k);
                }
            }
            if let Some(k) = removed {
                self.channels.remove(k);
            }
        });
        ui.horizontal_top(|ui| {
            // The lighting of this frame on a sphere.
            let gamma = session
                .records
                .get(frame)
                .and_then(|r| r.track.as_ref())
                .and_then(|t| <[f32; 27]>::try_from(t.sh.as_slice()).ok());
            ui.vertical(|ui| {
                ui.label("Lighting (SH)");
                match gamma {
                    Some(gamma) => {
                        if self
                            .sphere
                            .as_ref()
                            .is_none_or(|(shown, _)| *shown != frame)
                        {
                            let image = sh_sphere_image(&gamma, 160);
                            let color = egui::ColorImage::from_rgba_unmultiplied(
                                [160, 160],
                                image.as_raw(),
                            );
                            match self.sphere.as_mut() {
                                Some((shown, texture)) => {
                                    texture.set(color, egui::TextureOptions::LINEAR);
                                    *shown = frame;
                                }
                                None => {
                                    let texture = ui.ctx().load_texture(
                                        "sh sphere",
                                        color,
                                        egui::TextureOptions::LINEAR,
                                    );
                                    self.sphere = Some((frame, texture));
                                }
                            }
                        }
                        if let Some((_, texture)) = &self.sphere {
                            ui.add(egui::Image::new((texture.id(), egui::vec2(160.0, 160.0))));
                        }
                    }
                    None => {
                        ui.label("no face in this frame");
                    }
                }
            });
            let names = self.names();
            let playhead = frame as f64 / session.fps.max(1e-6);
            // A plot in a horizontal layout would take the window's whole width.
            let (width, height) = (ui.available_width(), ui.available_height());
            let response = egui_plot::Plot::new("weight curves")
                .width(width.max(100.0))
                .height(height.max(100.0))
                .legend(egui_plot::Legend::default())
                .include_y(0.0)
                .include_y(1.0)
                .allow_scroll(false)
                .show(ui, |plot| {
                    for &c in &self.channels {
                        let name = names.get(c).copied().unwrap_or("?");
                        plot.line(egui_plot::Line::new(name, self.curve(session, c)).width(1.5));
                    }
                    plot.vline(egui_plot::VLine::new("playhead", playhead));
                    plot.pointer_coordinate()
                });
            if response.response.clicked()
                && let Some(p) = response.inner
            {
                let k = (p.x * session.fps).round().max(0.0) as usize;
                jump = Some(k.min(session.frame_count().saturating_sub(1)));
            }
        });
        jump
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_light_shades_the_sphere_evenly_and_a_key_light_from_the_left_lights_the_left() {
        let even = sh_sphere_image(&face::sh::constant_light(0.8), 64);
        let centre = even.get_pixel(32, 32).0;
        let near_rim = even.get_pixel(4, 32).0;
        assert_eq!(centre[3], 255);
        for c in 0..3 {
            assert!((i32::from(centre[c]) - i32::from(near_rim[c])).abs() <= 1);
        }
        assert_eq!(
            even.get_pixel(0, 0).0[3],
            0,
            "outside the disc is transparent"
        );
        let left = face::sh::directional_light(Vec3::new(-1.0, 0.0, 0.3).normalize(), [1.0; 3]);
        let lit = sh_sphere_image(&left, 64);
        assert!(lit.get_pixel(8, 32).0[0] > lit.get_pixel(56, 32).0[0]);
    }

    #[test]
    fn switching_names_keeps_the_channels_both_lists_have() {
        let mut panel = MotionPanel::default();
        let jaw_ict = face::names::ict_index("jawOpen").expect("jawOpen");
        assert!(panel.channels.contains(&jaw_ict));
        panel.set_arkit(true);
        let jaw_arkit = face::names::arkit_index("jawOpen").expect("jawOpen");
        assert!(panel.channels.contains(&jaw_arkit));
        assert_eq!(panel.channels.len(), 4);
        panel.set_arkit(false);
        assert!(panel.channels.contains(&jaw_ict));
    }
}
