//! Temporal smoothing of the per-frame tracking parameters p = (w, R, t, gamma).
//!
//! The paper reconstructs every frame independently and notes that "some temporal smoothing
//! as a post-processing step will produce better results" (supplementary, on videos). Per
//! frame estimates jitter (TrackNet sees a slightly different crop each frame, the landmark
//! detector is noisy), while real motion is either slow (head drift, lighting) or very fast
//! (a blink closes and opens in about 100 ms). A fixed low-pass cannot serve both, so every
//! channel goes through a One-Euro filter (Casiez, Roussel and Vogel, CHI 2012): a
//! first-order low-pass whose cutoff rises with the (low-passed) speed of the signal,
//! fc = min_cutoff + beta |dx/dt|. At rest it removes jitter; during fast motion it opens
//! up and the lag vanishes.
//!
//! Timestamps are in seconds and may have any spacing (variable frame rate, dropped
//! frames): the filter's per-step factor is computed from the actual dt.

use std::f64::consts::PI;
use std::fmt;
use std::str::FromStr;

use face::NUM_BLENDSHAPES;
use face::sh::SH_COEFFICIENTS;
use glam::Vec3;

use crate::error::TrackingError;
use crate::params::FaceParams;

/// The smallest time step the filter uses. Two samples with the same timestamp (a
/// duplicated frame, a coarse clock) are treated as this far apart instead of dividing by
/// zero; see [`OneEuroFilter::filter`].
pub const MIN_DT_S: f64 = 1e-3;

/// Parameters of one One-Euro filter.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OneEuroParams {
    /// Cutoff frequency at rest, in Hz: lower removes more jitter but lags more on slow
    /// motion. Must be > 0.
    pub min_cutoff: f64,
    /// How fast the cutoff grows with speed, in Hz per (unit of the channel per second):
    /// higher follows fast motion with less lag but lets more jitter through while moving.
    /// Must be >= 0; 0 makes the filter a plain first-order low-pass at `min_cutoff`.
    pub beta: f64,
    /// Cutoff of the low-pass on the speed estimate, in Hz. Must be > 0.
    pub d_cutoff: f64,
}

impl OneEuroParams {
    pub const fn new(min_cutoff: f64, beta: f64, d_cutoff: f64) -> Self {
        Self {
            min_cutoff,
            beta,
            d_cutoff,
        }
    }

    /// Checks the ranges, naming `what` (e.g. `weights`) in the error.
    pub fn validate(&self, what: &str) -> Result<(), TrackingError> {
        let check = |key: &str, v: f64, positive: bool| {
            let ok = v.is_finite() && if positive { v > 0.0 } else { v >= 0.0 };
            if ok {
                Ok(())
            } else {
                let need = if positive { "> 0" } else { ">= 0" };
                Err(TrackingError::InvalidInput(format!(
                    "smoothing `{what}.{key}` is {v}, must be a finite number {need}"
                )))
            }
        };
        check("min_cutoff", self.min_cutoff, true)?;
        check("beta", self.beta, false)?;
        check("d_cutoff", self.d_cutoff, true)
    }
}

/// Smoothing factor of a first-order low-pass with cutoff `fc` (Hz) over a step `dt` (s):
/// alpha = 1 / (1 + tau / dt) with time constant tau = 1 / (2 pi fc), the exponential
/// smoothing form Casiez et al. use (x_hat = alpha x + (1 - alpha) x_hat_prev).
pub fn smoothing_factor(dt: f64, fc: f64) -> f64 {
    let tau = 1.0 / (2.0 * PI * fc);
    1.0 / (1.0 + tau / dt)
}

/// A One-Euro filter on one scalar channel.
#[derive(Clone, Debug, PartialEq)]
pub struct OneEuroFilter {
    params: OneEuroParams,
    /// (time, filtered value, filtered derivative) of the last sample; `None` before the
    /// first sample of a sequence.
    state: Option<(f64, f64, f64)>,
}

