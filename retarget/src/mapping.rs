//! Mapping data: how each tracked channel drives a puppet, stored as a JSON sidecar next to
//! the puppet (`hero.glb` -> `hero.mapping.json`).
//!
//! A channel's response, in this order (the same in the studio's editor, the CLI and the
//! exports):
//! 1. neutral calibration: `x' = max(0, (x - n) / (1 - n))` for the rest-pose weight `n` of
//!    the source (recorded with "calibrate neutral"), so the rest pose reads 0 and a full
//!    expression still reaches 1;
//! 2. `invert`: `x' = 1 - x'`;
//! 3. `curve`: a piecewise-linear response through the points `[x, y]` (x strictly
//!    increasing; constant beyond the ends; empty = identity);
//! 4. `y = gain * x' + offset`, then clamped to `clamp = [lo, hi]`.
//!
//! `source` is an ARKit channel (any naming convention, see `names`) or a VRM expression
//! preset derived from them (`vrm::VrmPreset`). `targets` name morph targets or VRM
//! expressions of the puppet; empty means "whatever the names match automatically".
//! An entry for a source replaces that source's automatic mapping; several entries for one
//! source drive several targets with different responses.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::error::{Result, RetargetError, io_error};
use crate::names::arkit_channel;
use crate::vrm::VrmPreset;

/// Layout version of the sidecar file.
pub const MAPPING_VERSION: u32 = 1;

/// The whole sidecar: per-channel responses, the rest pose, the head.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MappingData {
    pub version: u32,
    #[serde(default)]
    pub channels: Vec<ChannelMapping>,
    /// Rest-pose weight per source channel (ARKit name), subtracted by the calibration.
    #[serde(default)]
    pub neutral: BTreeMap<String, f32>,
    #[serde(default)]
    pub head: HeadMapping,
}

impl Default for MappingData {
    fn default() -> Self {
        Self {
            version: MAPPING_VERSION,
            channels: Vec::new(),
            neutral: BTreeMap::new(),
            head: HeadMapping::default(),
        }
    }
}

/// One source -> target(s) link with its response.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelMapping {
    pub source: String,
    #[serde(default)]
    pub targets: Vec<String>,
    #[serde(default = "one")]
    pub gain: f32,
    #[serde(default)]
    pub offset: f32,
    #[serde(default = "unit_range")]
    pub clamp: [f32; 2],
    #[serde(default)]
    pub curve: Vec<[f32; 2]>,
    #[serde(default)]
    pub invert: bool,
}

fn one() -> f32 {
    1.0
}

fn unit_range() -> [f32; 2] {
    [0.0, 1.0]
}

impl ChannelMapping {
    /// The identity response for `source`, to automatic targets.
    pub fn identity(source: impl Into<String>) -> Self {
        Self {
            source: source.into(),
            targets: Vec::new(),
            gain: 1.0,
            offset: 0.0,
            clamp: unit_range(),
            curve: Vec::new(),
            invert: false,
        }
    }

    /// Steps 2-4 of the response (the calibration is applied to the source beforehand).
    pub fn respond(&self, calibrated: f32) -> f32 {
        let x = if self.invert {
            1.0 - calibrated
        } else {
            calibrated
        };
        let y = self.gain * piecewise_linear(&self.curve, x) + self.offset;
        y.clamp(self.clamp[0], self.clamp[1])
    }
}

/// How head rotation reaches the puppet's head node.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadMapping {
    #[serde(default = "yes")]
    pub enabled: bool,
    /// Node name to rotate; by default the VRM humanoid head bone, else a node named like
    /// "head" or "neck".
    #[serde(default)]
    pub node: Option<String>,
    /// Multiplies each angle (0.5 = half the motion).
    #[serde(default = "one")]
    pub gain: f32,
    /// Mirror left and right (a puppet facing the performer like a mirror image).
    #[serde(default)]
    pub mirror: bool,
}

fn yes() -> bool {
    true
}

impl Default for HeadMapping {
    fn default() -> Self {
        Self {
            enabled: true,
            node: None,
            gain: 1.0,
            mirror: false,
        }
    }
}

/// Step 1 of the response: `max(0, (x - n) / (1 - n))`; a rest weight of 1 or more leaves
/// nothing to map and gives 0.
pub fn calibrate(x: f32, neutral: f32) -> f32 {
    if neutral <= 0.0 {
        return x;
    }
    if neutral >= 1.0 {
        return 0.0;
    }
    ((x - neutral) / (1.0 - neutral)).max(0.0)
}

