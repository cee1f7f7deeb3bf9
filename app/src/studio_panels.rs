//! The studio's 2D panels over a [`StudioSession`]: the input frame with its overlay and
//! the timeline. Functions that draw egui end in `_ui`; they read the session and change
//! only the [`PlaybackState`] they are given.

use egui::{Color32, Pos2, Rect, Stroke, StrokeKind, Vec2};

use crate::studio_session::{FrameOverlay, StudioSession};

/// Which frame is shown and whether it advances by itself.
#[derive(Clone, Debug, PartialEq)]
pub struct PlaybackState {
    pub frame: usize,
    pub playing: bool,
    /// Time carried over between UI frames, in seconds, so playback keeps the footage's
    /// rate whatever the display's.
    pub carry_secs: f64,
    pub show_detected: bool,
    pub show_model: bool,
    pub show_boxes: bool,
}

impl Default for PlaybackState {
    fn default() -> Self {
        Self {
            frame: 0,
            playing: false,
            carry_secs: 0.0,
            show_detected: true,
            show_model: true,
            show_boxes: true,
        }
    }
}

impl PlaybackState {
    /// Advances by `dt_secs` of wall time at `fps`, looping at `frames`.
    pub fn advance(&mut self, dt_secs: f64, fps: f64, frames: usize) {
        if !self.playing || frames == 0 || fps <= 0.0 {
            return;
        }
        self.carry_secs += dt_secs.clamp(0.0, 0.25);
        let step = 1.0 / fps;
        while self.carry_secs >= step {
            self.carry_secs -= step;
            self.frame = (self.frame + 1) % frames;
        }
    }

    pub fn step(&mut self, delta: isize, frames: usize) {
        if frames == 0 {
            return;
        }
        self.playing = false;
        self.frame = (self.frame as isize + delta).rem_euclid(frames as isize) as usize;
    }
}

/// A scrolled list of `rows` rows, each one widget high, of which only the rows in view are
/// laid out and drawn. The side lists have 53 rows, and on a software rasteriser every row
/// drawn costs frame time (README, "Studio frame rate").
pub fn list_rows(ui: &mut egui::Ui, rows: usize, mut row: impl FnMut(&mut egui::Ui, usize)) {
    let height = ui.spacing().interact_size.y;
    egui::ScrollArea::vertical().show_rows(ui, height, rows, |ui, range| {
        for k in range {
            row(ui, k);
        }
    });
}

/// Play/pause, previous/next and a scrub slider over the session's frames.
pub fn timeline_ui(ui: &mut egui::Ui, playback: &mut PlaybackState, session: &StudioSession) {
    let frames = session.frame_count();
    ui.horizontal(|ui| {
        if ui.button("Previous").clicked() {
            playback.step(-1, frames);
        }
        let label = if playback.playing { "Pause" } else { "Play" };
        if ui.button(label).clicked() {
            playback.playing = !playback.playing;
        }
        if ui.button("Next").clicked() {
            playback.step(1, frames);
        }
        let last = frames.saturating_sub(1);
        let slider = egui::Slider::new(&mut playback.frame, 0..=last)
            .text("frame")
            .clamping(egui::SliderClamping::Always);
        if ui.add(slider).changed() {
            playback.playing = false;
        }
        ui.label(format!(
            "{:.2} s / {:.2} s",
            playback.frame as f64 / session.fps.max(1e-6),
            frames as f64 / session.fps.max(1e-6)
        ));
    });
}

/// Maps frame pixels into the rectangle the frame is drawn in.
fn to_screen(rect: Rect, frame_size: [u32; 2], p: glam::Vec2) -> Pos2 {
    Pos2::new(
        rect.left() + p.x / frame_size[0].max(1) as f32 * rect.width(),
        rect.top() + p.y / frame_size[1].max(1) as f32 * rect.height(),
    )
}

fn box_rect(rect: Rect, frame_size: [u32; 2], b: [f32; 4]) -> Rect {
    Rect::from_min_max(
        to_screen(rect, frame_size, glam::Vec2::new(b[0], b[1])),
        to_screen(rect, frame_size, glam::Vec2::new(b[0] + b[2], b[1] + b[3])),
    )
}

/// Colours of the overlay, also named in the legend.
pub const DETECTED_COLOUR: Color32 = Color32::from_rgb(255, 196, 0);
pub const MODEL_COLOUR: Color32 = Color32::from_rgb(0, 200, 255);
pub const CROP_COLOUR: Color32 = Color32::from_rgb(160, 160, 160);

/// The overlay of one frame, drawn over `rect` (where the frame image is).
pub fn paint_overlay(
    painter: &egui::Painter,
    rect: Rect,
    frame_size: [u32; 2],
    overlay: &FrameOverlay,
    playback: &PlaybackState,
) {
    let radius = (rect.width() / 320.0).clamp(1.5, 3.5);
    if playback.show_boxes {
        if let Some(crop) = overlay.crop {
            painter.rect_stroke(
                box_rect(rect, frame_size, crop),
                0.0,
                Stroke::new(1.0, CROP_COLOUR),
                StrokeKind::Middle,
            );
        }
        if let Some(face_box) = overlay.face_box {
            let r = box_rect(rect, frame_size, face_box);
            painter.rect_stroke(r, 0.0, Stroke::new(1.5, MODEL_COLOUR), StrokeKind::Middle);
            if let Some(confidence) = overlay.confidence {
                painter.text(
                    r.left_top() - Vec2::new(0.0, 2.0),
                    egui::Align2::LEFT_BOTTOM,
                    format!("confidence {confidence:.2}"),
                    egui::FontId::proportional(12.0),
                    MODEL_COLOUR,
                );
            }
        }
    }
    if playback.show_detected {
        for p in &overlay.detected {
            painter.circle_filled(to_screen(rect, frame_size, *p), radius, DETECTED_COLOUR);
        }
    }
    if playback.show_model {
        for p in &overlay.model {
            painter.circle_stroke(
                to_screen(rect, frame_size, *p),
                radius + 1.0,
                Stroke::new(1.2, MODEL_COLOUR),
            );
        }
    }
}

