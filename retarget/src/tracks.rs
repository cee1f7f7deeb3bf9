//! Reading tracked motion: the tracking JSON of `likeness track` or any hand-written or
//! third-party file with the same few fields.
//!
//! Only `arkit_names` (any naming convention, any order, a subset is fine) and each
//! frame's `arkit_weights` (aligned with `arkit_names`) are required; `time_s` (seconds,
//! default `index / 30`), `rotation_deg` (`[yaw, pitch, roll]`) and `translation`
//! (centimetres, checked only) are used when present. A frame with `"face": false` has no
//! tracking values and is skipped.
//!
//! Absurd values are refused with the frame and the field named, so every export made
//! from accepted tracks is valid (a glTF animation needs finite, strictly increasing
//! 32-bit times):
//! - times: finite, within [0, [`MAX_TIME_S`]] (24 h), and each at least
//!   [`MIN_FRAME_STEP_S`] after the previous frame's as 32-bit floats (also counted from
//!   the first frame, as the glTF animation stores them);
//! - weights: finite; within [[`WEIGHT_REFUSE_BELOW`], [`WEIGHT_REFUSE_ABOVE`]], then
//!   clamped to [0, 1] (trackers overshoot a little); outside it an error;
//! - `rotation_deg`: finite, each angle within ±[`MAX_ROTATION_DEG`];
//! - `translation`: finite, each component within ±[`MAX_TRANSLATION_CM`].
//!
//! The Live Link Face CSV reader (`export::parse_live_link_csv`) applies the same rules.

use std::path::Path;

use face::names::{ARKIT_NAMES, NUM_ARKIT};
use serde::Deserialize;

use crate::error::{Result, RetargetError, io_error};
use crate::names::arkit_channel;

/// Frame rate assumed for files without `time_s`.
pub const DEFAULT_FPS: f32 = 30.0;
/// Latest time a frame may have, in seconds (24 h: a Live Link timecode is a time of day).
pub const MAX_TIME_S: f64 = 86_400.0;
/// Smallest step between two frames' times as 32-bit floats, in seconds (at most 10,000
/// frames per second; a Live Link timecode resolves 1/60,000 s). Near 24 h a 32-bit float
/// resolves only 1/128 s, so frames there must be at least that far apart.
pub const MIN_FRAME_STEP_S: f32 = 1e-4;
/// Weights below this are refused; from it up to 0 they are clamped to 0.
pub const WEIGHT_REFUSE_BELOW: f64 = -0.5;
/// Weights above this are refused; from 1 up to it they are clamped to 1.
pub const WEIGHT_REFUSE_ABOVE: f64 = 1.5;
/// Largest head angle (yaw, pitch or roll) accepted, in degrees either way.
pub const MAX_ROTATION_DEG: f64 = 360.0;
/// Largest head translation component accepted, in centimetres either way (100 m).
pub const MAX_TRANSLATION_CM: f64 = 10_000.0;

/// Names of the three `rotation_deg` angles, in order.
pub const ROTATION_NAMES: [&str; 3] = ["yaw", "pitch", "roll"];

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

/// A weight as a file carries it: the weight clamped to [0, 1], or why it is refused
/// (not finite, or outside [[`WEIGHT_REFUSE_BELOW`], [`WEIGHT_REFUSE_ABOVE`]]).
pub fn checked_weight(w: f64) -> std::result::Result<f32, String> {
    if !w.is_finite() {
        return Err("is not a finite number".into());
    }
    if !(WEIGHT_REFUSE_BELOW..=WEIGHT_REFUSE_ABOVE).contains(&w) {
        return Err(format!(
            "{} is outside [{WEIGHT_REFUSE_BELOW}, {WEIGHT_REFUSE_ABOVE}] (weights run from 0 \
             to 1; overshoots up to 0.5 are clamped)",
            show(w)
        ));
    }
    Ok((w as f32).clamp(0.0, 1.0))
}

/// A head angle in degrees, or why it is refused (not finite, or beyond
/// ±[`MAX_ROTATION_DEG`]).
pub fn checked_angle_deg(deg: f64) -> std::result::Result<f32, String> {
    bounded(deg, MAX_ROTATION_DEG, "degrees")
}

/// A head angle in radians (Live Link Face) as degrees, or why it is refused (the bound
/// is ±[`MAX_ROTATION_DEG`] in radians).
pub fn checked_angle_rad(rad: f64) -> std::result::Result<f32, String> {
    bounded(rad, MAX_ROTATION_DEG.to_radians(), "radians").map(|_| rad.to_degrees() as f32)
}

