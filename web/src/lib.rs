//! # likeness-web: the studio in the browser
//!
//! Owns what only a web page has: fetching the template and the networks from the served
//! directory (with a page message when they are absent), starting eframe's web runner on
//! the page's canvas, the page's side of files, downloads, video decoding and the webcam
//! (`getUserMedia`), the face-locating Web Worker that gives tracking a second core, and
//! the numbers the page reports (`window.likeness`: time to first frame, the tracking
//! benchmark). It must not hold the model's mathematics or the studio's panels: those are
//! `face`, `tracking` and `likeness`, the same code the native studio runs.
//!
//! The asset list and its messages are plain Rust, tested natively; the rest compiles only
//! for wasm32.

#[cfg(target_arch = "wasm32")]
mod bench;
#[cfg(target_arch = "wasm32")]
mod host;
#[cfg(target_arch = "wasm32")]
mod page;
#[cfg(target_arch = "wasm32")]
mod worker;

use std::collections::HashMap;

/// A file the page fetches from the served directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Asset {
    /// Relative to the page.
    pub url: &'static str,
    /// What it is, for the page's message when it is absent.
    pub what: &'static str,
    /// Where a user gets it when it is absent.
    pub source: Source,
}

/// Where a missing file comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Source {
    /// The ICT FaceKit template (MIT): not redistributed by the project.
    FaceKit,
    /// OpenSeeFace's models (BSD-2): not redistributed by the project.
    OpenSeeFace,
    /// MediaPipe's models (Apache-2.0) and their ICT correspondence: not redistributed by
    /// the project.
    MediaPipe,
    /// Made by the project's own code, in the repository's `assets/`.
    Project,
}

pub const TEMPLATE: Asset = Asset {
    url: "facemodel/ict_face_model.safetensors",
    what: "the face template (ICT FaceKit as one safetensors file)",
    source: Source::FaceKit,
};
pub const MANIFEST: Asset = Asset {
    url: "models/manifest.json",
    what: "the networks' manifest",
    source: Source::Project,
};
/// The browser's TrackNet (`manifest.json`'s `web_track_net`: 128 px where native tracking
/// reads 160 px, for the page's frame rate).
pub const TRACK_NET: Asset = Asset {
    url: "models/track_net_web.onnx",
    what: "TrackNet (the browser's)",
    source: Source::Project,
};
pub const MODEL_NET: Asset = Asset {
    url: "models/model_net.onnx",
    what: "ModelNet",
    source: Source::Project,
};
pub const MEAN_ALBEDO: Asset = Asset {
    url: "models/mean_albedo.safetensors",
    what: "the trained mean albedo",
    source: Source::Project,
};
pub const DETECTOR: Asset = Asset {
    url: "openseeface/mnv3_detection_plain_b1.onnx",
    what: "the OpenSeeFace face detector (tract variant)",
    source: Source::OpenSeeFace,
};
pub const LANDMARKS: Asset = Asset {
    url: "openseeface/lm_model0_plain_b1.onnx",
    what: "the OpenSeeFace landmark network (tract variant)",
    source: Source::OpenSeeFace,
};
pub const MEDIAPIPE_DETECTOR: Asset = Asset {
    url: "mediapipe/face_detection_short_range.onnx",
    what: "MediaPipe's BlazeFace face detector",
    source: Source::MediaPipe,
};
pub const MEDIAPIPE_MESH: Asset = Asset {
    url: "mediapipe/face_landmark.onnx",
    what: "MediaPipe's Face Mesh",
    source: Source::MediaPipe,
};
pub const MEDIAPIPE_CORRESPONDENCE: Asset = Asset {
    url: "mediapipe/ict_correspondence.json",
    what: "the ICT vertex under each Face Mesh point",
    source: Source::MediaPipe,
};
pub const DEMO_PUPPET: Asset = Asset {
    url: "puppets/pip.glb",
    what: "the demo puppet",
    source: Source::Project,
};

/// Everything the studio fetches before it starts, in fetch order.
pub const REQUIRED_ASSETS: [Asset; 8] = [
    MANIFEST,
    TRACK_NET,
    MODEL_NET,
    MEAN_ALBEDO,
    DETECTOR,
    LANDMARKS,
    DEMO_PUPPET,
    TEMPLATE,
];

/// Fetched when the served directory has them: MediaPipe's face locator (File > Face
/// locator), offered only when all three are there.
pub const OPTIONAL_ASSETS: [Asset; 3] =
    [MEDIAPIPE_DETECTOR, MEDIAPIPE_MESH, MEDIAPIPE_CORRESPONDENCE];

/// The page's note (in the console) when optional files are absent: what is not offered and
/// where to get the files.
pub fn optional_missing_note(missing: &[Asset]) -> String {
    let names: Vec<&str> = missing.iter().map(|a| a.url).collect();
    format!(
        "MediaPipe's face locator is not offered: the served directory lacks {}. {}",
        names.join(", "),
        MEDIAPIPE_SOURCE
    )
}

const MEDIAPIPE_SOURCE: &str = "MediaPipe's models (Apache-2.0: the PyPI wheel \
    mediapipe==0.10.14, face_detection_short_range.tflite and face_landmark.tflite converted \
    to ONNX as shared/models/README.md describes) and ict_correspondence.json go in a folder \
    named by LIKENESS_MODELS=DIR (with a subfolder mediapipe/).";

