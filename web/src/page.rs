//! The page: fetches what the studio needs, starts the studio on the canvas, and keeps
//! `window.likeness` (what the page reports: status, timings, tracking rate) up to date.

use std::cell::{Cell, RefCell};
use std::path::Path;
use std::rc::Rc;
use std::sync::Arc;

use likeness::scene::Scene;
use likeness::studio::StudioApp;
use likeness::web_host::WebHost;
use tracking::bundle::{NamedBytes, NetworkBytes};
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;
use wasm_bindgen_futures::JsFuture;

use crate::bench::BenchState;
use crate::host::PageHost;
use crate::{
    Asset, Fetched, OPTIONAL_ASSETS, REQUIRED_ASSETS, missing_message, optional_missing_note,
};

/// `window.likeness`: what the page reports, read by people (the status line) and by the
/// end-to-end test.
struct Report {
    object: js_sys::Object,
}

impl Report {
    fn new() -> Self {
        let object = js_sys::Object::new();
        if let Some(window) = web_sys::window() {
            let _ = js_sys::Reflect::set(&window, &"likeness".into(), &object);
        }
        Self { object }
    }

    /// The `window.likeness` [`Report::new`] made (a new one if there is none).
    fn new_shared() -> Self {
        let object = web_sys::window()
            .and_then(|w| js_sys::Reflect::get(&w, &"likeness".into()).ok())
            .and_then(|v| v.dyn_into::<js_sys::Object>().ok())
            .unwrap_or_default();
        Self { object }
    }

    fn set(&self, key: &str, value: impl Into<JsValue>) {
        js_set(&self.object, key, value);
    }

    /// The status line under the canvas, and `window.likeness.status`.
    fn status(&self, text: &str, is_error: bool) {
        self.set("status", text);
        if is_error {
            self.set("error", text);
        }
        if let Some(element) = web_sys::window()
            .and_then(|w| w.document())
            .and_then(|d| d.get_element_by_id("status"))
        {
            element.set_text_content(Some(text));
            let _ = element.set_attribute("class", if is_error { "error" } else { "" });
        }
    }
}

/// `object[key] = value`. Setting a property of a plain object the page made cannot fail.
pub(crate) fn js_set(object: &js_sys::Object, key: &str, value: impl Into<JsValue>) {
    let _ = js_sys::Reflect::set(object, &key.into(), &value.into());
}

fn now_ms() -> f64 {
    web_sys::window()
        .and_then(|w| w.performance())
        .map_or(0.0, |p| p.now())
}

/// Fetches `url`: `Ok(None)` when the server says it is not there (404), an error for
/// anything else that goes wrong.
async fn fetch_bytes(url: &str) -> Result<Option<Vec<u8>>, String> {
    let window = web_sys::window().ok_or("no window")?;
    let response = JsFuture::from(window.fetch_with_str(url))
        .await
        .map_err(|e| format!("{url}: {}", js_error(&e)))?;
    let response: web_sys::Response = response
        .dyn_into()
        .map_err(|_| format!("{url}: not a response"))?;
    if response.status() == 404 {
        return Ok(None);
    }
    if !response.ok() {
        return Err(format!("{url}: HTTP {}", response.status()));
    }
    let buffer = JsFuture::from(
        response
            .array_buffer()
            .map_err(|e| format!("{url}: {}", js_error(&e)))?,
    )
    .await
    .map_err(|e| format!("{url}: {}", js_error(&e)))?;
    Ok(Some(js_sys::Uint8Array::new(&buffer).to_vec()))
}

pub(crate) fn js_error(value: &JsValue) -> String {
    value
        .dyn_ref::<js_sys::Error>()
        .map(|e| String::from(e.message()))
        .or_else(|| value.as_string())
        .unwrap_or_else(|| format!("{value:?}"))
}

/// Yields to the browser for `ms` milliseconds (at least until its next task).
pub(crate) async fn sleep(ms: i32) {
    let promise = js_sys::Promise::new(&mut |resolve, _| {
        if let Some(window) = web_sys::window() {
            let _ = window.set_timeout_with_callback_and_timeout_and_arguments_0(&resolve, ms);
        }
    });
    let _ = JsFuture::from(promise).await;
}

