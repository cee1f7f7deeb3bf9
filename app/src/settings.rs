//! What the studio remembers between runs: recent files, the export folder, the overlay
//! choices. Stored through eframe's own persistence (a RON file in the platform's data
//! folder), so there is no second settings file to keep in step.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

/// The key the settings are stored under.
pub const SETTINGS_KEY: &str = "likeness-settings";

/// How many recent files the File menu lists.
pub const RECENT_LIMIT: usize = 8;

/// A file the studio opened: a session or footage.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum RecentFile {
    Session(PathBuf),
    Footage(String),
}

impl RecentFile {
    pub fn label(&self) -> String {
        match self {
            RecentFile::Session(p) => format!("Session: {}", p.display()),
            RecentFile::Footage(f) => format!("Footage: {f}"),
        }
    }
}

/// What finds the face in footage the studio opens (File > Face locator).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum FaceLocator {
    /// OpenSeeFace's detector and 66 landmarks.
    #[default]
    OpenSeeFace,
    /// MediaPipe's BlazeFace and 468-point Face Mesh (finds close-ups; refinement fits all
    /// 468 points).
    MediaPipe,
}

impl FaceLocator {
    pub fn label(self) -> &'static str {
        match self {
            Self::OpenSeeFace => "OpenSeeFace (66 points)",
            Self::MediaPipe => "MediaPipe Face Mesh (468 points)",
        }
    }

    pub fn choice(self) -> tracking::pipeline::LocatorChoice {
        match self {
            Self::OpenSeeFace => tracking::pipeline::LocatorChoice::Landmarks,
            Self::MediaPipe => tracking::pipeline::LocatorChoice::MediaPipe,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Settings {
    /// Most recent first, without duplicates.
    pub recent: Vec<RecentFile>,
    pub export_dir: String,
    pub overlay_opacity: f32,
    pub show_detected: bool,
    pub show_model: bool,
    pub show_boxes: bool,
    /// The last puppet loaded (reloaded at start when it still exists).
    pub puppet: Option<PathBuf>,
    /// Anti-aliased shape edges in the window; `None` chooses by the adapter (off on a
    /// software rasteriser, where they double the triangles egui draws).
    pub smooth_edges: Option<bool>,
    /// Render the puppet view at half size while a clip plays; `None` chooses by the
    /// adapter (on for a software rasteriser, where its cost grows with the pixels filled).
    pub reduce_3d_while_playing: Option<bool>,
    /// What finds the face in footage opened from now on.
    pub face_locator: FaceLocator,
}

impl Default for Settings {
    fn default() -> Self {
        Self {
            recent: Vec::new(),
            export_dir: "likeness-export".into(),
            overlay_opacity: 0.6,
            show_detected: true,
            show_model: true,
            show_boxes: true,
            puppet: None,
            smooth_edges: None,
            reduce_3d_while_playing: None,
            face_locator: FaceLocator::default(),
        }
    }
}

impl Settings {
    /// Puts `file` first in the recent list.
    pub fn remember(&mut self, file: RecentFile) {
        self.recent.retain(|f| *f != file);
        self.recent.insert(0, file);
        self.recent.truncate(RECENT_LIMIT);
    }

    /// Drops a recent file that could not be opened.
    pub fn forget(&mut self, file: &RecentFile) {
        self.recent.retain(|f| f != file);
    }

    /// Values read from an older or hand-edited store, made safe to use.
    pub fn sanitized(mut self) -> Self {
        if !self.overlay_opacity.is_finite() {
            self.overlay_opacity = Settings::default().overlay_opacity;
        }
        self.overlay_opacity = self.overlay_opacity.clamp(0.0, 1.0);
        self.recent.truncate(RECENT_LIMIT);
        self
    }
}

/// The studio's application id: its window title and the name of its data folder
/// (settings in `app.ron`, the autosave).
pub const STUDIO_APP_ID: &str = "Likeness studio";

/// Where the studio autosaves the last processed session: the platform's data folder for
/// the app (the same eframe uses for its settings), or the system temp folder.
pub fn autosave_path() -> PathBuf {
    #[cfg(not(target_arch = "wasm32"))]
    return eframe::storage_dir(STUDIO_APP_ID)
        .unwrap_or_else(|| std::env::temp_dir().join("likeness"))
        .join("autosave.likeness");
    // A browser has no folders (asking for one panics): sessions are saved as downloads,
    // and the autosave is never written there.
    #[cfg(target_arch = "wasm32")]
    PathBuf::from("autosave.likeness")
}

/// `path` with the `.likeness` extension when it has none.
pub fn with_session_extension(path: &Path) -> PathBuf {
    if path.extension().is_some() {
        path.to_owned()
    } else {
        path.with_extension("likeness")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recent_files_are_unique_most_recent_first_and_bounded() {
        let mut s = Settings::default();
        for k in 0..12 {
            s.remember(RecentFile::Footage(format!("clip{k}.mp4")));
        }
        s.remember(RecentFile::Footage("clip5.mp4".into()));
        assert_eq!(s.recent.len(), RECENT_LIMIT);
        assert_eq!(s.recent[0], RecentFile::Footage("clip5.mp4".into()));
        assert_eq!(
            s.recent
                .iter()
                .filter(|f| **f == RecentFile::Footage("clip5.mp4".into()))
                .count(),
            1
        );
        assert_eq!(s.recent[1], RecentFile::Footage("clip11.mp4".into()));
        s.forget(&RecentFile::Footage("clip5.mp4".into()));
        assert_eq!(s.recent[0], RecentFile::Footage("clip11.mp4".into()));
    }

    #[test]
    fn settings_round_trip_and_bad_values_are_repaired() {
        let mut s = Settings {
            overlay_opacity: 0.25,
            ..Settings::default()
        };
        s.remember(RecentFile::Session("a.likeness".into()));
        let text = serde_json::to_string(&s).unwrap();
        let back: Settings = serde_json::from_str(&text).unwrap();
        assert_eq!(back, s);
        // Missing fields take their defaults; a NaN opacity is repaired.
        let partial: Settings = serde_json::from_str(r#"{"export_dir":"out"}"#).unwrap();
        assert_eq!(partial.export_dir, "out");
        assert_eq!(partial.overlay_opacity, 0.6);
        assert_eq!(partial.face_locator, FaceLocator::OpenSeeFace);
        let mesh = Settings {
            face_locator: FaceLocator::MediaPipe,
            ..Settings::default()
        };
        let back: Settings = serde_json::from_str(&serde_json::to_string(&mesh).unwrap()).unwrap();
        assert_eq!(back.face_locator, FaceLocator::MediaPipe);
        let repaired = Settings {
            overlay_opacity: f32::NAN,
            ..Settings::default()
        }
        .sanitized();
        assert_eq!(repaired.overlay_opacity, 0.6);
        assert_eq!(
            with_session_extension(Path::new("x")),
            PathBuf::from("x.likeness")
        );
    }
}