impl OneEuroFilter {
    pub fn new(params: OneEuroParams) -> Self {
        Self {
            params,
            state: None,
        }
    }

    pub fn params(&self) -> OneEuroParams {
        self.params
    }

    /// Forgets the history: the next sample starts a new sequence.
    pub fn reset(&mut self) {
        self.state = None;
    }

    /// Filters sample `x` taken at `time_s` seconds.
    ///
    /// - The first sample of a sequence passes through unchanged (there is nothing to
    ///   average with).
    /// - A timestamp earlier than the previous one (a seek, a restarted source) or a
    ///   non-finite one starts a new sequence: the sample passes through.
    /// - An equal timestamp is treated as [`MIN_DT_S`] later.
    /// - A non-finite `x` is returned as it is without touching the state, so one bad value
    ///   neither poisons the following frames nor gets hidden from the caller.
    pub fn filter(&mut self, time_s: f64, x: f64) -> f64 {
        if !x.is_finite() {
            return x;
        }
        let Some((t_prev, x_prev, dx_prev)) = self
            .state
            .filter(|(t, _, _)| time_s.is_finite() && time_s >= *t)
        else {
            self.state = time_s.is_finite().then_some((time_s, x, 0.0));
            return x;
        };
        let dt = (time_s - t_prev).max(MIN_DT_S);
        let p = self.params;
        // Speed from the previous *filtered* value, low-passed at d_cutoff (the paper's
        // choice: the raw finite difference of jittery samples is mostly noise).
        let dx = (x - x_prev) / dt;
        let a_d = smoothing_factor(dt, p.d_cutoff);
        let dx_hat = a_d * dx + (1.0 - a_d) * dx_prev;
        let fc = p.min_cutoff + p.beta * dx_hat.abs();
        let a = smoothing_factor(dt, fc);
        let x_hat = a * x + (1.0 - a) * x_prev;
        self.state = Some((time_s, x_hat, dx_hat));
        x_hat
    }
}

/// One-Euro parameters per group of [`FaceParams`] channels, or smoothing switched off.
///
/// Default values (30-60 fps video, TrackNet plus refinement):
/// - weights w (unitless, [0, 1]): min_cutoff 1 Hz, beta 4, d_cutoff 2 Hz. A blink closes
///   and opens within ~100 ms, i.e. |dw/dt| around 10-30 per second; beta = 4 lifts the
///   cutoff to tens of Hz at that speed so a 2-frame blink at 30 fps still peaks above 0.95
///   (a 1-frame blink above 0.85), while weight jitter of 0.02 at rest keeps the cutoff near
///   1 Hz (its standard deviation drops to about half at 30 fps). d_cutoff 2 Hz (Casiez et
///   al. suggest 1) lets the speed estimate react within one or two frames of a blink.
/// - rotation (radians): min_cutoff 0.8 Hz, beta 5, d_cutoff 1 Hz. Pose jitter is a few
///   tenths of a degree, which is what makes an avatar shimmer; a head turning at 1 rad/s
///   gets a cutoff near 6 Hz (lag ~30 ms).
/// - translation (centimetres): min_cutoff 0.8 Hz, beta 0.5, d_cutoff 1 Hz: moving at
///   10 cm/s gives a cutoff near 6 Hz, like the rotation.
/// - lighting gamma: min_cutoff 0.5 Hz, beta 0: the light changes over seconds, and any
///   faster change in the estimate is flicker.
///
/// Parsed from text by [`FromStr`], for command lines: `off`, `default`, `key=value` pairs
/// separated by commas where a bare key (`min_cutoff`, `beta`, `d_cutoff`) applies to every
/// group and a qualified one (`weights.beta`, `rotation.min_cutoff`, `translation.d_cutoff`,
/// `lighting.min_cutoff`, ...) to one group; unset values keep their defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SmoothingConfig {
    /// `false`: pass-through (single images, or when a later stage smooths).
    pub enabled: bool,
    pub weights: OneEuroParams,
    pub rotation: OneEuroParams,
    pub translation: OneEuroParams,
    pub lighting: OneEuroParams,
}

