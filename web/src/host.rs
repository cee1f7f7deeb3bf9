//! The page's side of [`WebHost`]: a file input, downloads through a Blob URL, video frames
//! from a `<video>` element drawn onto a canvas, and the webcam through `getUserMedia`.
//! Everything the browser answers asynchronously lands in shared slots that the studio
//! reads on its next frame.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::Arc;
use tracking::bundle::NetworkBytes;
use tracking::pipeline::LocatorChoice;

use image::RgbImage;
use likeness::web_host::{CameraFrame, PickedFile, VideoFrames, WebHost};
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;
use wasm_bindgen_futures::JsFuture;

use crate::page::js_error;
use crate::worker::{LocatorWorker, WorkerFiles};

/// Frame rate assumed for video files: the browser does not tell a file's own.
const VIDEO_FPS: f64 = 30.0;

#[derive(Default)]
struct Camera {
    state: Option<CameraFrame>,
    video: Option<web_sys::HtmlVideoElement>,
    stream: Option<web_sys::MediaStream>,
    /// The video time of the last frame handed out, so a frame is never tracked twice.
    last_time: f64,
}

pub struct PageHost {
    picked: Rc<RefCell<Vec<PickedFile>>>,
    video: Rc<RefCell<Option<VideoFrames>>>,
    camera: Rc<RefCell<Camera>>,
    /// The networks, whose locator models the face-locating worker gets.
    networks: Option<Arc<NetworkBytes>>,
    /// Which Face Mesh points make the 68 landmarks
    /// ([`tracking::mediapipe::ibug68_points_to_f32s`]): the worker has no template to work
    /// them out; `None` without MediaPipe's models.
    mediapipe_points: Option<Vec<f32>>,
    /// The worker of the locator the last job asked for, started then; or why it could not
    /// start (it is not tried again for that locator: jobs then locate faces on the page's
    /// thread). A job that asks for the other locator replaces it (a job still using it
    /// keeps it alive until it ends): one worker at a time, as the page has one core to
    /// spare.
    locator: RefCell<Option<LocatorSlot>>,
}

/// The locator worker a [`PageHost`] keeps, for the locator it runs.
type LocatorSlot = (WorkerKind, Result<Rc<LocatorWorker>, String>);

/// Which locator a worker runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum WorkerKind {
    OpenSeeFace,
    MediaPipe,
}

impl PageHost {
    /// The host for `networks`; `template` places MediaPipe's 68 points.
    pub fn new(networks: Option<Arc<NetworkBytes>>, template: &face::Template) -> Self {
        let mediapipe_points = networks
            .as_ref()
            .and_then(|n| n.mediapipe.as_ref())
            .and_then(|m| match m.correspondence.ibug68_points(template) {
                Ok(points) => Some(tracking::mediapipe::ibug68_points_to_f32s(&points)),
                Err(e) => {
                    tracing::warn!("no MediaPipe worker: {e}");
                    None
                }
            });
        Self {
            picked: Rc::default(),
            video: Rc::default(),
            camera: Rc::default(),
            networks,
            mediapipe_points,
            locator: RefCell::new(None),
        }
    }

    /// The files a worker running `kind` starts from; `None` when the page lacks them.
    fn worker_files(&self, kind: WorkerKind) -> Option<WorkerFiles> {
        let networks = self.networks.as_ref()?;
        Some(match kind {
            WorkerKind::OpenSeeFace => {
                let (detector, landmarks) = networks.openseeface.as_ref()?;
                WorkerFiles::OpenSeeFace {
                    detector: detector.bytes.clone(),
                    landmarks: landmarks.bytes.clone(),
                }
            }
            WorkerKind::MediaPipe => {
                let mediapipe = networks.mediapipe.as_ref()?;
                WorkerFiles::MediaPipe {
                    detector: mediapipe.detector.bytes.clone(),
                    mesh: mediapipe.mesh.bytes.clone(),
                    points: self.mediapipe_points.clone()?,
                }
            }
        })
    }
}

fn document() -> Option<web_sys::Document> {
    web_sys::window().and_then(|w| w.document())
}

/// A new element of the page's document, as its `web_sys` type.
fn create<T: JsCast>(tag: &str) -> Result<T, String> {
    document()
        .ok_or("no document")?
        .create_element(tag)
        .map_err(|e| js_error(&e))?
        .dyn_into()
        .map_err(|_| format!("<{tag}> is not the expected element"))
}

