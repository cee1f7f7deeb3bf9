//! The page's tracking benchmark, `window.likeness.benchTracking(locator)`: the demo clip's
//! frames tracked again, faces found by `locator` (`"openseeface"`, the default, or
//! `"mediapipe"`), through the studio's own job ([`SteppedTracking`], faces located in the
//! worker beside the page's thread) with the studio not drawing meanwhile, timed by the
//! wall clock. In the studio the same job shares the page's thread with drawing, which on
//! a software-rendered canvas (headless Chromium's SwiftShader) costs more than tracking;
//! this measures what tracking alone sustains in the page.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;

use image::RgbImage;
use likeness::demo::DemoConfig;
use likeness::scene::Scene;
use likeness::stepped::{FrameFeed, SteppedTracking, TrackingRate};
use likeness::web_host::WebHost;
use tracking::pipeline::{LocatorChoice, TrackerConfig};
use wasm_bindgen::prelude::*;

use crate::page::js_set;
use wasm_bindgen_futures::JsFuture;
use web_time::{Duration, Instant};

/// What the page's thread shares with the benchmark.
#[derive(Default)]
pub struct BenchState {
    /// `benchTracking()` was called: the locator asked for and the promise's resolve and
    /// reject functions.
    requested: Option<(LocatorChoice, js_sys::Function, js_sys::Function)>,
    /// A benchmark is running: the studio does not draw.
    pub running: bool,
}

/// Installs `window.likeness.benchTracking()` on `report` (`window.likeness`). It returns a
/// promise of the result; the studio starts the run on its next frame (it holds the frames).
pub fn install(report: &js_sys::Object, state: Rc<RefCell<BenchState>>, ctx: egui::Context) {
    let function = Closure::<dyn FnMut(JsValue) -> js_sys::Promise>::new(move |name: JsValue| {
        let state = state.clone();
        let ctx = ctx.clone();
        js_sys::Promise::new(&mut |resolve, reject| {
            let locator = match bench_locator(&name) {
                Ok(locator) => locator,
                Err(e) => {
                    let _ = reject.call1(&JsValue::NULL, &js_sys::Error::new(&e).into());
                    return;
                }
            };
            let mut state = state.borrow_mut();
            if state.running || state.requested.is_some() {
                let _ = reject.call1(
                    &JsValue::NULL,
                    &js_sys::Error::new("a tracking benchmark is already running").into(),
                );
                return;
            }
            state.requested = Some((locator, resolve, reject));
            ctx.request_repaint();
        })
    });
    js_set(report, "benchTracking", function.as_ref().clone());
    // The function lives as long as the page.
    function.forget();
}

/// The locator `benchTracking(name)` names: OpenSeeFace's when none is named.
fn bench_locator(name: &JsValue) -> Result<LocatorChoice, String> {
    if name.is_undefined() || name.is_null() {
        return Ok(LocatorChoice::Landmarks);
    }
    match name.as_string().as_deref() {
        Some("openseeface") => Ok(LocatorChoice::Landmarks),
        Some("mediapipe") => Ok(LocatorChoice::MediaPipe),
        Some(other) => Err(format!(
            "benchTracking: the locator is \"openseeface\" or \"mediapipe\", not {other:?}"
        )),
        None => Err(
            "benchTracking: the locator is \"openseeface\" or \"mediapipe\", not a non-string"
                .into(),
        ),
    }
}

/// Starts a requested benchmark on `frames()` (the demo's clip, copied only then); `None`:
/// there is no demo session yet, and the request is refused.
pub fn start_if_requested(
    state: &Rc<RefCell<BenchState>>,
    scene: &Arc<Scene>,
    host: &Rc<dyn WebHost>,
    frames: impl FnOnce() -> Option<Vec<RgbImage>>,
    ctx: &egui::Context,
) {
    let Some((locator, resolve, reject)) = state.borrow_mut().requested.take() else {
        return;
    };
    let Some(frames) = frames() else {
        let _ = reject.call1(
            &JsValue::NULL,
            &js_sys::Error::new("the demo is not ready: there are no frames to track yet").into(),
        );
        return;
    };
    state.borrow_mut().running = true;
    let (state, scene, host, ctx) = (state.clone(), scene.clone(), host.clone(), ctx.clone());
    wasm_bindgen_futures::spawn_local(async move {
        let result = run(&scene, host.as_ref(), frames, locator).await;
        state.borrow_mut().running = false;
        ctx.request_repaint();
        match result {
            Ok(report) => {
                let _ = resolve.call1(&JsValue::NULL, &report);
            }
            Err(e) => {
                let _ = reject.call1(&JsValue::NULL, &js_sys::Error::new(&e).into());
            }
        }
    });
}

