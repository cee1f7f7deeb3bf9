//! What a browser page does for the studio. In a browser there are no paths, dialogs of
//! the operating system or threads: files arrive as bytes (dropped on the page, or picked
//! with the page's file input), writes become downloads, video is decoded by the page's
//! `<video>` element and the camera is `getUserMedia`. The `likeness-web` crate implements
//! this trait with `web-sys`; this crate only calls it, so it keeps no browser code.

use image::RgbImage;

/// A file the user picked or dropped, with its bytes.
#[derive(Clone, Debug)]
pub struct PickedFile {
    pub name: String,
    pub bytes: std::sync::Arc<[u8]>,
}

/// A video the page is decoding into frames.
#[derive(Clone, Debug, PartialEq)]
pub enum VideoFrames {
    /// Still decoding: `done` frames so far, of about `total`.
    Decoding {
        done: usize,
        total: Option<usize>,
    },
    /// All frames, at `fps`.
    Done {
        frames: Vec<RgbImage>,
        fps: f64,
    },
    Failed(String),
}

/// What the camera has.
#[derive(Clone, Debug, PartialEq)]
pub enum CameraFrame {
    /// Permission is being asked or the stream is starting.
    Starting,
    Frame(RgbImage),
    /// No frame newer than the last one yet.
    Waiting,
    /// The camera could not start, or stopped (with why).
    Failed(String),
}

pub trait WebHost {
    /// Opens the page's file picker for files matching `accept` (an HTML `accept` list);
    /// what is chosen arrives through [`WebHost::take_picked_files`].
    fn pick_files(&self, accept: &str);
    /// Reads files dropped on the page (the browser reads them asynchronously); they
    /// arrive through [`WebHost::take_picked_files`].
    fn read_dropped(&self, files: Vec<egui::DroppedFileHandle>);
    /// Files picked or dropped since the last call.
    fn take_picked_files(&self) -> Vec<PickedFile>;
    /// Offers `bytes` as a download called `name`.
    fn download(&self, name: &str, mime: &str, bytes: &[u8]) -> Result<(), String>;
    /// Starts decoding a video file's frames (at most `max_frames`).
    fn decode_video(&self, file: &PickedFile, max_frames: usize);
    /// The video being decoded; `None` when there is none.
    fn video_frames(&self) -> Option<VideoFrames>;
    /// Asks for the camera.
    fn start_camera(&self);
    /// The camera's newest frame.
    fn camera_frame(&self) -> CameraFrame;
    fn stop_camera(&self);
    /// The page's face-locating worker running `locator` (OpenSeeFace's for `Auto`), for one
    /// job; `None` when the page has none for it (the job then locates faces on the page's
    /// thread, with its tracker's own locator, which must be the same).
    fn face_locator(
        &self,
        locator: tracking::pipeline::LocatorChoice,
    ) -> Option<Box<dyn crate::stepped::RemoteFaceLocator>>;
}

/// Whether a file name is a video the browser can decode (by extension).
pub fn is_video_name(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    [".mp4", ".webm", ".mov", ".m4v", ".mkv", ".ogv"]
        .iter()
        .any(|ext| lower.ends_with(ext))
}

/// Whether a file name is a puppet (glTF, GLB or VRM).
pub fn is_puppet_name(name: &str) -> bool {
    let lower = name.to_ascii_lowercase();
    [".glb", ".gltf", ".vrm"]
        .iter()
        .any(|ext| lower.ends_with(ext))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_kinds_by_extension_in_any_case() {
        assert!(is_video_name("clip.MP4") && is_video_name("a.webm"));
        assert!(!is_video_name("face.png") && !is_video_name("mp4"));
        assert!(is_puppet_name("Hero.VRM") && is_puppet_name("pip.glb"));
        assert!(!is_puppet_name("hero.vrm.png"));
    }
}