thread_local! {
    /// The canvas frames are drawn on to read their pixels (one, reused: a camera at 30 fps
    /// would otherwise make 30 canvases a second).
    static GRAB_CANVAS: RefCell<Option<web_sys::CanvasRenderingContext2d>> = const { RefCell::new(None) };
}

/// Reads a browser `File` (or `Blob`) into bytes.
async fn blob_bytes(blob: &web_sys::Blob) -> Result<Vec<u8>, String> {
    let buffer = JsFuture::from(blob.array_buffer())
        .await
        .map_err(|e| js_error(&e))?;
    Ok(js_sys::Uint8Array::new(&buffer).to_vec())
}

/// Draws `source` (a video element) at `width` x `height` and reads the pixels back.
fn grab(source: &web_sys::HtmlVideoElement, width: u32, height: u32) -> Result<RgbImage, String> {
    let context = GRAB_CANVAS.with(|slot| -> Result<_, String> {
        if let Some(context) = slot.borrow().as_ref() {
            return Ok(context.clone());
        }
        let canvas: web_sys::HtmlCanvasElement = create("canvas")?;
        let context: web_sys::CanvasRenderingContext2d = canvas
            .get_context("2d")
            .map_err(|e| js_error(&e))?
            .ok_or("no 2D context")?
            .dyn_into()
            .map_err(|_| "not a 2D context")?;
        *slot.borrow_mut() = Some(context.clone());
        Ok(context)
    })?;
    let canvas = context.canvas().ok_or("the 2D context has no canvas")?;
    if canvas.width() != width || canvas.height() != height {
        canvas.set_width(width);
        canvas.set_height(height);
    }
    context
        .draw_image_with_html_video_element_and_dw_and_dh(
            source,
            0.0,
            0.0,
            f64::from(width),
            f64::from(height),
        )
        .map_err(|e| js_error(&e))?;
    let data = context
        .get_image_data(0.0, 0.0, f64::from(width), f64::from(height))
        .map_err(|e| js_error(&e))?
        .data();
    let rgb: Vec<u8> = data
        .chunks_exact(4)
        .flat_map(|p| [p[0], p[1], p[2]])
        .collect();
    RgbImage::from_raw(width, height, rgb).ok_or_else(|| "frame size mismatch".to_owned())
}

/// Resolves when `target` fires `event` (or `error`, as an error).
async fn once(target: &web_sys::EventTarget, event: &str) -> Result<(), String> {
    let promise = js_sys::Promise::new(&mut |resolve, reject| {
        let options = web_sys::AddEventListenerOptions::new();
        options.set_once(true);
        let _ = target.add_event_listener_with_callback_and_add_event_listener_options(
            event, &resolve, &options,
        );
        let _ = target.add_event_listener_with_callback_and_add_event_listener_options(
            "error", &reject, &options,
        );
    });
    JsFuture::from(promise)
        .await
        .map(|_| ())
        .map_err(|_| format!("the browser could not {event} the video"))
}

/// Decodes a video file by seeking a `<video>` element frame by frame.
async fn decode_video(
    bytes: Rc<[u8]>,
    max_frames: usize,
    slot: Rc<RefCell<Option<VideoFrames>>>,
) -> Result<(), String> {
    let array = js_sys::Uint8Array::from(&bytes[..]);
    let parts = js_sys::Array::of1(&array);
    let blob = web_sys::Blob::new_with_u8_array_sequence(&parts).map_err(|e| js_error(&e))?;
    let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(|e| js_error(&e))?;
    let video: web_sys::HtmlVideoElement = create("video")?;
    video.set_muted(true);
    video.set_preload("auto");
    video.set_src(&url);
    let result = async {
        once(&video, "loadeddata").await?;
        let (width, height) = (video.video_width(), video.video_height());
        if width == 0 || height == 0 {
            return Err("the browser cannot decode this video".to_owned());
        }
        let (width, height) = crate::fitted_frame_size(width, height);
        let duration = video.duration();
        let total = if duration.is_finite() && duration > 0.0 {
            ((duration * VIDEO_FPS).floor() as usize).clamp(1, max_frames)
        } else {
            max_frames
        };
        let mut frames = Vec::with_capacity(total);
        for k in 0..total {
            let t = k as f64 / VIDEO_FPS;
            if k > 0 {
                video.set_current_time(t);
                once(&video, "seeked").await?;
            }
            frames.push(grab(&video, width, height)?);
            *slot.borrow_mut() = Some(VideoFrames::Decoding {
                done: frames.len(),
                total: Some(total),
            });
        }
        Ok(frames)
    }
    .await;
    let _ = web_sys::Url::revoke_object_url(&url);
    let frames = result?;
    *slot.borrow_mut() = Some(VideoFrames::Done {
        frames,
        fps: VIDEO_FPS,
    });
    Ok(())
}