/// The largest rectangle of the frame's aspect ratio that fits `available`, centred.
pub fn fit_rect(available: Rect, frame_size: [u32; 2]) -> Rect {
    let aspect = frame_size[0].max(1) as f32 / frame_size[1].max(1) as f32;
    let mut size = available.size();
    if size.x / size.y.max(1.0) > aspect {
        size.x = size.y * aspect;
    } else {
        size.y = size.x / aspect;
    }
    Rect::from_center_size(available.center(), size)
}

/// The parts of `outer` that `inner` (inside it, e.g. from [`fit_rect`]) leaves uncovered:
/// the bars above, below, left and right of it, without overlaps. A picture is framed by
/// painting these instead of a full background under it, since on a software rasteriser
/// every pixel egui fills twice costs its time again.
pub fn letterbox_bars(outer: Rect, inner: Rect) -> Vec<Rect> {
    let inner = inner.intersect(outer);
    if !inner.is_positive() {
        return vec![outer];
    }
    let bars = [
        Rect::from_min_max(outer.min, egui::pos2(outer.max.x, inner.min.y)),
        Rect::from_min_max(egui::pos2(outer.min.x, inner.max.y), outer.max),
        Rect::from_min_max(
            egui::pos2(outer.min.x, inner.min.y),
            egui::pos2(inner.min.x, inner.max.y),
        ),
        Rect::from_min_max(
            egui::pos2(inner.max.x, inner.min.y),
            egui::pos2(outer.max.x, inner.max.y),
        ),
    ];
    bars.into_iter().filter(|r| r.is_positive()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn letterbox_bars_cover_exactly_what_the_picture_leaves() {
        let outer = Rect::from_min_size(egui::pos2(10.0, 20.0), egui::vec2(600.0, 400.0));
        // A 4:3 frame in a wider area: bars left and right only.
        let inner = fit_rect(outer, [640, 480]);
        let bars = letterbox_bars(outer, inner);
        assert_eq!(bars.len(), 2);
        let area: f32 = bars.iter().map(|r| r.area()).sum::<f32>() + inner.area();
        assert!((area - outer.area()).abs() < 1e-2, "{area}");
        for (i, a) in bars.iter().enumerate() {
            assert!(!a.intersects(inner.shrink(0.01)));
            for b in &bars[i + 1..] {
                assert!(!a.intersects(b.shrink(0.01)));
            }
        }
        // An off-centre picture leaves all four bars; none when it fills the area.
        let inner = Rect::from_min_size(egui::pos2(20.0, 30.0), egui::vec2(100.0, 100.0));
        let bars = letterbox_bars(outer, inner);
        assert_eq!(bars.len(), 4);
        let area: f32 = bars.iter().map(|r| r.area()).sum::<f32>() + inner.area();
        assert!((area - outer.area()).abs() < 1e-2, "{area}");
        assert!(letterbox_bars(outer, outer).is_empty());
        // No picture: the whole area.
        assert_eq!(letterbox_bars(outer, Rect::NOTHING), vec![outer]);
    }

    #[test]
    fn playback_keeps_the_footage_rate_and_loops() {
        let mut p = PlaybackState {
            playing: true,
            ..PlaybackState::default()
        };
        // 30 fps footage shown at 60 Hz: one frame every two UI frames.
        for _ in 0..4 {
            p.advance(1.0 / 60.0 + 1e-9, 30.0, 10);
        }
        assert_eq!(p.frame, 2);
        // Looping.
        p.frame = 9;
        p.advance(1.0 / 30.0 + 1e-9, 30.0, 10);
        assert_eq!(p.frame, 0);
        // Paused: nothing moves.
        p.playing = false;
        p.advance(1.0, 30.0, 10);
        assert_eq!(p.frame, 0);
        // Stepping pauses and wraps both ways.
        p.playing = true;
        p.step(-1, 10);
        assert_eq!((p.frame, p.playing), (9, false));
        p.step(2, 10);
        assert_eq!(p.frame, 1);
    }

    #[test]
    fn frame_pixels_map_onto_the_drawn_rectangle() {
        let available = Rect::from_min_size(Pos2::new(10.0, 20.0), Vec2::new(800.0, 300.0));
        let rect = fit_rect(available, [640, 480]);
        assert!((rect.width() / rect.height() - 640.0 / 480.0).abs() < 1e-4);
        assert_eq!(rect.height(), 300.0);
        assert_eq!(rect.center(), available.center());
        let corner = to_screen(rect, [640, 480], glam::Vec2::new(640.0, 480.0));
        assert!((corner - rect.right_bottom()).length() < 1e-3);
        let b = box_rect(rect, [640, 480], [0.0, 0.0, 320.0, 240.0]);
        assert!((b.width() - rect.width() / 2.0).abs() < 1e-3);
    }
}