/// A number as a message shows it: `1e300`, not three hundred digits.
pub(crate) fn show(v: f64) -> String {
    if v != 0.0 && !(1e-4..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

fn bounded(v: f64, bound: f64, unit: &str) -> std::result::Result<f32, String> {
    if !v.is_finite() {
        return Err("is not a finite number".into());
    }
    if v.abs() > bound {
        let bound = if bound.fract() == 0.0 {
            format!("{bound}")
        } else {
            format!("{bound:.4}")
        };
        return Err(format!("{} {unit} is beyond ±{bound} {unit}", show(v)));
    }
    Ok(v as f32)
}

/// Checks a clip's times one frame at a time, in order (the rules in the module
/// documentation): finite, within [0, [`MAX_TIME_S`]], increasing, and at least
/// [`MIN_FRAME_STEP_S`] apart as 32-bit floats, both from the previous frame and counted
/// from the first frame (as a glTF animation stores them).
#[derive(Debug, Default)]
pub struct TimeChecker {
    first: f32,
    previous: Option<PreviousTime>,
}

#[derive(Debug)]
struct PreviousTime {
    frame: String,
    time: f64,
    time_f32: f32,
    from_first: f32,
}

impl TimeChecker {
    pub fn new() -> Self {
        Self::default()
    }

    /// Checks the next frame's time `t` (seconds). `frame` ("frame 3", "line 5") and
    /// `field` (`time_s`, `Timecode`) name it in the error. Returns the time as `f32`.
    pub fn check(&mut self, frame: &str, field: &str, t: f64) -> std::result::Result<f32, String> {
        if !t.is_finite() {
            return Err(format!("{frame}: {field} is not a finite number"));
        }
        if !(0.0..=MAX_TIME_S).contains(&t) {
            return Err(format!(
                "{frame}: {field} {} s is outside [0, {MAX_TIME_S}] s (0 to 24 h)",
                show(t)
            ));
        }
        let time_f32 = t as f32;
        let from_first = match &self.previous {
            None => {
                self.first = time_f32;
                0.0
            }
            Some(p) => {
                if t <= p.time {
                    let how = if t == p.time { "the same as" } else { "before" };
                    return Err(format!(
                        "{frame}: {field} {t} s is {how} {}'s {} s; times must increase from \
                         frame to frame",
                        p.frame, p.time
                    ));
                }
                let from_first = time_f32 - self.first;
                let step = time_f32 - p.time_f32;
                if !(step >= MIN_FRAME_STEP_S && from_first > p.from_first) {
                    return Err(format!(
                        "{} and {frame}: {field} {} s and {t} s are {step} s apart as 32-bit \
                         floats (the precision of animation times); frames must be at least \
                         {MIN_FRAME_STEP_S} s apart, and near 24 h at least 1/128 s",
                        p.frame, p.time
                    ));
                }
                from_first
            }
        };
        self.previous = Some(PreviousTime {
            frame: frame.to_owned(),
            time: t,
            time_f32,
            from_first,
        });
        Ok(time_f32)
    }
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
    /// Checked, not used: camera-space centimetres in `likeness track`'s files.
    #[serde(default)]
    translation: Option<serde_json::Value>,
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
                        ARKIT_NAMES[a]
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
        let mut times = TimeChecker::new();
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
                let name = &raw.arkit_names[j];
                match column {
                    Some(a) => {
                        arkit[*a] = checked_weight(w)
                            .map_err(|e| format!("frame {k}: weight {j} (`{name}`) {e}"))?;
                    }
                    // An ignored column only has to be a number.
                    None if !w.is_finite() => {
                        return Err(format!(
                            "frame {k}: weight {j} (`{name}`) is not a finite number"
                        ));
                    }
                    None => {}
                }
            }
            let time_s = match (f.time_s, f.index) {
                (Some(t), _) => times.check(&format!("frame {k}"), "`time_s`", t)?,
                (None, index) => {
                    let index = index.map_or(k as f64, |i| i as f64);
                    times.check(
                        &format!("frame {k}"),
                        &format!("the time of `index` {index} at {DEFAULT_FPS} fps (no `time_s`)"),
                        index / f64::from(DEFAULT_FPS),
                    )?
                }
            };
            let rotation_deg = match f.rotation_deg {
                Some(r) => {
                    let mut deg = [0.0f32; 3];
                    for ((slot, v), name) in deg.iter_mut().zip(r).zip(ROTATION_NAMES) {
                        *slot = checked_angle_deg(v)
                            .map_err(|e| format!("frame {k}: `rotation_deg` {name} {e}"))?;
                    }
                    Some(deg)
                }
                None => None,
            };
            if let Some(t) = &f.translation {
                check_translation(t).map_err(|e| format!("frame {k}: `translation` {e}"))?;
            }
            tracks.frames.push(TrackedFrame {
                time_s,
                arkit,
                rotation_deg,
            });
        }
        Ok(tracks)
    }

    /// Checks tracks made in code (or edited after loading) by the rules files are held
    /// to: times as [`TimeChecker`], weights finite within [0, 1], angles finite within
    /// ±[`MAX_ROTATION_DEG`]. The error names the frame (its position in `frames`) and
    /// the field.
    pub fn check(&self) -> std::result::Result<(), String> {
        let mut times = TimeChecker::new();
        for (k, f) in self.frames.iter().enumerate() {
            times.check(&format!("frame {k}"), "`time_s`", f64::from(f.time_s))?;
            for (a, &w) in f.arkit.iter().enumerate() {
                if !(0.0..=1.0).contains(&w) {
                    return Err(format!(
                        "frame {k}: weight `{}` {w} is not within [0, 1]",
                        ARKIT_NAMES[a]
                    ));
                }
            }
            for (v, name) in f.rotation_deg.into_iter().flatten().zip(ROTATION_NAMES) {
                checked_angle_deg(f64::from(v))
                    .map_err(|e| format!("frame {k}: `rotation_deg` {name} {e}"))?;
            }
        }
        Ok(())
    }
}