async fn start_camera(camera: Rc<RefCell<Camera>>) -> Result<(), String> {
    let window = web_sys::window().ok_or("no window")?;
    let devices = window
        .navigator()
        .media_devices()
        .map_err(|_| "this browser has no camera access (navigator.mediaDevices)")?;
    let constraints = web_sys::MediaStreamConstraints::new();
    constraints.set_video(&JsValue::TRUE);
    let promise = devices
        .get_user_media_with_constraints(&constraints)
        .map_err(|e| js_error(&e))?;
    let stream: web_sys::MediaStream = JsFuture::from(promise)
        .await
        .map_err(|e| format!("the camera could not start: {}", js_error(&e)))?
        .dyn_into()
        .map_err(|_| "not a media stream")?;
    let video: web_sys::HtmlVideoElement = create("video")?;
    video.set_muted(true);
    video.set_src_object(Some(&stream));
    let _ = JsFuture::from(video.play().map_err(|e| js_error(&e))?)
        .await
        .map_err(|e| format!("the camera stream does not play: {}", js_error(&e)))?;
    let mut camera = camera.borrow_mut();
    camera.video = Some(video);
    camera.stream = Some(stream);
    camera.state = Some(CameraFrame::Waiting);
    Ok(())
}

impl PageHost {
    /// The face-locating worker: `None` before a job asked for it, then whether it runs
    /// or why it stopped.
    pub fn worker_state(&self) -> Option<Result<(), String>> {
        match &self.locator.borrow().as_ref()?.1 {
            Ok(worker) => Some(worker.failed().map_or(Ok(()), Err)),
            Err(reason) => Some(Err(reason.clone())),
        }
    }
}

impl WebHost for PageHost {
    fn face_locator(
        &self,
        locator: LocatorChoice,
    ) -> Option<Box<dyn likeness::stepped::RemoteFaceLocator>> {
        let kind = match locator {
            LocatorChoice::PreCropped => return None,
            LocatorChoice::MediaPipe => WorkerKind::MediaPipe,
            LocatorChoice::Landmarks | LocatorChoice::Auto => WorkerKind::OpenSeeFace,
        };
        let mut slot = self.locator.borrow_mut();
        if slot.as_ref().is_none_or(|(running, _)| *running != kind) {
            let started = LocatorWorker::start(self.worker_files(kind)?);
            if let Err(e) = &started {
                tracing::warn!(
                    "no face-locating worker ({e}); faces are located on the page's thread"
                );
            }
            *slot = Some((kind, started.map(Rc::new)));
        }
        // A worker that stopped, or never started, stays so: jobs locate faces here.
        match slot.as_ref()? {
            (_, Ok(worker)) if worker.failed().is_none() => Some(Box::new(worker.channel())),
            _ => None,
        }
    }

    fn pick_files(&self, accept: &str) {
        let input: web_sys::HtmlInputElement = match create("input") {
            Ok(input) => input,
            Err(e) => {
                tracing::error!("cannot open the file picker: {e}");
                return;
            }
        };
        input.set_type("file");
        input.set_multiple(true);
        input.set_accept(accept);
        let picked = self.picked.clone();
        let chosen = input.clone();
        let on_change = Closure::once(move || {
            let Some(files) = chosen.files() else {
                return;
            };
            for i in 0..files.length() {
                let Some(file) = files.get(i) else { continue };
                let picked = picked.clone();
                wasm_bindgen_futures::spawn_local(async move {
                    match blob_bytes(&file).await {
                        Ok(bytes) => picked.borrow_mut().push(PickedFile {
                            name: file.name(),
                            bytes: bytes.into(),
                        }),
                        Err(e) => tracing::error!("{}: {e}", file.name()),
                    }
                });
            }
        });
        input.set_onchange(Some(on_change.as_ref().unchecked_ref()));
        on_change.forget();
        input.click();
    }

