//! The frame-rate floor of an eframe + wgpu window on this machine, without the studio:
//! a window that draws `clips` clipped rectangles (one egui draw call each) and repaints
//! continuously, timed with the studio's own probe. It tells what the window system and
//! the adapter cost before any studio work (`cargo run --release --example present_floor
//! -- 1280x720 0 [vsync]`, with DISPLAY set).

use std::time::{Duration, Instant};

use likeness::fps_probe::FpsProbe;

struct Floor {
    clips: usize,
    /// Whether the panel paints its own fill over the whole window.
    fill: bool,
    /// Dropped once the measurement ends: the window draws a few more frames while closing.
    probe: Option<FpsProbe>,
}

impl eframe::App for Floor {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        visuals.panel_fill.to_normalized_gamma_f32()
    }

    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        let ctx = ui.ctx().clone();
        ctx.request_repaint();
        if self.probe.as_mut().is_some_and(|p| p.frame(Instant::now())) {
            self.probe = None;
            ctx.send_viewport_cmd(egui::ViewportCommand::Close);
        }
        // The window is cleared to the panel colour, so the panel paints no fill: what
        // remains is the clear, the heading's text and the presentation.
        egui::CentralPanel::default()
            .frame(if self.fill {
                egui::Frame::central_panel(ui.style()).fill(egui::Color32::from_gray(30))
            } else {
                egui::Frame::central_panel(ui.style()).fill(egui::Color32::TRANSPARENT)
            })
            .show(ui, |ui| {
                ui.heading("present floor");
                let full = ui.max_rect();
                let painter = ui.painter();
                for k in 0..self.clips {
                    let x = full.left() + (k % 20) as f32 * 60.0;
                    let y = full.top() + 40.0 + (k / 20) as f32 * 30.0;
                    let rect = egui::Rect::from_min_size(egui::pos2(x, y), egui::vec2(50.0, 20.0));
                    painter.with_clip_rect(rect).rect_filled(
                        rect.expand(5.0),
                        2.0,
                        egui::Color32::from_rgb(40, 90, 160),
                    );
                }
            });
    }
}

fn main() -> eframe::Result {
    let args: Vec<String> = std::env::args().collect();
    let size = args.get(1).map_or("1280x720", String::as_str);
    let (w, h) = size
        .split_once('x')
        .and_then(|(w, h)| Some((w.parse::<f32>().ok()?, h.parse::<f32>().ok()?)))
        .unwrap_or((1280.0, 720.0));
    let clips = args.get(2).and_then(|c| c.parse().ok()).unwrap_or(0);
    let flag = |name: &str| args.iter().skip(3).any(|a| a == name);
    let vsync = flag("vsync");
    let fill = flag("fill");
    let dithering = flag("dither");
    let probe = FpsProbe::new("floor", Duration::from_secs(2), Duration::from_secs(5));
    let report = probe.report.clone();
    let options = eframe::NativeOptions {
        renderer: eframe::Renderer::Wgpu,
        wgpu_options: likeness::studio_shots::window_wgpu_configuration(vsync),
        viewport: egui::ViewportBuilder::default().with_inner_size([w, h]),
        dithering,
        ..Default::default()
    };
    eframe::run_native(
        "present floor",
        options,
        Box::new(move |_cc| {
            Ok(Box::new(Floor {
                clips,
                fill,
                probe: Some(probe),
            }))
        }),
    )?;
    if let Ok(Some(r)) = report.lock().map(|r| r.clone()) {
        println!(
            "{size} clips {clips} fill {fill} dithering {dithering} vsync {vsync}: {:.1} fps, median {:.1} ms, p95 {:.1} ms",
            r.fps(),
            r.median_ms,
            r.p95_ms
        );
    }
    Ok(())
}
