// The face-locating worker (web/src/worker.rs): a second instance of the page's wasm
// module runs the face locator (OpenSeeFace's detector and landmarks, or MediaPipe's
// BlazeFace and Face Mesh) on the frames the page posts, in the order they come, while the
// page's thread does the rest of each frame.
import init, { FaceLocatorWorker } from "./likeness_web.js";

let locator = null;
// Messages are handled one after another: the init is asynchronous, and frames that come
// meanwhile wait for it.
let queue = Promise.resolve();

self.onmessage = (event) => {
  queue = queue.then(() => handle(event.data));
};

function message(e) {
  return String((e && e.message) || e);
}

// The worker cannot go on (the module did not start, or trapped and is in an unknown
// state): the page is told, and locates faces itself from then on.
function fail(reason) {
  self.postMessage({ kind: "failed", error: reason });
  self.onmessage = null;
  self.close();
}

async function handle(msg) {
  if (msg.kind === "init") {
    try {
      await init({ module_or_path: msg.module });
      locator = msg.locator === "mediapipe"
        ? FaceLocatorWorker.mediapipe(msg.detector, msg.mesh, msg.points)
        : new FaceLocatorWorker(msg.detector, msg.landmarks);
    } catch (e) {
      fail("the face locator did not start: " + message(e));
    }
    return;
  }
  if (msg.kind !== "frame" || locator === null) {
    return;
  }
  const reply = { kind: "located", channel: msg.channel, located: null };
  try {
    reply.located = locator.locate(new Uint8Array(msg.pixels), msg.width, msg.height, msg.reset) ?? null;
  } catch (e) {
    if (e instanceof WebAssembly.RuntimeError) {
      fail("the face locator crashed: " + message(e));
      return;
    }
    // A frame that cannot be located (its tracking error): that frame's answer.
    reply.error = message(e);
  }
  self.postMessage(reply, reply.located ? [reply.located.buffer] : []);
}
