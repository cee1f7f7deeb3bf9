//! The face-locating Web Worker: the face locator (OpenSeeFace's detector and landmarks, or
//! MediaPipe's BlazeFace and Face Mesh) runs in a second instance of this wasm module
//! (`worker.js` loads it) while the page's thread crops, runs TrackNet and refines the
//! frame before, so the two halves of a frame overlap on two cores as the native
//! pipeline's threads do. wasm32 without shared memory has no threads, and a worker is how
//! a page gets a second core; frames go over as transferred buffers and located faces come
//! back as numbers ([`LocatedFace::to_f32s`]).
//!
//! Page side: [`LocatorWorker`] starts the worker and hands each job a [`WorkerChannel`]
//! (the app's [`RemoteFaceLocator`]). Worker side: [`FaceLocatorWorker`], called by
//! `worker.js`.

use std::cell::RefCell;
use std::collections::{HashMap, VecDeque};
use std::rc::Rc;
use std::sync::Arc;

use image::RgbImage;
use likeness::stepped::{LocatorReply, RemoteFaceLocator};
use tracking::TrackingError;
use tracking::bundle::NamedBytes;
use tracking::mediapipe::MeshFollower;
use tracking::openseeface::FaceFollower;
use tracking::pipeline::LocatedFace;
use wasm_bindgen::JsCast;
use wasm_bindgen::prelude::*;

use crate::page::{js_error, js_set};

/// The worker's script, beside `index.html`.
const WORKER_URL: &str = "./worker.js";

// --- worker side ---------------------------------------------------------------------------

/// Boxed: the two followers differ a lot in size and a worker holds one.
enum Follower {
    OpenSeeFace(Box<FaceFollower>),
    MediaPipe(Box<MeshFollower>),
}

/// A face locator following one face, frame after frame, in the worker.
#[wasm_bindgen]
pub struct FaceLocatorWorker {
    follower: Follower,
}

fn js(error: impl std::fmt::Display) -> JsError {
    JsError::new(&error.to_string())
}

#[wasm_bindgen]
impl FaceLocatorWorker {
    /// OpenSeeFace's follower from the `_plain_b1` detector and landmark network's bytes.
    #[wasm_bindgen(constructor)]
    pub fn new(detector: Vec<u8>, landmarks: Vec<u8>) -> Result<FaceLocatorWorker, JsError> {
        console_error_panic_hook::set_once();
        let detector = NamedBytes::new(crate::DETECTOR.url, detector);
        let landmarks = NamedBytes::new(crate::LANDMARKS.url, landmarks);
        let follower = tracking::bundle::face_follower(&detector, &landmarks).map_err(js)?;
        Ok(Self {
            follower: Follower::OpenSeeFace(Box::new(follower)),
        })
    }

    /// MediaPipe's follower from BlazeFace's and Face Mesh's bytes; `points`: which Face
    /// Mesh points make the 68 landmarks
    /// ([`tracking::mediapipe::ibug68_points_to_f32s`], worked out by the page, which has the
    /// template).
    pub fn mediapipe(
        detector: Vec<u8>,
        mesh: Vec<u8>,
        points: Vec<f32>,
    ) -> Result<FaceLocatorWorker, JsError> {
        console_error_panic_hook::set_once();
        let detector = NamedBytes::new(crate::MEDIAPIPE_DETECTOR.url, detector);
        let mesh = NamedBytes::new(crate::MEDIAPIPE_MESH.url, mesh);
        let points = tracking::mediapipe::ibug68_points_from_f32s(&points).map_err(js)?;
        let follower = tracking::bundle::mesh_follower(&detector, &mesh, points).map_err(js)?;
        Ok(Self {
            follower: Follower::MediaPipe(Box::new(follower)),
        })
    }