/// The page's message when files are absent: what each is and where to get it.
pub fn missing_message(missing: &[Asset]) -> String {
    let mut text = String::from("Likeness cannot start: the served directory lacks ");
    let names: Vec<String> = missing
        .iter()
        .map(|a| format!("{} ({})", a.url, a.what))
        .collect();
    text.push_str(&names.join(", "));
    text.push('.');
    let has = |source| missing.iter().any(|a| a.source == source);
    if has(Source::FaceKit) {
        text.push_str(
            " The face template is the ICT FaceKit light model (MIT, the public GitHub \
             repository ICT-VGL/ICT-FaceKit, folder FaceXModel/) in the project's one-file \
             layout, ict_face_model.safetensors; point scripts/web.sh at that file with \
             LIKENESS_FACEMODEL=FILE.",
        );
    }
    if has(Source::OpenSeeFace) {
        text.push_str(
            " The OpenSeeFace models (BSD-2, the public GitHub repository \
             emilianavt/OpenSeeFace, folder models/, rewritten for tract as described in \
             shared/models/README.md) go in a folder named by LIKENESS_MODELS=DIR (with a \
             subfolder openseeface/).",
        );
    }
    if has(Source::MediaPipe) {
        text.push(' ');
        text.push_str(MEDIAPIPE_SOURCE);
    }
    if has(Source::Project) {
        text.push_str(
            " The networks and puppets are in the repository's assets/: rebuild with \
             scripts/web.sh.",
        );
    }
    text
}

/// Video and camera frames are scaled down to fit this: the tracker works on 224-pixel
/// crops, and larger frames only cost the page memory, which holds every frame of a session.
pub const MAX_FRAME_SIZE: (u32, u32) = (1280, 720);

/// `width` x `height` scaled down (never up) to fit [`MAX_FRAME_SIZE`], aspect kept.
pub fn fitted_frame_size(width: u32, height: u32) -> (u32, u32) {
    let scale = (f64::from(MAX_FRAME_SIZE.0) / f64::from(width.max(1)))
        .min(f64::from(MAX_FRAME_SIZE.1) / f64::from(height.max(1)))
        .min(1.0);
    (
        ((f64::from(width) * scale).round() as u32).max(1),
        ((f64::from(height) * scale).round() as u32).max(1),
    )
}

/// Fetched files by asset.
#[derive(Default)]
pub struct Fetched {
    files: HashMap<Asset, Vec<u8>>,
}

impl Fetched {
    pub fn insert(&mut self, asset: Asset, bytes: Vec<u8>) {
        self.files.insert(asset, bytes);
    }

    pub fn take(&mut self, asset: &Asset) -> Option<Vec<u8>> {
        self.files.remove(asset)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_asset_is_distinct_and_relative() {
        let all: Vec<Asset> = REQUIRED_ASSETS.into_iter().chain(OPTIONAL_ASSETS).collect();
        for (i, a) in all.iter().enumerate() {
            assert!(
                !a.url.starts_with('/') && !a.url.contains(".."),
                "{}",
                a.url
            );
            assert!(all[i + 1..].iter().all(|b| b.url != a.url));
        }
    }

    #[test]
    fn the_optional_note_names_the_missing_mediapipe_files_and_where_to_get_them() {
        let text = optional_missing_note(&[MEDIAPIPE_MESH, MEDIAPIPE_CORRESPONDENCE]);
        assert!(text.contains("mediapipe/face_landmark.onnx"));
        assert!(text.contains("mediapipe/ict_correspondence.json"));
        assert!(!text.contains("face_detection_short_range.onnx,"));
        assert!(text.contains("mediapipe==0.10.14") && text.contains("LIKENESS_MODELS"));
    }

    #[test]
    fn frames_shrink_to_fit_720p_with_their_aspect_and_never_grow() {
        assert_eq!(fitted_frame_size(640, 480), (640, 480));
        assert_eq!(fitted_frame_size(1920, 1080), (1280, 720));
        assert_eq!(fitted_frame_size(3840, 2160), (1280, 720));
        // Portrait phone video: the height limits.
        assert_eq!(fitted_frame_size(1080, 1920), (405, 720));
        assert_eq!(fitted_frame_size(0, 0), (1, 1));
    }

    #[test]
    fn the_missing_message_names_each_file_and_where_to_get_it() {
        let text = missing_message(&[TEMPLATE, LANDMARKS]);
        assert!(text.contains("facemodel/ict_face_model.safetensors"));
        assert!(text.contains("openseeface/lm_model0_plain_b1.onnx"));
        assert!(text.contains("ICT-VGL/ICT-FaceKit") && text.contains("LIKENESS_FACEMODEL"));
        assert!(text.contains("emilianavt/OpenSeeFace") && text.contains("LIKENESS_MODELS"));
        assert!(
            !text.contains("assets/"),
            "no project file is missing: {text}"
        );
        let project = missing_message(&[TRACK_NET]);
        assert!(project.contains("models/track_net_web.onnx") && project.contains("assets/"));
        assert!(!project.contains("ICT-FaceKit"));
    }
}