#[wasm_bindgen(start)]
pub fn start() {
    // The face-locating worker instantiates this module too; it has no page to run.
    if web_sys::window().is_none() {
        return;
    }
    // A panic is the page's error too (the test and the status line see it), then the
    // console's, with its stack.
    std::panic::set_hook(Box::new(|info| {
        let report = Report::new_shared();
        report.status(&format!("Likeness stopped: {info}"), true);
        console_error_panic_hook::hook(info);
    }));
    tracing_wasm::set_as_global_default();
    wasm_bindgen_futures::spawn_local(async {
        let report = Report::new();
        if let Err(e) = run(&report).await {
            report.status(&e, true);
        }
    });
}

/// Fetches each of `assets` into `fetched`, saying which is loading; returns those the
/// server does not have.
async fn fetch_into(
    assets: &[Asset],
    fetched: &mut Fetched,
    report: &Report,
) -> Result<Vec<Asset>, String> {
    let mut missing = Vec::new();
    for &asset in assets {
        report.status(&format!("loading {}...", asset.url), false);
        match fetch_bytes(asset.url).await? {
            Some(bytes) => fetched.insert(asset, bytes),
            None => missing.push(asset),
        }
    }
    Ok(missing)
}

async fn run(report: &Report) -> Result<(), String> {
    report.set("startedMs", now_ms());
    let mut fetched = Fetched::default();
    let missing = fetch_into(&REQUIRED_ASSETS, &mut fetched, report).await?;
    if !missing.is_empty() {
        return Err(missing_message(&missing));
    }
    let optional_missing = fetch_into(&OPTIONAL_ASSETS, &mut fetched, report).await?;
    if !optional_missing.is_empty() {
        tracing::info!("{}", optional_missing_note(&optional_missing));
    }
    report.set("assetsMs", now_ms());
    report.status("reading the face template...", false);
    // The status line is drawn before the long synchronous step.
    sleep(0).await;
    let scene = make_scene(&mut fetched)?;
    report.set("sceneMs", now_ms());
    report.status("starting the studio...", false);
    let canvas = web_sys::window()
        .and_then(|w| w.document())
        .and_then(|d| d.get_element_by_id("likeness"))
        .and_then(|e| e.dyn_into::<web_sys::HtmlCanvasElement>().ok())
        .ok_or("the page has no <canvas id=\"likeness\">")?;
    let puppet = fetched.take(&crate::DEMO_PUPPET);
    report.set(
        "mediapipeLocator",
        scene
            .networks
            .as_ref()
            .is_some_and(|n| n.mediapipe.is_some()),
    );
    let page_networks = scene.networks.clone();
    let runner = eframe::WebRunner::new();
    let options = eframe::WebOptions::default();
    let scene = Arc::new(scene);
    let started = Rc::new(Cell::new(false));
    let started_in_app = started.clone();
    runner
        .start(
            canvas,
            options,
            Box::new(move |cc| {
                let mut studio = StudioApp::new(cc, scene.clone());
                let page_host = Rc::new(PageHost::new(page_networks, &scene.model.template));
                let host: Rc<dyn WebHost> = page_host.clone();
                studio.web_host = Some(host.clone());
                let bench = Rc::new(RefCell::new(BenchState::default()));
                let report = Report::new_shared();
                crate::bench::install(&report.object, bench.clone(), cc.egui_ctx.clone());
                if let Some(bytes) = puppet {
                    studio.puppet_panel.demo_puppet_bytes = Some(likeness::web_host::PickedFile {
                        name: crate::DEMO_PUPPET.url.to_owned(),
                        bytes: bytes.into(),
                    });
                }
                let backend = match cc.wgpu_render_state.as_ref() {
                    Some(rs) => {
                        let info = rs.adapter.get_info();
                        let backend = format!("{:?} ({})", info.backend, info.name);
                        studio.start_demo_in_steps(rs);
                        backend
                    }
                    None => "none".to_owned(),
                };
                started_in_app.set(true);
                Ok(Box::new(WebStudio {
                    studio,
                    scene,
                    host,
                    page_host,
                    bench,
                    report,
                    backend,
                    frames: 0,
                    demo_reported: false,
                    shown_session: None,
                }))
            }),
        )
        .await
        .map_err(|e| format!("the studio could not start: {}", js_error(&e)))?;
    if !started.get() {
        return Err("the studio could not start".into());
    }
    // The runner lives as long as the page.
    std::mem::forget(runner);
    Ok(())
}

