//! Reading tracked motion: the tracking JSON of `likeness track` or any hand-written or
//! third-party file with the same few fields.
//!
//! Only `arkit_names` (any naming convention, any order, a subset is fine) and each
//! frame's `arkit_weights` (aligned with `arkit_names`) are required; `time_s` (seconds,
//! default `index / 30`) and `rotation_deg` (`[yaw, pitch, roll]`) are used when present.
//! A frame with `"face": false` has no tracking values and is skipped.

use std::path::Path;

use face::names::NUM_ARKIT;
use serde::Deserialize;

use crate::error::{Result, RetargetError, io_error};
use crate::names::arkit_channel;

/// Frame rate assumed for files without `time_s`.
pub const DEFAULT_FPS: f32 = 30.0;

/// One tracked frame in ARKit channel order.
#[derive(Clone, Debug, PartialEq)]
pub struct TrackedFrame {
    pub time_s: f32,
    pub arkit: [f32; NUM_ARKIT],
    /// `[yaw, pitch, roll]` in degrees, if the file has head pose.
    pub rotation_deg: Option<[f32; 3]>,
}

/// A clip of tracked frames, in time order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tracks {
    pub frames: Vec<TrackedFrame>,
    /// Frames marked `"face": false`, skipped.
    pub frames_without_face: usize,
    /// Names in `arkit_names` that are not ARKit channels (ignored, reported).
    pub unknown_names: Vec<String>,
}

#[derive(Deserialize)]
struct RawTracks {
    arkit_names: Vec<String>,
    frames: Vec<RawFrame>,
}

#[derive(Deserialize)]
struct RawFrame {
    #[serde(default)]
    index: Option<u64>,
    #[serde(default)]
    time_s: Option<f64>,
    #[serde(default)]
    face: Option<bool>,
    #[serde(default)]
    arkit_weights: Option<Vec<f64>>,
    #[serde(default)]
    rotation_deg: Option<[f64; 3]>,
}