impl Default for SmoothingConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            weights: OneEuroParams::new(1.0, 4.0, 2.0),
            // Rotation and position: measured on the held-out clips (tracking/README.md),
            // 0.8 Hz cutoffs lagged a moving head by ~1 % NME; these keep the jitter
            // reduction with about half that lag.
            rotation: OneEuroParams::new(2.0, 5.0, 1.0),
            translation: OneEuroParams::new(3.0, 5.0, 1.0),
            lighting: OneEuroParams::new(0.5, 0.0, 1.0),
        }
    }
}

/// The groups of channels, by the names [`SmoothingConfig`]'s text form uses.
const GROUPS: [&str; 4] = ["weights", "rotation", "translation", "lighting"];
const KEYS: [&str; 3] = ["min_cutoff", "beta", "d_cutoff"];

impl SmoothingConfig {
    /// Smoothing switched off: [`FaceParamsSmoother::filter`] returns its input.
    pub fn off() -> Self {
        Self {
            enabled: false,
            ..Self::default()
        }
    }

    /// The same parameters for every group.
    pub fn uniform(params: OneEuroParams) -> Self {
        Self {
            enabled: true,
            weights: params,
            rotation: params,
            translation: params,
            lighting: params,
        }
    }

    /// Checks every group's ranges (see [`OneEuroParams`]).
    pub fn validate(&self) -> Result<(), TrackingError> {
        for (name, p) in GROUPS.iter().zip(self.groups()) {
            p.validate(name)?;
        }
        Ok(())
    }

    fn groups(&self) -> [OneEuroParams; 4] {
        [self.weights, self.rotation, self.translation, self.lighting]
    }

    fn group_mut(&mut self, name: &str) -> Option<&mut OneEuroParams> {
        match name {
            "weights" => Some(&mut self.weights),
            "rotation" => Some(&mut self.rotation),
            "translation" => Some(&mut self.translation),
            "lighting" => Some(&mut self.lighting),
            _ => None,
        }
    }
}

fn set_key(p: &mut OneEuroParams, key: &str, value: f64) {
    match key {
        "min_cutoff" => p.min_cutoff = value,
        "beta" => p.beta = value,
        "d_cutoff" => p.d_cutoff = value,
        _ => {}
    }
}

impl FromStr for SmoothingConfig {
    type Err = TrackingError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let text = s.trim();
        match text {
            "off" | "none" => return Ok(Self::off()),
            "default" | "on" | "" => return Ok(Self::default()),
            _ => {}
        }
        let mut config = Self::default();
        for item in text.split(',').map(str::trim).filter(|i| !i.is_empty()) {
            let Some((key, value)) = item.split_once('=') else {
                return Err(TrackingError::InvalidInput(format!(
                    "smoothing option `{item}` is not key=value (expected `off`, `default` or \
                     e.g. `min_cutoff=1.0,weights.beta=4`)"
                )));
            };
            let (key, value) = (key.trim(), value.trim());
            // The key first, so a typo is reported as such whatever the value.
            let (group, field) = match key.split_once('.') {
                None => (None, key),
                Some((group, field)) => (Some(group), field),
            };
            let known_group = group.is_none_or(|g| GROUPS.contains(&g));
            if !known_group || !KEYS.contains(&field) {
                return Err(TrackingError::InvalidInput(format!(
                    "unknown smoothing key `{key}` (keys: {}, each optionally qualified by a \
                     group: {})",
                    KEYS.join(", "),
                    GROUPS.map(|g| format!("{g}.")).join(", ")
                )));
            }
            let parsed: f64 = value.parse().map_err(|_| {
                TrackingError::InvalidInput(format!(
                    "smoothing `{key}` = `{value}` is not a number"
                ))
            })?;
            // beta = 0 is meaningful (a plain low-pass); a zero cutoff would freeze the
            // output.
            let zero_ok = field == "beta";
            if !parsed.is_finite() || parsed < 0.0 || (!zero_ok && parsed == 0.0) {
                let need = if zero_ok { ">= 0" } else { "> 0" };
                return Err(TrackingError::InvalidInput(format!(
                    "smoothing `{key}` = {value}: must be a finite number {need}"
                )));
            }
            for name in GROUPS.into_iter().filter(|&n| group.is_none_or(|g| g == n)) {
                if let Some(p) = config.group_mut(name) {
                    set_key(p, field, parsed);
                }
            }
        }
        config.validate()?;
        Ok(config)
    }
}

