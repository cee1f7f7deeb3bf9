//! Temporal smoothing against independent expectations: the closed-form first-order
//! low-pass, exact pass-through cases, a noisy sine with known noise, and a blink.

mod common;

use std::f64::consts::PI;

use common::noise;

use face::names::ict_index;
use glam::Vec3;
use tracking::FaceParams;
use tracking::smooth::{
    FaceParamsSmoother, MIN_DT_S, OneEuroFilter, OneEuroParams, SmoothingConfig, smoothing_factor,
};

fn varied_params(k: u32) -> FaceParams {
    let mut p = FaceParams::default();
    for (i, w) in p.weights.iter_mut().enumerate() {
        *w = (0.5 + 0.5 * noise(k * 1000 + i as u32)) as f32;
    }
    p.pose.euler_rad = Vec3::new(0.3, -0.2, 0.1) + 0.05 * noise(k * 7 + 3) as f32;
    p.pose.translation = Vec3::new(1.0, -2.0, -55.0) + noise(k * 5 + 1) as f32;
    for (i, g) in p.gamma.iter_mut().enumerate() {
        *g += 0.1 * noise(k * 300 + i as u32) as f32;
    }
    p
}

fn smoother(config: SmoothingConfig) -> FaceParamsSmoother {
    FaceParamsSmoother::try_new(config).unwrap_or_else(|e| panic!("{e}"))
}

#[test]
fn constant_input_passes_unchanged_after_the_first_sample() {
    let p = varied_params(1);
    let mut s = smoother(SmoothingConfig::default());
    // Irregular timestamps: the constant must survive any dt.
    let mut t = 0.0;
    for k in 0..50 {
        t += 0.01 + 0.03 * (noise(k) + 1.0);
        assert_eq!(s.filter(t, &p), p, "frame {k}");
    }
}

#[test]
fn beta_zero_is_a_first_order_low_pass_with_the_closed_form_alpha() {
    // Cutoff chosen so that tau = 1 / (2 pi fc) equals dt = 1/30 s: alpha = 1/(1 + 1) = 1/2
    // exactly, so the step response after n steps is 1 - 2^-n.
    let dt = 1.0 / 30.0;
    let fc = 1.0 / (2.0 * PI * dt);
    assert!((smoothing_factor(dt, fc) - 0.5).abs() < 1e-15);
    let mut f = OneEuroFilter::new(OneEuroParams::new(fc, 0.0, 1.0));
    assert_eq!(f.filter(0.0, 0.0), 0.0);
    for n in 1..=12 {
        let y = f.filter(n as f64 * dt, 1.0);
        let expected = 1.0 - 0.5f64.powi(n);
        assert!((y - expected).abs() < 1e-12, "step {n}: {y} vs {expected}");
    }

    // Irregular steps: each one must use alpha = 1 / (1 + tau / dt_n) with its own dt_n.
    let fc = 2.5;
    let tau = 1.0 / (2.0 * PI * fc);
    let mut f = OneEuroFilter::new(OneEuroParams::new(fc, 0.0, 1.0));
    f.filter(10.0, 0.0);
    let (mut t, mut expected) = (10.0, 0.0);
    for k in 0..40 {
        let dt = 0.005 + 0.05 * (noise(100 + k) + 1.0);
        t += dt;
        expected += (1.0 - expected) / (1.0 + tau / dt);
        let y = f.filter(t, 1.0);
        assert!((y - expected).abs() < 1e-12, "step {k}: {y} vs {expected}");
    }
}