impl Tracks {
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(io_error(path))?;
        Self::parse(&text).map_err(|reason| RetargetError::InvalidTracks {
            path: path.to_owned(),
            reason,
        })
    }

    /// Parses tracking JSON; the error says which frame and field is wrong.
    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        let raw: RawTracks = serde_json::from_str(text).map_err(|e| {
            format!("not a tracking file ({e}); it needs `arkit_names` and `frames`")
        })?;
        let mut columns = Vec::with_capacity(raw.arkit_names.len());
        let mut unknown_names = Vec::new();
        let mut seen = [false; NUM_ARKIT];
        for name in &raw.arkit_names {
            let channel = arkit_channel(name);
            if let Some(a) = channel {
                if std::mem::replace(&mut seen[a], true) {
                    return Err(format!(
                        "`arkit_names` lists the channel `{}` twice (as `{name}`)",
                        face::names::ARKIT_NAMES[a]
                    ));
                }
            } else {
                unknown_names.push(name.clone());
            }
            columns.push(channel);
        }
        if columns.iter().all(Option::is_none) {
            return Err("`arkit_names` has no ARKit channel".into());
        }
        let mut tracks = Tracks {
            unknown_names,
            ..Tracks::default()
        };
        for (k, f) in raw.frames.iter().enumerate() {
            if f.face == Some(false) {
                tracks.frames_without_face += 1;
                continue;
            }
            let weights = f.arkit_weights.as_ref().ok_or_else(|| {
                format!("frame {k}: no `arkit_weights` (and not marked `\"face\": false`)")
            })?;
            if weights.len() != columns.len() {
                return Err(format!(
                    "frame {k}: {} `arkit_weights` for {} `arkit_names`",
                    weights.len(),
                    columns.len()
                ));
            }
            let mut arkit = [0.0f32; NUM_ARKIT];
            for (j, (&w, column)) in weights.iter().zip(&columns).enumerate() {
                if !w.is_finite() {
                    return Err(format!(
                        "frame {k}: weight {j} (`{}`) is not a finite number",
                        raw.arkit_names[j]
                    ));
                }
                if let Some(a) = column {
                    // Trackers overshoot slightly; morph weights outside [0, 1] distort puppets.
                    arkit[*a] = (w as f32).clamp(0.0, 1.0);
                }
            }
            let index = f.index.map_or(k as f64, |i| i as f64);
            let time_s = f.time_s.unwrap_or(index / f64::from(DEFAULT_FPS));
            if !time_s.is_finite() {
                return Err(format!("frame {k}: `time_s` is not a finite number"));
            }
            let rotation_deg = match f.rotation_deg {
                Some(r) if r.iter().all(|v| v.is_finite()) => Some(r.map(|v| v as f32)),
                Some(_) => {
                    return Err(format!(
                        "frame {k}: `rotation_deg` is not three finite numbers"
                    ));
                }
                None => None,
            };
            tracks.frames.push(TrackedFrame {
                time_s: time_s as f32,
                arkit,
                rotation_deg,
            });
        }
        if tracks.frames.windows(2).any(|p| p[1].time_s <= p[0].time_s) {
            return Err("`time_s` must increase from frame to frame".into());
        }
        Ok(tracks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use face::names::arkit_index;

    #[test]
    fn hand_written_subset_in_any_convention() {
        let text = r#"{"arkit_names": ["JawOpen", "eyeBlink_L", "mouthSmile"], "frames": [
            {"arkit_weights": [0.5, 1.2, 0.1]},
            {"face": false},
            {"time_s": 0.5, "arkit_weights": [0.25, 0.0, 0.0], "rotation_deg": [10, -5, 2]}
        ]}"#;
        let t = Tracks::parse(text).unwrap();
        assert_eq!(t.frames.len(), 2);
        assert_eq!(t.frames_without_face, 1);
        assert_eq!(t.unknown_names, vec!["mouthSmile".to_string()]);
        assert_eq!(t.frames[0].arkit[arkit_index("jawOpen").unwrap()], 0.5);
        assert_eq!(t.frames[0].arkit[arkit_index("eyeBlinkLeft").unwrap()], 1.0);
        assert_eq!(t.frames[0].time_s, 0.0);
        assert_eq!(t.frames[1].rotation_deg, Some([10.0, -5.0, 2.0]));
    }

    #[test]
    fn bad_files_name_the_problem() {
        for (text, expect) in [
            ("", "not a tracking file"),
            (r#"{"frames": []}"#, "arkit_names"),
            (
                r#"{"arkit_names": ["smile"], "frames": []}"#,
                "no ARKit channel",
            ),
            (
                r#"{"arkit_names": ["jawOpen"], "frames": [{"arkit_weights": [0.1, 0.2]}]}"#,
                "frame 0: 2",
            ),
            (
                r#"{"arkit_names": ["jawOpen", "JawOpen"], "frames": []}"#,
                "twice",
            ),
            (
                r#"{"arkit_names": ["jawOpen"], "frames": [{}]}"#,
                "no `arkit_weights`",
            ),
            (
                r#"{"arkit_names": ["jawOpen"], "frames": [{"time_s": 1, "arkit_weights": [0]}, {"time_s": 0.5, "arkit_weights": [0]}]}"#,
                "increase",
            ),
        ] {
            let err = Tracks::parse(text).unwrap_err();
            assert!(err.contains(expect), "{text}: {err}");
        }
        // NaN cannot be written in JSON; a huge exponent overflows to infinity in serde_json's f64.
        let err = Tracks::parse(
            r#"{"arkit_names": ["jawOpen"], "frames": [{"arkit_weights": [1e999]}]}"#,
        )
        .unwrap_err();
        assert!(
            err.contains("frame 0") || err.contains("not a tracking file"),
            "{err}"
        );
    }
}