/// Lets the browser run its event loop (the worker's answers arrive there) without a
/// timer's minimum delay, after work was done.
async fn yield_to_browser() {
    let promise = js_sys::Promise::new(&mut |resolve, _| {
        let Ok(channel) = web_sys::MessageChannel::new() else {
            let _ = resolve.call0(&JsValue::NULL);
            return;
        };
        channel.port1().set_onmessage(Some(&resolve));
        let _ = channel.port2().post_message(&JsValue::NULL);
    });
    let _ = JsFuture::from(promise).await;
}

async fn run(
    scene: &Scene,
    host: &dyn WebHost,
    frames: Vec<RgbImage>,
    locator: LocatorChoice,
) -> Result<JsValue, String> {
    let networks = scene
        .networks
        .clone()
        .ok_or("the networks were not loaded")?;
    let face = Arc::new(face::FaceModel::new(scene.model.template.clone()));
    let config = TrackerConfig {
        threads: 1,
        fov_deg: Some(DemoConfig::default().fov_deg),
        locator,
        ..TrackerConfig::default()
    };
    let tracker = networks
        .tracker(face.clone(), config, true)
        .map_err(|e| e.to_string())?;
    let model_net = networks.model_net().map_err(|e| e.to_string())?;
    let clip_frames = frames.len();
    let mut job = SteppedTracking::new(
        face,
        tracker,
        model_net,
        FrameFeed::clip(frames, DemoConfig::default().fps),
        usize::MAX,
        DemoConfig::default().personalize_frames,
    )
    .with_remote_locator(host.face_locator(locator));
    let beside = job.locating_beside();
    let started = Instant::now();
    // The tracking stage only: personalization is not part of the rate.
    while !job.tracking_done() {
        let before = job.rate.frames;
        if let Some(Err(e)) = job.step(Duration::from_millis(50)) {
            return Err(e);
        }
        if started.elapsed() > Duration::from_secs(600) {
            return Err("the benchmark did not finish in 10 minutes".into());
        }
        if job.rate.frames > before {
            yield_to_browser().await;
        } else {
            // Spinning on `yield_to_browser` while waiting would take a core from the
            // worker (and from the browser's compiler threads) on a two-core machine; the
            // worker has frames queued, so waking a few milliseconds late costs it nothing.
            crate::page::sleep(2).await;
        }
    }
    let still_beside = job.locating_beside();
    let found = job.faces_found();
    Ok(report(
        &job.rate,
        clip_frames,
        beside && still_beside,
        locator,
        found,
    ))
}

/// `{locator, frames, clipFrames, facesFound, wallSeconds, fps, locatedInWorker, stageMs:
/// {...}}`.
fn report(
    rate: &TrackingRate,
    clip_frames: usize,
    in_worker: bool,
    locator: LocatorChoice,
    faces_found: usize,
) -> JsValue {
    let object = js_sys::Object::new();
    let name = match locator {
        LocatorChoice::MediaPipe => "mediapipe",
        _ => "openseeface",
    };
    js_set(&object, "locator", name);
    js_set(&object, "facesFound", faces_found as f64);
    js_set(&object, "frames", rate.frames as f64);
    js_set(&object, "clipFrames", clip_frames as f64);
    js_set(&object, "wallSeconds", rate.wall_seconds);
    js_set(&object, "fps", rate.wall_fps().unwrap_or(0.0));
    js_set(&object, "locatedInWorker", in_worker);
    js_set(&object, "stageMs", crate::page::stage_ms(rate));
    object.into()
}