    /// The face in the next frame (`width` x `height` RGB bytes) as
    /// [`LocatedFace::to_f32s`]'s numbers, or nothing when the frame shows none; `reset`
    /// forgets the face followed so far. Throws the tracking error of a frame that cannot
    /// be located.
    pub fn locate(
        &mut self,
        rgb: Vec<u8>,
        width: u32,
        height: u32,
        reset: bool,
    ) -> Result<Option<Vec<f32>>, JsError> {
        tracking::source::check_frame_size(width, height).map_err(js)?;
        let got = rgb.len();
        let image = RgbImage::from_raw(width, height, rgb).ok_or_else(|| {
            let needed = u64::from(width) * u64::from(height) * 3;
            JsError::new(&format!(
                "a {width}x{height} RGB frame has {needed} bytes, not {got}"
            ))
        })?;
        let located = match &mut self.follower {
            Follower::OpenSeeFace(follower) => {
                if reset {
                    follower.reset();
                }
                LocatedFace::follow(follower, &image)
            }
            Follower::MediaPipe(follower) => {
                if reset {
                    follower.reset();
                }
                LocatedFace::follow_mesh(follower, &image)
            }
        };
        located
            .map(|found| found.map(|face| face.to_f32s()))
            .map_err(js)
    }
}

// --- page side -----------------------------------------------------------------------------

/// What a worker starts from.
pub enum WorkerFiles {
    /// OpenSeeFace's `_plain_b1` detector and landmark network.
    OpenSeeFace {
        detector: Arc<[u8]>,
        landmarks: Arc<[u8]>,
    },
    /// BlazeFace, Face Mesh and which points make the 68 landmarks.
    MediaPipe {
        detector: Arc<[u8]>,
        mesh: Arc<[u8]>,
        points: Vec<f32>,
    },
}

/// Answers from the worker, sorted by job.
#[derive(Default)]
struct Replies {
    by_channel: HashMap<u32, VecDeque<LocatorReply>>,
    /// Why the worker stopped, once it has.
    failed: Option<String>,
    next_channel: u32,
}

/// The page's face-locating worker, shared by the jobs (one at a time, in practice).
pub struct LocatorWorker {
    worker: web_sys::Worker,
    replies: Rc<RefCell<Replies>>,
    _on_message: Closure<dyn FnMut(web_sys::MessageEvent)>,
    _on_error: Closure<dyn FnMut(web_sys::Event)>,
}

fn get(object: &JsValue, key: &str) -> JsValue {
    js_sys::Reflect::get(object, &key.into()).unwrap_or(JsValue::UNDEFINED)
}

impl LocatorWorker {
    /// Starts `worker.js` with this page's wasm module and a locator's files.
    pub fn start(files: WorkerFiles) -> Result<Self, String> {
        let options = web_sys::WorkerOptions::new();
        options.set_type(web_sys::WorkerType::Module);
        let worker = web_sys::Worker::new_with_options(WORKER_URL, &options)
            .map_err(|e| format!("{WORKER_URL}: {}", js_error(&e)))?;
        let replies = Rc::new(RefCell::new(Replies::default()));
        let on_message = {
            let replies = replies.clone();
            Closure::<dyn FnMut(_)>::new(move |event: web_sys::MessageEvent| {
                receive(&mut replies.borrow_mut(), &event.data());
            })
        };
        let on_error = {
            let replies = replies.clone();
            // A script that fails to load sends a plain `Event`, one that throws an
            // `ErrorEvent` with a message.
            Closure::<dyn FnMut(_)>::new(move |event: web_sys::Event| {
                let message = get(&event, "message")
                    .as_string()
                    .filter(|m| !m.is_empty())
                    .unwrap_or_else(|| "the script did not load".into());
                let reason = format!("{WORKER_URL}: {message}");
                tracing::error!("the face-locating worker stopped: {reason}");
                replies.borrow_mut().failed.get_or_insert(reason);
            })
        };
        worker.set_onmessage(Some(on_message.as_ref().unchecked_ref()));
        worker.set_onerror(Some(on_error.as_ref().unchecked_ref()));
        // The compiled module goes along, so the worker instantiates without fetching and
        // compiling the 27 MB again.
        let init = js_sys::Object::new();
        js_set(&init, "kind", "init");
        js_set(&init, "module", wasm_bindgen::module());
        match &files {
            WorkerFiles::OpenSeeFace {
                detector,
                landmarks,
            } => {
                js_set(&init, "locator", "openseeface");
                js_set(&init, "detector", js_sys::Uint8Array::from(&detector[..]));
                js_set(&init, "landmarks", js_sys::Uint8Array::from(&landmarks[..]));
            }
            WorkerFiles::MediaPipe {
                detector,
                mesh,
                points,
            } => {
                js_set(&init, "locator", "mediapipe");
                js_set(&init, "detector", js_sys::Uint8Array::from(&detector[..]));
                js_set(&init, "mesh", js_sys::Uint8Array::from(&mesh[..]));
                js_set(&init, "points", js_sys::Float32Array::from(&points[..]));
            }
        }
        worker
            .post_message(&init)
            .map_err(|e| format!("the face-locating worker: {}", js_error(&e)))?;
        Ok(Self {
            worker,
            replies,
            _on_message: on_message,
            _on_error: on_error,
        })
    }