    fn read_dropped(&self, files: Vec<egui::DroppedFileHandle>) {
        for file in files {
            let picked = self.picked.clone();
            wasm_bindgen_futures::spawn_local(async move {
                let name = file.path().file_name().map_or_else(
                    || file.path().display().to_string(),
                    |n| n.to_string_lossy().into_owned(),
                );
                match file.bytes_async().await {
                    Ok(bytes) => picked.borrow_mut().push(PickedFile {
                        name,
                        bytes: bytes.into(),
                    }),
                    Err(e) => tracing::error!("{name}: {e}"),
                }
            });
        }
    }

    fn take_picked_files(&self) -> Vec<PickedFile> {
        std::mem::take(&mut *self.picked.borrow_mut())
    }

    fn download(&self, name: &str, mime: &str, bytes: &[u8]) -> Result<(), String> {
        let array = js_sys::Uint8Array::from(bytes);
        let parts = js_sys::Array::of1(&array);
        let options = web_sys::BlobPropertyBag::new();
        options.set_type(mime);
        let blob = web_sys::Blob::new_with_u8_array_sequence_and_options(&parts, &options)
            .map_err(|e| js_error(&e))?;
        let url = web_sys::Url::create_object_url_with_blob(&blob).map_err(|e| js_error(&e))?;
        let anchor: web_sys::HtmlAnchorElement = create("a")?;
        anchor.set_href(&url);
        anchor.set_download(name);
        anchor.click();
        let _ = web_sys::Url::revoke_object_url(&url);
        Ok(())
    }

    fn decode_video(&self, file: &PickedFile, max_frames: usize) {
        *self.video.borrow_mut() = Some(VideoFrames::Decoding {
            done: 0,
            total: None,
        });
        let slot = self.video.clone();
        let bytes: Rc<[u8]> = Rc::from(&file.bytes[..]);
        wasm_bindgen_futures::spawn_local(async move {
            if let Err(e) = decode_video(bytes, max_frames.max(1), slot.clone()).await {
                *slot.borrow_mut() = Some(VideoFrames::Failed(e));
            }
        });
    }

    fn video_frames(&self) -> Option<VideoFrames> {
        let mut slot = self.video.borrow_mut();
        match slot.as_ref()? {
            // The frames are handed over once.
            VideoFrames::Done { .. } | VideoFrames::Failed(_) => slot.take(),
            decoding => Some(decoding.clone()),
        }
    }

    fn start_camera(&self) {
        {
            let mut camera = self.camera.borrow_mut();
            camera.state = Some(CameraFrame::Starting);
            camera.last_time = -1.0;
        }
        let camera = self.camera.clone();
        wasm_bindgen_futures::spawn_local(async move {
            if let Err(e) = start_camera(camera.clone()).await {
                camera.borrow_mut().state = Some(CameraFrame::Failed(e));
            }
        });
    }

    fn camera_frame(&self) -> CameraFrame {
        let mut camera = self.camera.borrow_mut();
        match &camera.state {
            None => return CameraFrame::Failed("the camera was not started".into()),
            Some(CameraFrame::Waiting) => {}
            Some(other) => return other.clone(),
        }
        let Some(video) = camera.video.clone() else {
            return CameraFrame::Waiting;
        };
        let time = video.current_time();
        // HAVE_CURRENT_DATA: a frame can be drawn.
        if video.ready_state() < 2 || time == camera.last_time {
            return CameraFrame::Waiting;
        }
        camera.last_time = time;
        let (width, height) = crate::fitted_frame_size(video.video_width(), video.video_height());
        match grab(&video, width, height) {
            Ok(image) => CameraFrame::Frame(image),
            Err(e) => CameraFrame::Failed(e),
        }
    }

    fn stop_camera(&self) {
        let mut camera = self.camera.borrow_mut();
        if let Some(stream) = camera.stream.take() {
            for track in stream.get_tracks().iter() {
                if let Ok(track) = track.dyn_into::<web_sys::MediaStreamTrack>() {
                    track.stop();
                }
            }
        }
        camera.video = None;
        camera.state = None;
    }
}