/// The template and networks from fetched bytes.
fn make_scene(fetched: &mut Fetched) -> Result<Scene, String> {
    let template_bytes = fetched
        .take(&crate::TEMPLATE)
        .ok_or("the template was not fetched")?;
    let template =
        face::Template::from_safetensors_bytes(&template_bytes, Path::new(crate::TEMPLATE.url))
            .map_err(|e| format!("{}: {e}", crate::TEMPLATE.url))?;
    let manifest_text = fetched
        .take(&crate::MANIFEST)
        .ok_or("the manifest was not fetched")?;
    let manifest_text = String::from_utf8(manifest_text)
        .map_err(|_| format!("{}: not UTF-8 text", crate::MANIFEST.url))?;
    let manifest = tracking::networks::Manifest::from_json(Path::new("models"), &manifest_text)
        .map_err(|e| e.to_string())?;
    // The browser runs its own TrackNet (crate::TRACK_NET), whose size the manifest gives.
    let expected = crate::TRACK_NET.url.trim_start_matches("models/");
    match &manifest.web_track_net {
        Some(web) if web.file == expected => {}
        other => {
            return Err(format!(
                "{}: names {} as the browser's TrackNet, the page fetches {expected}; export the models again (python -m likeness_train.export)",
                crate::MANIFEST.url,
                other.as_ref().map_or("no file", |w| w.file.as_str())
            ));
        }
    }
    let manifest = manifest.for_web();
    let mediapipe = mediapipe_bytes(fetched, &template);
    let mut named = |asset: &Asset| -> Result<NamedBytes, String> {
        let bytes = fetched
            .take(asset)
            .ok_or_else(|| format!("{} was not fetched", asset.url))?;
        Ok(NamedBytes::new(asset.url, bytes))
    };
    let networks = NetworkBytes {
        track_net: named(&crate::TRACK_NET)?,
        model_net: named(&crate::MODEL_NET)?,
        mean_albedo: named(&crate::MEAN_ALBEDO)?,
        openseeface: Some((named(&crate::DETECTOR)?, named(&crate::LANDMARKS)?)),
        mediapipe,
        manifest,
    };
    let mut scene = Scene::from_template(template);
    scene.networks = Some(Arc::new(networks));
    Ok(scene)
}

/// MediaPipe's locator when all its files were fetched and fit the template; otherwise
/// `None` (said in the console): the studio then offers OpenSeeFace's only.
fn mediapipe_bytes(
    fetched: &mut Fetched,
    template: &face::Template,
) -> Option<tracking::bundle::MediaPipeBytes> {
    let mut take = |asset: &Asset| {
        fetched
            .take(asset)
            .map(|bytes| NamedBytes::new(asset.url, bytes))
    };
    let detector = take(&crate::MEDIAPIPE_DETECTOR)?;
    let mesh = take(&crate::MEDIAPIPE_MESH)?;
    let correspondence = take(&crate::MEDIAPIPE_CORRESPONDENCE)?;
    let checked = tracking::bundle::MediaPipeBytes::from_bytes(detector, mesh, &correspondence)
        .and_then(|bytes| {
            // The worker gets these points; a correspondence that does not fit the template
            // is refused here, once, rather than on the first frame.
            bytes.correspondence.ibug68_points(template)?;
            Ok(bytes)
        });
    match checked {
        Ok(bytes) => Some(bytes),
        Err(e) => {
            tracing::warn!("MediaPipe's face locator is not offered: {e}");
            None
        }
    }
}

/// Mean milliseconds per frame in each stage of tracking.
pub(crate) fn stage_ms(rate: &likeness::stepped::TrackingRate) -> js_sys::Object {
    let n = rate.frames.max(1) as f64;
    let t = &rate.stage_ms;
    let stages = js_sys::Object::new();
    for (name, ms) in [
        ("detect", t.detect_ms),
        ("landmarks", t.landmarks_ms),
        ("crop", t.crop_ms),
        ("tracknet", t.tracknet_ms),
        ("refine", t.refine_ms),
        ("smooth", t.smooth_ms),
    ] {
        js_set(&stages, name, ms / n);
    }
    stages
}

/// The studio with the page's reporting around it.
struct WebStudio {
    studio: StudioApp,
    scene: Arc<Scene>,
    host: Rc<dyn WebHost>,
    page_host: Rc<PageHost>,
    bench: Rc<RefCell<BenchState>>,
    report: Report,
    backend: String,
    frames: u64,
    demo_reported: bool,
    /// The session the status line last named (source, frames).
    shown_session: Option<(String, usize)>,
}

impl eframe::App for WebStudio {
    fn clear_color(&self, visuals: &egui::Visuals) -> [f32; 4] {
        self.studio.clear_color(visuals)
    }

