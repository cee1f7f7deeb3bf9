//! Frame-rate measurement of the real studio window (`likeness studio --measure-fps`): the
//! time between consecutive UI frames while a panel plays the clip, which includes egui's
//! paint and the presentation of the previous frame, i.e. what a user sees.
//!
//! This is the number the studio's 60 fps goal is about; `bench-studio` (headless, with a
//! read-back instead of a presentation) breaks a frame into its parts.

use std::sync::{Arc, Mutex};
use web_time::{Duration, Instant};

/// What a finished measurement found.
#[derive(Clone, Debug, PartialEq)]
pub struct FpsReport {
    pub panel: String,
    pub frames: usize,
    pub seconds: f64,
    /// Frame intervals, milliseconds.
    pub mean_ms: f64,
    pub median_ms: f64,
    pub p95_ms: f64,
    pub worst_ms: f64,
}

impl FpsReport {
    /// Frames per second over the whole measurement.
    pub fn fps(&self) -> f64 {
        self.frames as f64 / self.seconds.max(1e-9)
    }

    /// Summarises frame intervals (milliseconds) measured over `seconds`.
    pub fn from_intervals(panel: &str, mut intervals_ms: Vec<f64>, seconds: f64) -> Option<Self> {
        if intervals_ms.is_empty() {
            return None;
        }
        intervals_ms.sort_by(f64::total_cmp);
        let n = intervals_ms.len();
        let at = |q: f64| intervals_ms[((n as f64 * q) as usize).min(n - 1)];
        Some(Self {
            panel: panel.to_owned(),
            frames: n,
            seconds,
            mean_ms: intervals_ms.iter().sum::<f64>() / n as f64,
            median_ms: at(0.5),
            p95_ms: at(0.95),
            worst_ms: intervals_ms[n - 1],
        })
    }
}

/// Watches the studio's frames: a warm-up (textures, pipelines, the first clip frames),
/// then `measure` of timed frames, then asks the window to close.
pub struct FpsProbe {
    pub panel: String,
    warmup: Duration,
    measure: Duration,
    started: Option<Instant>,
    measuring_since: Option<Instant>,
    last_frame: Option<Instant>,
    intervals_ms: Vec<f64>,
    /// Where the report goes when the measurement ends (read after the window closes).
    pub report: Arc<Mutex<Option<FpsReport>>>,
}

impl FpsProbe {
    pub fn new(panel: &str, warmup: Duration, measure: Duration) -> Self {
        Self {
            panel: panel.to_owned(),
            warmup,
            measure,
            started: None,
            measuring_since: None,
            last_frame: None,
            intervals_ms: Vec::new(),
            report: Arc::new(Mutex::new(None)),
        }
    }

    /// Records a frame starting at `now`; true once the measurement is over (the report
    /// is then stored).
    pub fn frame(&mut self, now: Instant) -> bool {
        let started = *self.started.get_or_insert(now);
        if now.duration_since(started) < self.warmup {
            return false;
        }
        let since = *self.measuring_since.get_or_insert(now);
        if let Some(last) = self.last_frame.filter(|&l| l >= since) {
            self.intervals_ms
                .push(now.duration_since(last).as_secs_f64() * 1000.0);
        }
        self.last_frame = Some(now);
        let elapsed = now.duration_since(since);
        if elapsed < self.measure {
            return false;
        }
        let report = FpsReport::from_intervals(
            &self.panel,
            std::mem::take(&mut self.intervals_ms),
            elapsed.as_secs_f64(),
        );
        // A poisoned lock means the reader panicked; there is nobody left to tell.
        if let Ok(mut slot) = self.report.lock() {
            *slot = report;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_of_steady_frames() {
        let mut probe = FpsProbe::new("puppet", Duration::from_millis(100), Duration::from_secs(1));
        let t0 = Instant::now();
        // 10 ms frames: 10 warm-up frames, then 100 intervals in the measured second.
        let mut done = false;
        let mut k = 0;
        while !done {
            done = probe.frame(t0 + Duration::from_millis(10 * k));
            k += 1;
        }
        let report = probe.report.lock().unwrap().clone().expect("report");
        assert_eq!(report.frames, 100);
        assert!((report.mean_ms - 10.0).abs() < 1e-6, "{report:?}");
        assert!((report.fps() - 100.0).abs() < 1e-6, "{report:?}");
        assert!((report.worst_ms - 10.0).abs() < 1e-6);
    }

    #[test]
    fn percentiles_of_uneven_frames() {
        let mut intervals: Vec<f64> = vec![10.0; 95];
        intervals.extend([50.0; 5]);
        let r = FpsReport::from_intervals("face", intervals, 0.75).expect("report");
        assert_eq!(r.median_ms, 10.0);
        assert_eq!(r.p95_ms, 50.0);
        assert_eq!(r.worst_ms, 50.0);
        assert!((r.mean_ms - 12.0).abs() < 1e-9);
        assert!(FpsReport::from_intervals("x", Vec::new(), 1.0).is_none());
    }
}