/// A piecewise-linear curve through `points` (x strictly increasing), constant beyond its
/// ends; the identity when empty.
pub fn piecewise_linear(points: &[[f32; 2]], x: f32) -> f32 {
    let (Some(first), Some(last)) = (points.first(), points.last()) else {
        return x;
    };
    if x <= first[0] {
        return first[1];
    }
    if x >= last[0] {
        return last[1];
    }
    for pair in points.windows(2) {
        let ([x0, y0], [x1, y1]) = (pair[0], pair[1]);
        if x <= x1 {
            let t = (x - x0) / (x1 - x0);
            return y0 + t * (y1 - y0);
        }
    }
    last[1]
}

/// A source channel: one of the 52 ARKit weights, or a VRM preset computed from them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Source {
    Arkit(usize),
    Vrm(VrmPreset),
}

impl Source {
    /// Resolves a source name: ARKit first (any convention), then VRM 1.0 / 0.x presets.
    pub fn parse(name: &str) -> Option<Self> {
        arkit_channel(name)
            .map(Source::Arkit)
            .or_else(|| VrmPreset::parse(name).map(Source::Vrm))
    }

    pub fn name(&self) -> String {
        match self {
            Source::Arkit(a) => face::names::ARKIT_NAMES[*a].to_owned(),
            Source::Vrm(p) => p.name().to_owned(),
        }
    }
}

/// `head.gain` beyond this is refused: ten times the performer's turn is already
/// cartoonish, and larger products of gain and angle lose all precision.
pub const MAX_HEAD_GAIN: f32 = 10.0;

impl MappingData {
    /// Checks every number and name; the error says which entry is wrong.
    pub fn validate(&self, path: &Path) -> Result<()> {
        let bad = |reason: String| RetargetError::InvalidMapping {
            path: path.to_owned(),
            reason,
        };
        if self.version != MAPPING_VERSION {
            return Err(bad(format!(
                "version {} is not supported (this build reads version {MAPPING_VERSION})",
                self.version
            )));
        }
        for (k, c) in self.channels.iter().enumerate() {
            let at = format!("channels[{k}] (source `{}`)", c.source);
            if Source::parse(&c.source).is_none() {
                return Err(bad(format!(
                    "{at}: unknown source; use one of the 52 ARKit names (any case or convention) or a VRM expression preset"
                )));
            }
            for (name, v) in [
                ("gain", c.gain),
                ("offset", c.offset),
                ("clamp[0]", c.clamp[0]),
                ("clamp[1]", c.clamp[1]),
            ] {
                if !v.is_finite() {
                    return Err(bad(format!("{at}: {name} is not a finite number")));
                }
            }
            if c.clamp[0] > c.clamp[1] {
                return Err(bad(format!(
                    "{at}: clamp [{}, {}] has its low end above its high end",
                    c.clamp[0], c.clamp[1]
                )));
            }
            if c.curve.iter().flatten().any(|v| !v.is_finite()) {
                return Err(bad(format!(
                    "{at}: curve has a point that is not a finite number"
                )));
            }
            if c.curve.windows(2).any(|p| p[1][0] <= p[0][0]) {
                return Err(bad(format!("{at}: curve x values must increase strictly")));
            }
            if c.targets.iter().any(|t| t.trim().is_empty()) {
                return Err(bad(format!("{at}: a target name is empty")));
            }
        }
        for (name, &v) in &self.neutral {
            if arkit_channel(name).is_none() {
                return Err(bad(format!("neutral: `{name}` is not an ARKit channel")));
            }
            if !(0.0..=1.0).contains(&v) {
                return Err(bad(format!("neutral: `{name}` = {v} is outside [0, 1]")));
            }
        }
        if !(self.head.gain.is_finite() && self.head.gain.abs() <= MAX_HEAD_GAIN) {
            return Err(bad(format!(
                "head.gain {} is not a number within ±{MAX_HEAD_GAIN} (1 turns the puppet's head as far as the performer's)",
                self.head.gain
            )));
        }
        Ok(())
    }

    /// Rest-pose weights indexed by ARKit channel.
    pub fn neutral_weights(&self) -> [f32; face::NUM_ARKIT] {
        let mut out = [0.0; face::NUM_ARKIT];
        for (name, &v) in &self.neutral {
            if let Some(a) = arkit_channel(name) {
                out[a] = v;
            }
        }
        out
    }

    /// Records `rest` (ARKit weights of the performer's rest pose) as the neutral.
    pub fn calibrate_neutral(&mut self, rest: &[f32; face::NUM_ARKIT]) {
        self.neutral = face::names::ARKIT_NAMES
            .iter()
            .zip(rest)
            .filter(|(_, v)| **v > 0.0 && v.is_finite())
            .map(|(n, v)| ((*n).to_owned(), v.min(1.0)))
            .collect();
    }