impl fmt::Display for SmoothingConfig {
    /// The text form [`FromStr`] reads back: `off`, or every group's three values.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if !self.enabled {
            return f.write_str("off");
        }
        let mut first = true;
        for (name, p) in GROUPS.iter().zip(self.groups()) {
            for (key, v) in KEYS.iter().zip([p.min_cutoff, p.beta, p.d_cutoff]) {
                if !first {
                    f.write_str(",")?;
                }
                first = false;
                write!(f, "{name}.{key}={v}")?;
            }
        }
        Ok(())
    }
}

const NUM_CHANNELS: usize = NUM_BLENDSHAPES + 3 + 3 + SH_COEFFICIENTS;

/// One channel's filter, `None` (pass-through) when its group's parameters are invalid.
#[derive(Clone, Debug)]
struct ChannelFilter(Option<OneEuroFilter>);

impl ChannelFilter {
    fn filter(&mut self, time_s: f64, x: f64) -> f64 {
        match &mut self.0 {
            Some(f) => f.filter(time_s, x),
            None => x,
        }
    }
}

/// One-Euro filters on every channel of [`FaceParams`]: 53 weights, the three Euler angles,
/// the translation and the 27 SH coefficients.
///
/// Euler angles are filtered unwrapped (each sample is moved by a multiple of 2 pi to the
/// branch nearest the previous output), so a roll crossing +-180 degrees is not averaged
/// into 0; the output is wrapped back to (-pi, pi]. Weights are clamped to [0, 1] (a convex
/// combination of valid weights already is; the clamp only guards inputs outside the range).
#[derive(Clone, Debug)]
pub struct FaceParamsSmoother {
    config: SmoothingConfig,
    filters: Vec<ChannelFilter>,
    /// Last unwrapped Euler angles, for choosing the branch of the next sample.
    last_euler: Option<[f64; 3]>,
}

impl FaceParamsSmoother {
    /// A smoother with `config`. A group whose parameters are out of range (see
    /// [`SmoothingConfig::validate`], which [`FromStr`] already applies) passes through
    /// unfiltered rather than freezing or diverging; use [`FaceParamsSmoother::try_new`]
    /// to have that reported instead.
    pub fn new(config: SmoothingConfig) -> Self {
        let mut filters = Vec::with_capacity(NUM_CHANNELS);
        let groups = [
            ("weights", config.weights, NUM_BLENDSHAPES),
            ("rotation", config.rotation, 3),
            ("translation", config.translation, 3),
            ("lighting", config.lighting, SH_COEFFICIENTS),
        ];
        for (name, params, count) in groups {
            let params = params.validate(name).ok().map(|_| params);
            filters.extend((0..count).map(|_| ChannelFilter(params.map(OneEuroFilter::new))));
        }
        Self {
            config,
            filters,
            last_euler: None,
        }
    }

    /// [`FaceParamsSmoother::new`] after checking `config`.
    pub fn try_new(config: SmoothingConfig) -> Result<Self, TrackingError> {
        config.validate()?;
        Ok(Self::new(config))
    }

    /// Pass-through (the mode for single images).
    pub fn off() -> Self {
        Self {
            config: SmoothingConfig::off(),
            filters: Vec::new(),
            last_euler: None,
        }
    }

    pub fn config(&self) -> &SmoothingConfig {
        &self.config
    }