/// `translation`: three finite numbers within ±[`MAX_TRANSLATION_CM`].
fn check_translation(value: &serde_json::Value) -> std::result::Result<(), String> {
    let numbers: Option<Vec<f64>> = value
        .as_array()
        .filter(|a| a.len() == 3)
        .and_then(|a| a.iter().map(serde_json::Value::as_f64).collect());
    let numbers = numbers.ok_or("is not three numbers (centimetres)")?;
    for (v, axis) in numbers.into_iter().zip(["x", "y", "z"]) {
        bounded(v, MAX_TRANSLATION_CM, "cm").map_err(|e| format!("{axis} {e}"))?;
    }
    Ok(())
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
        assert!(t.check().is_ok());
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

    /// Tracks of one `jawOpen` column with these frame bodies.
    fn parse_frames(frames: &[&str]) -> std::result::Result<Tracks, String> {
        Tracks::parse(&format!(
            r#"{{"arkit_names": ["jawOpen", "notAChannel"], "frames": [{}]}}"#,
            frames.join(",")
        ))
    }

    fn assert_refused(frames: &[&str], expect: &[&str]) {
        let err = parse_frames(frames).expect_err("accepted");
        for e in expect {
            assert!(err.contains(e), "{frames:?}: `{err}` lacks `{e}`");
        }
    }

    #[test]
    fn times_must_be_finite_within_24_hours_and_increase_as_32_bit_floats() {
        // Beyond f32's range (the issue's "(2 frames, NaN s)") and beyond 24 h.
        assert_refused(
            &[
                r#"{"time_s": 0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 1e39, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 1", "`time_s`", "1e39", "24 h"],
        );
        assert_refused(
            &[r#"{"time_s": 86400.5, "arkit_weights": [0, 0]}"#],
            &["frame 0", "`time_s`", "outside"],
        );
        // Negative (the issue's "-0.30 s").
        assert_refused(
            &[r#"{"time_s": -0.3, "arkit_weights": [0, 0]}"#],
            &["frame 0", "`time_s`", "-0.3"],
        );
        // Duplicate and backwards, naming both frames (a skipped frame between them counts).
        assert_refused(
            &[
                r#"{"time_s": 0.5, "arkit_weights": [0, 0]}"#,
                r#"{"face": false}"#,
                r#"{"time_s": 0.5, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 2", "the same as frame 0", "`time_s`"],
        );
        assert_refused(
            &[
                r#"{"time_s": 0.5, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 0.25, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 1", "before frame 0"],
        );
        // Two f64 times that are one 32-bit float.
        assert_refused(
            &[
                r#"{"time_s": 1.0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 1.00000001, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 0 and frame 1", "32-bit"],
        );
        // Near 24 h a float resolves 1/128 s: 1 ms steps collapse there, not near 0.
        assert_refused(
            &[
                r#"{"time_s": 86399.0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 86399.001, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 0 and frame 1", "32-bit"],
        );
        assert!(
            parse_frames(&[
                r#"{"time_s": 1.0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 1.001, "arkit_weights": [0, 0]}"#,
            ])
            .is_ok()
        );
        // More than 10,000 frames per second.
        assert_refused(
            &[
                r#"{"time_s": 0.0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 0.00005, "arkit_weights": [0, 0]}"#,
            ],
            &["frame 0 and frame 1", "0.0001"],
        );
        // Without `time_s` the index gives the time, and it is held to the same bound.
        assert_refused(
            &[r#"{"index": 10000000000, "arkit_weights": [0, 0]}"#],
            &["frame 0", "`index`", "24 h"],
        );
        // The worst accepted: the last instant of 24 h, 1/128 s after the one before.
        let t = parse_frames(&[
            r#"{"time_s": 86399.9921875, "arkit_weights": [0, 0]}"#,
            r#"{"time_s": 86400, "arkit_weights": [0, 0]}"#,
        ])
        .unwrap();
        assert_eq!(t.frames[1].time_s, 86400.0);
        assert!(t.check().is_ok());
    }

    #[test]
    fn weights_slightly_out_of_range_are_clamped_far_out_refused() {
        let jaw = arkit_index("jawOpen").unwrap();
        let t = parse_frames(&[
            r#"{"time_s": 0, "arkit_weights": [1.5, 0]}"#,
            r#"{"time_s": 1, "arkit_weights": [-0.5, 0]}"#,
            r#"{"time_s": 2, "arkit_weights": [0.75, 1e300]}"#,
        ])
        .unwrap();
        let jaws: Vec<f32> = t.frames.iter().map(|f| f.arkit[jaw]).collect();
        assert_eq!(jaws, [1.0, 0.0, 0.75]);
        // The issue's 1e300 on a channel, and a percentage.
        assert_refused(
            &[
                r#"{"time_s": 0, "arkit_weights": [0, 0]}"#,
                r#"{"time_s": 1, "arkit_weights": [1e300, 0]}"#,
            ],
            &["frame 1", "weight 0", "`jawOpen`", "1e300", "1.5"],
        );
        assert_refused(
            &[r#"{"time_s": 0, "arkit_weights": [1.51, 0]}"#],
            &["frame 0", "`jawOpen`", "outside"],
        );
        assert_refused(
            &[r#"{"time_s": 0, "arkit_weights": [-0.51, 0]}"#],
            &["frame 0", "`jawOpen`", "outside"],
        );
    }

    #[test]
    fn head_angles_and_translation_are_bounded() {
        assert_refused(
            &[r#"{"arkit_weights": [0, 0], "rotation_deg": [0, 1e30, 0]}"#],
            &["frame 0", "`rotation_deg` pitch", "1e30"],
        );
        assert_refused(
            &[r#"{"arkit_weights": [0, 0], "rotation_deg": [0, 0, -360.5]}"#],
            &["frame 0", "`rotation_deg` roll", "360"],
        );
        let t = parse_frames(&[r#"{"arkit_weights": [0, 0], "rotation_deg": [360, -360, 0]}"#])
            .unwrap();
        assert_eq!(t.frames[0].rotation_deg, Some([360.0, -360.0, 0.0]));
        assert_refused(
            &[r#"{"arkit_weights": [0, 0], "translation": [0, 0, -1e9]}"#],
            &["frame 0", "`translation` z", "-1e9 cm", "10000 cm"],
        );
        assert_refused(
            &[r#"{"arkit_weights": [0, 0], "translation": "far"}"#],
            &["frame 0", "`translation`", "three numbers"],
        );
        assert!(
            parse_frames(&[r#"{"arkit_weights": [0, 0], "translation": [1.5, -2, -60]}"#]).is_ok()
        );
    }

    #[test]
    fn tracks_made_in_code_are_checked_by_the_same_rules() {
        let frame = |time_s: f32| TrackedFrame {
            time_s,
            arkit: [0.0; NUM_ARKIT],
            rotation_deg: Some([0.0; 3]),
        };
        let mut t = Tracks {
            frames: vec![frame(0.0), frame(0.5)],
            ..Tracks::default()
        };
        assert!(t.check().is_ok());
        t.frames[1].time_s = f32::NAN;
        assert!(t.check().unwrap_err().contains("frame 1"));
        t.frames[1].time_s = 0.5;
        t.frames[1].arkit[3] = 2.0;
        assert!(t.check().unwrap_err().contains(ARKIT_NAMES[3]));
        t.frames[1].arkit[3] = 1.0;
        t.frames[0].rotation_deg = Some([0.0, 0.0, 1e30]);
        assert!(t.check().unwrap_err().contains("roll"));
    }
}