    /// Why the worker stopped, if it has.
    pub fn failed(&self) -> Option<String> {
        self.replies.borrow().failed.clone()
    }

    /// A channel for one job: its frames' answers come to it alone, in order.
    pub fn channel(self: &Rc<Self>) -> WorkerChannel {
        let mut replies = self.replies.borrow_mut();
        let id = replies.next_channel;
        replies.next_channel += 1;
        replies.by_channel.insert(id, VecDeque::new());
        WorkerChannel {
            id,
            worker: self.clone(),
        }
    }
}

impl Drop for LocatorWorker {
    fn drop(&mut self) {
        self.worker.terminate();
    }
}

/// One message from the worker: `{kind: "located", channel, located?, error?}` or
/// `{kind: "failed", error}`.
fn receive(replies: &mut Replies, data: &JsValue) {
    let kind = get(data, "kind").as_string().unwrap_or_default();
    let error = get(data, "error").as_string();
    match kind.as_str() {
        "located" => {
            let Some(channel) = get(data, "channel").as_f64() else {
                return;
            };
            // Answers for a job that is gone (stopped, replaced) are dropped.
            let Some(queue) = replies.by_channel.get_mut(&(channel as u32)) else {
                return;
            };
            let located = match error {
                Some(error) => Err(TrackingError::Relayed(error)),
                None => {
                    let numbers = get(data, "located");
                    if numbers.is_null() || numbers.is_undefined() {
                        Ok(None)
                    } else {
                        match numbers.dyn_into::<js_sys::Float32Array>() {
                            Ok(array) => LocatedFace::from_f32s(&array.to_vec()).map(Some),
                            Err(_) => Err(TrackingError::Relayed(
                                "the face-locating worker sent something other than numbers".into(),
                            )),
                        }
                    }
                }
            };
            queue.push_back(LocatorReply::Located(located));
        }
        "failed" => {
            let reason = error.unwrap_or_else(|| "it gave no reason".into());
            tracing::error!("the face-locating worker stopped: {reason}");
            replies.failed.get_or_insert(reason);
        }
        _ => {}
    }
}

/// One job's use of the worker.
pub struct WorkerChannel {
    id: u32,
    worker: Rc<LocatorWorker>,
}

impl RemoteFaceLocator for WorkerChannel {
    fn send(&mut self, image: &RgbImage, reset: bool) -> Result<(), String> {
        if let Some(reason) = self.worker.failed() {
            return Err(reason);
        }
        let pixels = js_sys::Uint8Array::from(image.as_raw().as_slice());
        let buffer = pixels.buffer();
        let message = js_sys::Object::new();
        js_set(&message, "kind", "frame");
        js_set(&message, "channel", self.id);
        js_set(&message, "width", image.width());
        js_set(&message, "height", image.height());
        js_set(&message, "reset", reset);
        js_set(&message, "pixels", buffer.clone());
        // Transferred, not copied: the page keeps its own copy of the frame.
        self.worker
            .worker
            .post_message_with_transfer(&message, &js_sys::Array::of1(&buffer))
            .map_err(|e| format!("the face-locating worker: {}", js_error(&e)))
    }

    fn receive(&mut self) -> Option<LocatorReply> {
        let mut replies = self.worker.replies.borrow_mut();
        if let Some(reply) = replies
            .by_channel
            .get_mut(&self.id)
            .and_then(|queue| queue.pop_front())
        {
            return Some(reply);
        }
        replies.failed.clone().map(LocatorReply::Failed)
    }
}

impl Drop for WorkerChannel {
    fn drop(&mut self) {
        self.worker.replies.borrow_mut().by_channel.remove(&self.id);
    }
}
