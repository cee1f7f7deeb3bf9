//! The software-presented window (`likeness::soft_window`) end to end, on its own Xvfb
//! display with lavapipe: what the app paints reaches the window's pixels exactly (an odd
//! width, so readback rows are padded), a square moved across the window leaves no trail
//! (only changed areas are redrawn), the last frame of an animation is shown once the app
//! goes idle, a click from XTEST reaches the app, a close command ends the loop, and
//! the app's settings are read from and saved to eframe's `app.ron`.
//!
//! Not a libtest harness: winit's event loop must own the main thread and can be created
//! once per process, so this is one scenario with a custom `main`.

use std::process::{Child, Command};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use x11rb::connection::Connection;
use x11rb::protocol::xproto::{AtomEnum, ConnectionExt as _, ImageFormat, Window};
use x11rb::protocol::xtest::ConnectionExt as _;

const TITLE: &str = "likeness soft window test";
const APP_ID: &str = "likeness-soft-window-test";
/// Odd on purpose: 301 * 4 bytes is not a multiple of wgpu's 256-byte copy row.
const SIZE: [u16; 2] = [301, 157];
const WHITE: [u8; 3] = [255, 255, 255];
const GREEN: [u8; 3] = [20, 180, 60];
const BLUE: [u8; 3] = [30, 60, 210];
const DEADLINE: Duration = Duration::from_secs(60);

/// What the app shows: a white square moving over green for `ANIMATED_FRAMES` frames, then
/// the same square parked without asking for more frames, all blue once clicked; it closes
/// when the checker is done.
const ANIMATED_FRAMES: u32 = 30;
const PHASE_ANIMATING: u32 = 0;
const PHASE_IDLE: u32 = 1;
const PHASE_CLICKED: u32 = 2;
const PHASE_DONE: u32 = 3;

struct Probe {
    phase: Arc<AtomicU32>,
    frames: u32,
    pixels_per_point: Arc<Mutex<f32>>,
    exited: Arc<AtomicU32>,
}

impl eframe::App for Probe {
    fn ui(&mut self, ui: &mut egui::Ui, _frame: &mut eframe::Frame) {
        self.frames += 1;
        let phase = self.phase.load(Ordering::SeqCst);
        if phase == PHASE_ANIMATING && self.frames >= ANIMATED_FRAMES {
            self.phase.store(PHASE_IDLE, Ordering::SeqCst);
        }
        let phase = self.phase.load(Ordering::SeqCst);
        let rect = ui.ctx().content_rect();
        let colour = |[r, g, b]: [u8; 3]| egui::Color32::from_rgb(r, g, b);
        if phase <= PHASE_IDLE {
            ui.painter().rect_filled(rect, 0.0, colour(GREEN));
            // Its own clip rectangle makes the square a primitive of its own, so moving it
            // damages only where it was and where it is: the background is not redrawn.
            let band =
                egui::Rect::from_min_max(egui::pos2(0.0, 30.0), egui::pos2(rect.max.x, 70.0));
            ui.painter().with_clip_rect(band).rect_filled(
                square(self.frames.min(ANIMATED_FRAMES)),
                0.0,
                colour(WHITE),
            );
        } else {
            ui.painter().rect_filled(rect, 0.0, colour(BLUE));
        }
        *self.pixels_per_point.lock().expect("scale slot") = ui.ctx().pixels_per_point();
        let response = ui.interact(rect, egui::Id::unique("whole window"), egui::Sense::click());
        if response.clicked() && phase == PHASE_IDLE {
            self.phase.store(PHASE_CLICKED, Ordering::SeqCst);
            ui.ctx().request_repaint();
        }
        match phase {
            PHASE_ANIMATING => ui.ctx().request_repaint(),
            PHASE_DONE => ui.ctx().send_viewport_cmd(egui::ViewportCommand::Close),
            _ => {}
        }
    }

    /// Opaque, as the studio's: the window then redraws only what changed (a see-through
    /// clear colour, eframe's default, makes every frame a full redraw).
    fn clear_color(&self, _visuals: &egui::Visuals) -> [f32; 4] {
        [0.0, 0.0, 0.0, 1.0]
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        storage.set_string("probe", format!("saved after {} frames", self.frames));
    }

    fn on_exit(&mut self) {
        self.exited.fetch_add(1, Ordering::SeqCst);
    }
}

/// Where the moving square is drawn at `frame`, in points.
fn square(frame: u32) -> egui::Rect {
    egui::Rect::from_min_size(
        egui::pos2(10.0 + 7.0 * frame as f32, 40.0),
        egui::vec2(20.0, 20.0),
    )
}