    fn save(&mut self, storage: &mut dyn eframe::Storage) {
        self.studio.save(storage);
    }

    fn ui(&mut self, ui: &mut egui::Ui, frame: &mut eframe::Frame) {
        if self.bench.borrow().running {
            // The benchmark has the page's thread to itself; nothing asks for a repaint.
            ui.centered_and_justified(|ui| ui.heading("measuring the tracking rate..."));
            return;
        }
        self.studio.ui(ui, frame);
        let demo_frames = || {
            self.studio
                .session()
                .filter(|s| s.source == likeness::studio_session::DEMO_SOURCE)
                .map(|s| s.frames.clone())
        };
        crate::bench::start_if_requested(
            &self.bench,
            &self.scene,
            &self.host,
            demo_frames,
            ui.ctx(),
        );
        self.frames += 1;
        if self.frames == 1 {
            self.report.set("firstFrameMs", now_ms());
            self.report.set("backend", self.backend.as_str());
            self.report
                .status(&format!("studio running on {}", self.backend), false);
        }
        self.report.set("frames", self.frames as f64);
        self.report.set(
            "worker",
            match self.page_host.worker_state() {
                None => "not started".to_owned(),
                Some(Ok(())) => "running".to_owned(),
                Some(Err(reason)) => format!("stopped: {reason}"),
            },
        );
        // What the studio holds now, for people reading the page and for the tests.
        match self.studio.session() {
            Some(session) => {
                self.report.set("sessionSource", session.source.as_str());
                self.report
                    .set("sessionFrames", session.frame_count() as f64);
            }
            None => self.report.set("sessionSource", JsValue::NULL),
        }
        let puppet = self
            .studio
            .puppet_panel
            .puppet
            .as_ref()
            .map(|p| p.path.display().to_string());
        self.report
            .set("puppet", puppet.map_or(JsValue::NULL, JsValue::from));
        match self.studio.job() {
            Some(job) => self.report.set(
                "job",
                format!(
                    "{}: {} {}",
                    job.input, job.progress.stage, job.progress.done
                ),
            ),
            None => self.report.set("job", JsValue::NULL),
        }
        if let Some(job) = self.studio.demo_job() {
            let p = &job.progress;
            let total = p.total.map_or(String::new(), |t| format!(" / {t}"));
            self.report
                .status(&format!("demo: {} {}{total}", p.stage, p.done), false);
        }
        if let Some(job) = self.studio.job() {
            self.report.status(
                &format!(
                    "{}: {} {}",
                    job.input, job.progress.stage, job.progress.done
                ),
                false,
            );
        } else if let Some(session) = self.studio.session()
            && self.demo_reported
        {
            let shown = (session.source.clone(), session.frame_count());
            if self.shown_session.as_ref() != Some(&shown) {
                self.report
                    .status(&format!("session: {}, {} frames", shown.0, shown.1), false);
                self.shown_session = Some(shown);
            }
        }
        if !self.demo_reported
            && let Some(session) = self
                .studio
                .session()
                .filter(|s| s.source == likeness::studio_session::DEMO_SOURCE)
        {
            self.demo_reported = true;
            // The status line keeps the demo's numbers until the session changes.
            self.shown_session = Some((session.source.clone(), session.frame_count()));
            self.report.set("demoReadyMs", now_ms());
            self.report
                .set("sessionFrames", session.frame_count() as f64);
            if let Some(rate) = self.studio.tracking_rate {
                self.report.set("trackedFrames", rate.frames as f64);
                self.report.set("trackingSeconds", rate.seconds);
                self.report.set("trackingWallSeconds", rate.wall_seconds);
                if let Some(fps) = rate.wall_fps() {
                    self.report.set("trackingWallFps", fps);
                }
                self.report.set("trackingStageMs", stage_ms(&rate));
                if let Some(fps) = rate.fps() {
                    self.report.set("trackingFps", fps);
                }
            }
            self.report.status(
                &format!(
                    "demo ready: {} frames tracked at {:.1} fps on {}",
                    session.frame_count(),
                    self.studio
                        .tracking_rate
                        .and_then(|r| r.fps())
                        .unwrap_or(0.0),
                    self.backend
                ),
                false,
            );
        }
        // An error shown in the studio is also the page's, for the test to see.
        if let Some(error) = self.studio.state.notices.latest_error() {
            self.report.set("lastError", error);
        }
    }

    fn on_exit(&mut self) {
        self.studio.on_exit();
    }
}