    /// Forgets the history (the face was lost, or a new clip starts): the next frame passes
    /// through unchanged.
    pub fn reset(&mut self) {
        self.filters
            .iter_mut()
            .filter_map(|f| f.0.as_mut())
            .for_each(OneEuroFilter::reset);
        self.last_euler = None;
    }

    /// Smooths the parameters of the frame at `time_s` seconds (see
    /// [`OneEuroFilter::filter`] for the handling of unusual timestamps).
    pub fn filter(&mut self, time_s: f64, params: &FaceParams) -> FaceParams {
        if !self.config.enabled || self.filters.len() != NUM_CHANNELS {
            return *params;
        }
        let (w_filters, rest) = self.filters.split_at_mut(NUM_BLENDSHAPES);
        let (r_filters, rest) = rest.split_at_mut(3);
        let (t_filters, g_filters) = rest.split_at_mut(3);
        let mut out = *params;
        for ((o, x), f) in out.weights.iter_mut().zip(&params.weights).zip(w_filters) {
            let y = f.filter(time_s, f64::from(*x)) as f32;
            *o = if y.is_finite() { y.clamp(0.0, 1.0) } else { y };
        }
        let euler = params.pose.euler_rad.to_array().map(f64::from);
        let continuous = match self.last_euler {
            Some(prev) => std::array::from_fn(|i| unwrap_near(euler[i], prev[i])),
            None => euler,
        };
        let mut filtered = [0.0f64; 3];
        for ((o, x), f) in filtered.iter_mut().zip(continuous).zip(r_filters) {
            *o = f.filter(time_s, x);
        }
        if filtered.iter().all(|v| v.is_finite()) {
            self.last_euler = Some(filtered);
        }
        out.pose.euler_rad = Vec3::from_array(filtered.map(|a| wrap_angle(a) as f32));
        let translation = params.pose.translation.to_array();
        let mut t_out = [0.0f32; 3];
        for ((o, x), f) in t_out.iter_mut().zip(translation).zip(t_filters) {
            *o = f.filter(time_s, f64::from(x)) as f32;
        }
        out.pose.translation = Vec3::from_array(t_out);
        for ((o, x), f) in out.gamma.iter_mut().zip(&params.gamma).zip(g_filters) {
            *o = f.filter(time_s, f64::from(*x)) as f32;
        }
        out
    }
}

/// `angle` moved by a multiple of 2 pi to lie within pi of `reference`.
fn unwrap_near(angle: f64, reference: f64) -> f64 {
    if !angle.is_finite() || !reference.is_finite() {
        return angle;
    }
    let turns = ((reference - angle) / (2.0 * PI)).round();
    angle + turns * 2.0 * PI
}

/// `angle` in (-pi, pi].
fn wrap_angle(angle: f64) -> f64 {
    // Angles already in range are returned bit for bit (constant input stays constant).
    if !angle.is_finite() || (angle > -PI && angle <= PI) {
        return angle;
    }
    let a = angle.rem_euclid(2.0 * PI);
    if a > PI { a - 2.0 * PI } else { a }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_helpers() {
        assert!((unwrap_near(-3.1, 3.1) - (2.0 * PI - 3.1)).abs() < 1e-12);
        assert!((unwrap_near(0.2, 0.1) - 0.2).abs() < 1e-12);
        assert!((wrap_angle(3.2) - (3.2 - 2.0 * PI)).abs() < 1e-12);
        assert!((wrap_angle(-3.2) - (2.0 * PI - 3.2)).abs() < 1e-12);
        assert_eq!(wrap_angle(PI), PI);
    }

    #[test]
    fn display_round_trips() {
        for c in [
            SmoothingConfig::default(),
            SmoothingConfig::off(),
            SmoothingConfig::uniform(OneEuroParams::new(0.25, 0.0, 3.5)),
        ] {
            let back: SmoothingConfig = c.to_string().parse().unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(back.enabled, c.enabled);
            if c.enabled {
                assert_eq!(back, c);
            }
        }
    }
}