/// (noise variance ratio, worst lag at the sine's fastest point in seconds) of the filter
/// on a 0.5 Hz, amplitude-0.4 sine sampled at 60 fps with uniform noise of standard
/// deviation 0.01. The noise passed through is the difference between the outputs on the
/// noisy and the clean sine; the lag is where the filtered clean sine crosses the mean
/// upwards, compared with the true crossing.
fn sine_response(params: OneEuroParams) -> (f64, f64) {
    let (fps, freq, amplitude, sigma) = (60.0, 0.5, 0.4, 0.01);
    let mut noisy = OneEuroFilter::new(params);
    let mut clean = OneEuroFilter::new(params);
    let n = 20 * 60;
    let warmup = 2 * 60;
    let (mut noise_power, mut count) = (0.0, 0.0);
    let mut clean_out = Vec::with_capacity(n);
    for i in 0..n {
        let t = i as f64 / fps;
        let s = 0.5 + amplitude * (2.0 * PI * freq * t).sin();
        // Uniform on [-sqrt(3) sigma, sqrt(3) sigma] has standard deviation sigma.
        let e = 3f64.sqrt() * sigma * noise(i as u32 + 77);
        let yn = noisy.filter(t, s + e);
        let yc = clean.filter(t, s);
        clean_out.push(yc);
        if i >= warmup {
            noise_power += (yn - yc).powi(2);
            count += 1.0;
        }
    }
    let mut worst_lag: f64 = 0.0;
    for i in warmup..n - 1 {
        let (a, b) = (clean_out[i], clean_out[i + 1]);
        if a < 0.5 && b >= 0.5 {
            let crossing = (i as f64 + (0.5 - a) / (b - a)) / fps;
            let truth = (crossing * freq).round() / freq;
            worst_lag = worst_lag.max(crossing - truth);
        }
    }
    (noise_power / count / (sigma * sigma), worst_lag)
}

#[test]
fn noisy_sine_loses_most_noise_and_little_lag_with_beta() {
    let weights = SmoothingConfig::default().weights;
    let (variance_ratio, lag) = sine_response(weights);
    // Stated bounds: the noise variance drops at least 2.5x, and at the sine's top speed
    // (1.26 per second) the output lags by less than 25 ms (1.5 frames at 60 fps).
    assert!(
        variance_ratio < 0.4,
        "noise variance ratio {variance_ratio}"
    );
    assert!(lag > 0.0 && lag < 0.025, "lag {lag} s");
    // The same filter without the speed term lags several times more: beta does the work.
    let (plain_ratio, plain_lag) = sine_response(OneEuroParams {
        beta: 0.0,
        ..weights
    });
    assert!(plain_lag > 0.1, "beta = 0 lag {plain_lag} s");
    assert!(plain_ratio < variance_ratio);
}

fn blink_peak(profile: &[f32]) -> f32 {
    let blink = ict_index("eyeBlink_L").unwrap_or_else(|| panic!("no eyeBlink_L"));
    let mut s = smoother(SmoothingConfig::default());
    let fps = 30.0;
    let mut values = vec![0.0f32; 30];
    values.extend_from_slice(profile);
    values.extend([0.0; 10]);
    let mut peak: f32 = 0.0;
    for (i, v) in values.iter().enumerate() {
        let mut p = FaceParams::default();
        // Realistic weight jitter at rest on the other channels and on the blink itself.
        for (c, w) in p.weights.iter_mut().enumerate() {
            *w = (0.05 + 0.02 * noise((i * 64 + c) as u32)) as f32;
        }
        p.weights[blink] = *v;
        let out = s.filter(i as f64 / fps, &p);
        if i >= 30 {
            peak = peak.max(out.weights[blink]);
        }
    }
    peak
}

#[test]
fn a_blink_survives_the_default_weight_smoothing() {
    // 0 -> 1 -> 0 within 100 ms at 30 fps: closed for one frame or for two.
    let one = blink_peak(&[1.0]);
    let two = blink_peak(&[1.0, 1.0]);
    assert!(one > 0.8, "one-frame blink peaks at {one}");
    assert!(two > 0.8, "two-frame blink peaks at {two}");
}

#[test]
fn off_is_identity() {
    let mut a = FaceParamsSmoother::off();
    let mut b = smoother(SmoothingConfig::off());
    for k in 0..20 {
        let p = varied_params(k);
        let t = f64::from(k) / 30.0;
        assert_eq!(a.filter(t, &p), p);
        assert_eq!(b.filter(t, &p), p);
    }
}

#[test]
fn reset_and_backwards_time_start_a_new_sequence() {
    let mut s = smoother(SmoothingConfig::default());
    for k in 0..10 {
        s.filter(f64::from(k) / 30.0, &varied_params(k));
    }
    let fresh = varied_params(99);
    let smoothed = s.filter(10.0 / 30.0, &fresh);
    assert_ne!(smoothed, fresh);
    s.reset();
    assert_eq!(s.filter(11.0 / 30.0, &fresh), fresh);
    // A timestamp going backwards (a seek) also passes the sample through.
    for k in 12..20 {
        s.filter(f64::from(k) / 30.0, &varied_params(k));
    }
    let other = varied_params(123);
    assert_ne!(s.filter(20.0 / 30.0, &other), other);
    assert_eq!(s.filter(0.5, &fresh), fresh);
    // A non-finite timestamp likewise.
    assert_eq!(s.filter(f64::NAN, &other), other);
}