    /// Reads and validates a sidecar file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(io_error(path))?;
        let data: Self =
            serde_json::from_str(&text).map_err(|e| RetargetError::InvalidMapping {
                path: path.to_owned(),
                reason: e.to_string(),
            })?;
        data.validate(path)?;
        Ok(data)
    }

    /// The sidecar next to `puppet` if it exists, else the default (automatic) mapping.
    pub fn load_for_puppet(puppet: &Path) -> Result<Self> {
        let sidecar = sidecar_path(puppet);
        if sidecar.exists() {
            Self::load(&sidecar)
        } else {
            Ok(Self::default())
        }
    }

    /// Writes the sidecar atomically (a temporary file renamed over the old one), so an
    /// interrupted save never leaves half a file.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.validate(path)?;
        let text = serde_json::to_string_pretty(self).map_err(|e| RetargetError::Write {
            path: path.to_owned(),
            reason: e.to_string(),
        })?;
        Ok(files::write_atomically(path, text.as_bytes())?)
    }
}

/// `dir/hero.glb` -> `dir/hero.mapping.json`.
pub fn sidecar_path(puppet: &Path) -> PathBuf {
    let stem = puppet
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    puppet.with_file_name(format!("{stem}.mapping.json"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn response_follows_the_documented_order() {
        let c = ChannelMapping {
            gain: 2.0,
            offset: -0.1,
            clamp: [0.0, 1.0],
            curve: vec![[0.0, 0.0], [0.5, 0.2], [1.0, 1.0]],
            invert: false,
            ..ChannelMapping::identity("jawOpen")
        };
        // curve(0.25) = 0.1 -> 2 * 0.1 - 0.1 = 0.1
        assert!((c.respond(0.25) - 0.1).abs() < 1e-6);
        // curve(0.75) = 0.6 -> 1.1 -> clamped to 1
        assert_eq!(c.respond(0.75), 1.0);
        let inverted = ChannelMapping {
            invert: true,
            ..ChannelMapping::identity("eyeBlinkLeft")
        };
        assert!((inverted.respond(0.3) - 0.7).abs() < 1e-6);
    }

    #[test]
    fn calibration_maps_rest_to_zero_and_keeps_full_range() {
        assert_eq!(calibrate(0.2, 0.2), 0.0);
        assert_eq!(calibrate(0.1, 0.2), 0.0);
        assert!((calibrate(1.0, 0.2) - 1.0).abs() < 1e-6);
        assert!((calibrate(0.6, 0.2) - 0.5).abs() < 1e-6);
        assert_eq!(calibrate(0.4, 0.0), 0.4);
        assert_eq!(calibrate(0.4, 1.0), 0.0);
    }

    #[test]
    fn piecewise_linear_is_constant_beyond_its_ends() {
        let pts = [[0.2, 0.1], [0.8, 0.9]];
        assert_eq!(piecewise_linear(&pts, 0.0), 0.1);
        assert_eq!(piecewise_linear(&pts, 1.0), 0.9);
        assert!((piecewise_linear(&pts, 0.5) - 0.5).abs() < 1e-6);
        assert_eq!(piecewise_linear(&[], 0.3), 0.3);
    }

    #[test]
    fn sidecar_round_trips_and_bad_files_are_clear_errors() {
        let dir = std::env::temp_dir().join(format!("likeness-mapping-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let puppet = dir.join("hero.glb");
        let sidecar = sidecar_path(&puppet);
        assert_eq!(sidecar.file_name().unwrap(), "hero.mapping.json");
        let mut data = MappingData::default();
        data.channels.push(ChannelMapping {
            targets: vec!["MouthOpen".into()],
            gain: 0.8,
            curve: vec![[0.0, 0.0], [1.0, 1.0]],
            ..ChannelMapping::identity("JawOpen")
        });
        let mut rest = [0.0; face::NUM_ARKIT];
        rest[face::names::arkit_index("mouthPucker").unwrap()] = 0.25;
        data.calibrate_neutral(&rest);
        data.save(&sidecar).unwrap();
        assert_eq!(MappingData::load_for_puppet(&puppet).unwrap(), data);

        for (text, expect) in [
            ("{", "EOF"),
            (r#"{"version": 2}"#, "version 2"),
            (
                r#"{"version": 1, "channels": [{"source": "frown"}]}"#,
                "unknown source",
            ),
            (
                r#"{"version": 1, "channels": [{"source": "jawOpen", "clamp": [1, 0]}]}"#,
                "low end",
            ),
            (
                r#"{"version": 1, "channels": [{"source": "jawOpen", "curve": [[0.5, 0], [0.5, 1]]}]}"#,
                "increase strictly",
            ),
            (r#"{"version": 1, "neutral": {"jawOpen": 1.5}}"#, "outside"),
            (r#"{"version": 1, "gains": {}}"#, "unknown field"),
        ] {
            std::fs::write(&sidecar, text).unwrap();
            let err = MappingData::load(&sidecar).unwrap_err().to_string();
            assert!(
                err.contains(expect) && err.contains("hero.mapping.json"),
                "{text}: {err}"
            );
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