/// The Xvfb server, stopped when dropped.
struct Xvfb(Child);

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_xvfb() -> (Xvfb, String) {
    // A display number no other test or session uses.
    let number = 200 + std::process::id() % 500;
    let display = format!(":{number}");
    let child = Command::new("Xvfb")
        .args([
            display.as_str(),
            "-screen",
            "0",
            "640x480x24",
            "-nolisten",
            "tcp",
        ])
        .spawn()
        .unwrap_or_else(|e| {
            panic!("cannot start Xvfb ({e}); scripts/setup.sh installs it (Debian: xvfb)")
        });
    let server = Xvfb(child);
    let started = Instant::now();
    while x11rb::connect(Some(&display)).is_err() {
        assert!(started.elapsed() < DEADLINE, "Xvfb {display} did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
    (server, display)
}

fn find_window(conn: &impl Connection, root: Window) -> Option<Window> {
    let tree = conn.query_tree(root).ok()?.reply().ok()?;
    tree.children.into_iter().find(|&w| {
        conn.get_property(false, w, AtomEnum::WM_NAME, AtomEnum::ANY, 0, 256)
            .ok()
            .and_then(|c| c.reply().ok())
            .is_some_and(|p| p.value == TITLE.as_bytes())
    })
}

/// The window's pixels as RGB rows (the server's 32-bit ZPixmap is B, G, R, pad).
fn window_pixels(conn: &impl Connection, window: Window) -> Option<Vec<[u8; 3]>> {
    let image = conn
        .get_image(ImageFormat::Z_PIXMAP, window, 0, 0, SIZE[0], SIZE[1], !0)
        .ok()?
        .reply()
        .ok()?;
    if image.depth != 24 || image.data.len() != usize::from(SIZE[0]) * usize::from(SIZE[1]) * 4 {
        panic!(
            "unexpected window image: depth {}, {} bytes",
            image.depth,
            image.data.len()
        );
    }
    Some(
        image
            .data
            .chunks_exact(4)
            .map(|p| [p[2], p[1], p[0]])
            .collect(),
    )
}

/// Waits until every pixel of the window is `expected(x, y)`; panics with what it saw.
fn wait_for(
    conn: &impl Connection,
    window: Window,
    expected: impl Fn(usize, usize) -> [u8; 3],
    what: &str,
) {
    let started = Instant::now();
    let mut last = None;
    while started.elapsed() < DEADLINE {
        if let Some(pixels) = window_pixels(conn, window) {
            let width = usize::from(SIZE[0]);
            let wrong: Vec<(usize, usize, [u8; 3])> = pixels
                .iter()
                .enumerate()
                .filter_map(|(i, &p)| {
                    let (x, y) = (i % width, i / width);
                    (p != expected(x, y)).then_some((x, y, p))
                })
                .collect();
            if wrong.is_empty() {
                return;
            }
            last = Some((wrong.len(), wrong[0]));
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    panic!(
        "{what}: the window never showed what was drawn (last: {last:?} = wrong pixels, first wrong x, y, colour)"
    );
}

fn checker(
    display: String,
    phase: Arc<AtomicU32>,
    pixels_per_point: Arc<Mutex<f32>>,
    ctx: Arc<Mutex<Option<egui::Context>>>,
) {
    let (conn, screen) = x11rb::connect(Some(&display)).expect("checker connects to Xvfb");
    let root = conn.setup().roots[screen].root;
    let started = Instant::now();
    let window = loop {
        if let Some(w) = find_window(&conn, root) {
            break w;
        }
        assert!(
            started.elapsed() < DEADLINE,
            "no window titled {TITLE:?} appeared"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    // The animation ends with a frame that asks for no other: it must still be shown, with
    // the square where it stopped and nothing left where it passed.
    let started = Instant::now();
    while phase.load(Ordering::SeqCst) != PHASE_IDLE {
        assert!(started.elapsed() < DEADLINE, "the animation did not end");
        std::thread::sleep(Duration::from_millis(20));
    }
    let scale = *pixels_per_point.lock().expect("scale slot");
    let parked = square(ANIMATED_FRAMES) * scale;
    let in_square = move |x: usize, y: usize| {
        let centre = egui::pos2(x as f32 + 0.5, y as f32 + 0.5);
        if parked.contains(centre) {
            WHITE
        } else {
            GREEN
        }
    };
    wait_for(&conn, window, in_square, "after the animation");
    // A click through XTEST, as a user's: pointer to the window's middle, press, release.
    let geometry = conn
        .translate_coordinates(window, root, SIZE[0] as i16 / 2, SIZE[1] as i16 / 2)
        .expect("translate request")
        .reply()
        .expect("window position");
    const MOTION: u8 = 6;
    const PRESS: u8 = 4;
    const RELEASE: u8 = 5;
    for (kind, detail) in [(MOTION, 0), (PRESS, 1), (RELEASE, 1)] {
        conn.xtest_fake_input(kind, detail, 0, root, geometry.dst_x, geometry.dst_y, 0)
            .expect("fake input request");
        conn.flush().expect("flush");
        std::thread::sleep(Duration::from_millis(100));
    }
    wait_for(&conn, window, |_, _| BLUE, "after the click");
    phase.store(PHASE_DONE, Ordering::SeqCst);
    if let Some(ctx) = ctx.lock().expect("context slot").as_ref() {
        ctx.request_repaint();
    }
}

fn main() {
    let data_home =
        std::env::temp_dir().join(format!("likeness-soft-window-{}", std::process::id()));
    let (server, display) = start_xvfb();
    // SAFETY: set before any other thread of this process exists.
    unsafe {
        std::env::set_var("XDG_DATA_HOME", &data_home);
        std::env::set_var("DISPLAY", &display);
        std::env::remove_var("WAYLAND_DISPLAY");
    }
    let settings = eframe::storage_dir(APP_ID)
        .expect("a settings folder")
        .join("app.ron");
    std::fs::create_dir_all(settings.parent().expect("folder")).expect("settings folder");
    // Written as eframe's window writes it: a RON map of strings.
    std::fs::write(&settings, "{\"probe\": \"written by eframe\"}").expect("seed app.ron");

    let options = likeness::studio_shots::window_renderer_options();
    let mut render_state =
        likeness::studio_shots::headless_render_state(options).expect("a wgpu adapter (lavapipe)");
    likeness::soft_window::retarget_for_soft_window(&mut render_state, options);

    let phase = Arc::new(AtomicU32::new(PHASE_ANIMATING));
    let setting_read = Arc::new(Mutex::new(None));
    let exited = Arc::new(AtomicU32::new(0));
    let ctx_slot = Arc::new(Mutex::new(None));
    let pixels_per_point = Arc::new(Mutex::new(1.0f32));
    let check = {
        let (display, phase, ctx_slot) = (display.clone(), phase.clone(), ctx_slot.clone());
        let scale = pixels_per_point.clone();
        std::thread::spawn(move || checker(display, phase, scale, ctx_slot))
    };
    let viewport = egui::ViewportBuilder::default()
        .with_title(TITLE)
        .with_inner_size([f32::from(SIZE[0]), f32::from(SIZE[1])]);
    let app_phase = phase.clone();
    let app_scale = pixels_per_point.clone();
    let (app_setting, app_exited) = (setting_read.clone(), exited.clone());
    let result =
        likeness::soft_window::run_soft_window(APP_ID, viewport, render_state, move |cc| {
            *ctx_slot.lock().expect("context slot") = Some(cc.egui_ctx.clone());
            *app_setting.lock().expect("setting slot") =
                cc.storage.and_then(|s| s.get_string("probe"));
            Box::new(Probe {
                phase: app_phase,
                frames: 0,
                pixels_per_point: app_scale,
                exited: app_exited,
            })
        });
    if let Err(panic) = check.join() {
        std::panic::resume_unwind(panic);
    }
    result.expect("the window ran and closed without an error");
    assert_eq!(phase.load(Ordering::SeqCst), PHASE_DONE);
    assert_eq!(exited.load(Ordering::SeqCst), 1, "on_exit runs once");
    assert_eq!(
        setting_read.lock().expect("setting").as_deref(),
        Some("written by eframe"),
        "the app reads eframe's app.ron"
    );
    let saved = std::fs::read_to_string(&settings).expect("app.ron after exit");
    let saved: std::collections::HashMap<String, String> =
        ron::from_str(&saved).expect("app.ron is a RON map of strings");
    let probe = saved.get("probe").expect("the app's key was saved");
    assert!(probe.starts_with("saved after "), "saved value: {probe}");
    assert!(
        saved.contains_key("egui"),
        "egui's memory is saved as eframe does"
    );
    drop(server);
    let _ = std::fs::remove_dir_all(&data_home);
    println!("soft window: pixels, no trail, idle frame, click, close and settings round trip: ok");
}