#[test]
fn invalid_parameters_are_reported_or_passed_through() {
    let bad = SmoothingConfig {
        weights: OneEuroParams::new(0.0, 1.0, 1.0),
        ..SmoothingConfig::default()
    };
    match FaceParamsSmoother::try_new(bad.clone()) {
        Ok(_) => panic!("a zero cutoff was accepted"),
        Err(e) => assert!(e.to_string().contains("weights.min_cutoff"), "{e}"),
    }
    // `new` keeps the valid groups and passes the invalid one through.
    let mut s = FaceParamsSmoother::new(bad);
    s.filter(0.0, &varied_params(1));
    let p = varied_params(2);
    let out = s.filter(1.0 / 30.0, &p);
    assert_eq!(out.weights, p.weights);
    assert_ne!(out.gamma, p.gamma);
}

#[test]
fn equal_timestamps_use_the_minimum_dt() {
    let p = OneEuroParams::new(3.0, 0.0, 1.0);
    let mut f = OneEuroFilter::new(p);
    f.filter(1.0, 0.0);
    let y = f.filter(1.0, 1.0);
    let expected = smoothing_factor(MIN_DT_S, 3.0);
    assert!((y - expected).abs() < 1e-15, "{y} vs {expected}");
}

#[test]
fn weights_stay_in_range_and_angles_do_not_wrap_through_zero() {
    let mut s = smoother(SmoothingConfig::default());
    let mut high = FaceParams {
        weights: [1.3; 53],
        ..FaceParams::default()
    };
    high.pose.euler_rad.z = 3.1;
    let out = s.filter(0.0, &high);
    assert!(out.weights.iter().all(|w| *w == 1.0));
    // Roll crossing +-pi: -3.1 is 0.08 rad from 3.1, so the output stays near +-pi
    // instead of averaging towards 0.
    let mut across = high;
    across.weights = [-0.2; 53];
    across.pose.euler_rad.z = -3.1;
    for k in 1..10 {
        let out = s.filter(f64::from(k) / 30.0, &across);
        assert!(out.weights.iter().all(|w| (0.0..=1.0).contains(w)));
        let roll = f64::from(out.pose.euler_rad.z);
        assert!(
            roll.abs() > 3.09 && roll.abs() <= PI,
            "frame {k}: roll {roll}"
        );
    }
}

#[test]
fn parses_presets_uniform_and_group_values() {
    let parse = |s: &str| {
        s.parse::<SmoothingConfig>()
            .unwrap_or_else(|e| panic!("`{s}`: {e}"))
    };
    assert!(!parse("off").enabled);
    assert_eq!(parse("default"), SmoothingConfig::default());
    let c = parse("min_cutoff=1.0,beta=0.3");
    for g in [c.weights, c.rotation, c.translation, c.lighting] {
        assert_eq!((g.min_cutoff, g.beta), (1.0, 0.3));
    }
    assert_eq!(
        c.weights.d_cutoff,
        SmoothingConfig::default().weights.d_cutoff
    );
    let c = parse("weights.beta=2, rotation.min_cutoff=0.5,lighting.d_cutoff=3");
    let d = SmoothingConfig::default();
    assert_eq!(c.weights.beta, 2.0);
    assert_eq!(c.weights.min_cutoff, d.weights.min_cutoff);
    assert_eq!(c.rotation.min_cutoff, 0.5);
    assert_eq!(c.lighting.d_cutoff, 3.0);
    assert_eq!(c.translation, d.translation);
    assert_eq!(parse("beta=0").weights.beta, 0.0);
}

#[test]
fn parse_errors_name_the_key() {
    for (text, key) in [
        ("speed=1", "speed"),
        ("weights.speed=1", "weights.speed"),
        ("eyes.beta=1", "eyes.beta"),
        ("beta=-1", "beta"),
        ("weights.min_cutoff=0", "weights.min_cutoff"),
        ("min_cutoff=nan", "min_cutoff"),
        ("rotation.d_cutoff=inf", "rotation.d_cutoff"),
        ("translation.beta=fast", "translation.beta"),
        ("lighting.beta", "lighting.beta"),
    ] {
        match text.parse::<SmoothingConfig>() {
            Ok(c) => panic!("`{text}` parsed as {c:?}"),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.contains(key), "`{text}`: {msg}");
            }
        }
    }
}
