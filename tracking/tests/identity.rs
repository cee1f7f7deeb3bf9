//! The identity fitted to a clip (tracking::identity) against known synthetic truth: frames
//! of a person made from the template and known identity coefficients, under known weights
//! and poses, their points projected exactly.

mod common;

use face::camera::{HeadPose, Intrinsics};
use face::names::ict_index;
use face::{PersonalizedBlendshapes, Template};
use glam::Vec3;
use tracking::FaceParams;
use tracking::identity::{ClipFrame, IdentityConfig, fit_identity, with_identity};
use tracking::refine::{FitPoints, LandmarkObservations, RefineConfig, Refiner};

fn camera() -> Intrinsics {
    Intrinsics::centered(640, 480, 600.0)
}

/// Twelve frames: yaw -25..25 degrees, pitch and expressions varying.
fn clip_params() -> Vec<FaceParams> {
    (0..12)
        .map(|n| {
            let t = n as f32 / 11.0;
            let mut p = FaceParams::default();
            p.weights[ict_index("jawOpen").unwrap_or(0)] = 0.5 * t;
            p.weights[ict_index("mouthSmile_L").unwrap_or(0)] = 0.6 * (1.0 - t);
            p.weights[ict_index("eyeBlink_R").unwrap_or(0)] = if n % 3 == 0 { 0.8 } else { 0.0 };
            p.pose = HeadPose::from_degrees(
                -25.0 + 50.0 * t,
                8.0 * (t * 6.0).sin(),
                3.0 * (t * 4.0).cos(),
                Vec3::new(1.0 - 2.0 * t, 0.5, -55.0),
            );
            p
        })
        .collect()
}

/// The person's points (all of `points`' vertices) seen in each frame, exactly.
fn observe(
    person: &PersonalizedBlendshapes,
    points: &FitPoints,
    frames: &[FaceParams],
) -> Vec<LandmarkObservations> {
    frames
        .iter()
        .map(|p| {
            let weights = p.blendshape_weights();
            let mut o = LandmarkObservations::new();
            for (k, &v) in points.vertices.iter().enumerate() {
                let pixel = camera()
                    .project(p.pose.transform(person.vertex(v as usize, &weights)))
                    .unwrap_or_else(|| panic!("point {k} behind the camera"));
                o.push(k, pixel, 1.0);
            }
            o
        })
        .collect()
}

/// Known coefficients: a clear person on the first components, nothing beyond.
fn true_coefficients(k: usize) -> Vec<f32> {
    (0..k)
        .map(|j| match j {
            0 => 1.2,
            1 => -0.8,
            2 => 0.6,
            5 => -1.0,
            _ => 0.0,
        })
        .collect()
}

/// Every 7th face vertex: a dense detector's spread of points without a contour.
fn dense_points(template: &Template) -> FitPoints {
    let face_part = template
        .landmarks_68
        .iter()
        .copied()
        .max()
        .map_or(0, |m| m as usize + 1);
    FitPoints {
        vertices: (0..face_part as u32).step_by(7).collect(),
        contours: vec![],
    }
}

#[test]
fn exact_points_recover_a_known_identity() {
    let model = common::face_model();
    let template = &model.template;
    let base = model.template_blendshapes();
    let k = 10;
    let alpha = true_coefficients(k);
    let person = with_identity(template, &base, &alpha).unwrap_or_else(|e| panic!("{e}"));
    let points = dense_points(template);
    let params = clip_params();
    let observed = observe(&person, &points, &params);
    let refiner = Refiner::with_points(&base, &points).unwrap_or_else(|e| panic!("{e}"));
    let frames: Vec<ClipFrame> = params
        .iter()
        .zip(&observed)
        .map(|(p, o)| ClipFrame {
            params: *p,
            observations: o,
        })
        .collect();
    let config = IdentityConfig {
        components: k,
        prior: 1e-6,
        iterations: 10,
        rounds: 1,
    };
    let fit = |config: &IdentityConfig| {
        fit_identity(
            template,
            &refiner,
            &camera(),
            &frames,
            &RefineConfig::unregularised(),
            config,
            &[],
        )
        .unwrap_or_else(|e| panic!("{e}"))
    };
    let exact = fit(&config);
    assert_eq!(exact.frames, params.len());
    assert!(
        exact.rms_before_px > 1.0,
        "the person should differ from the template: {exact:?}"
    );
    assert!(
        exact.rms_after_px < 0.02,
        "exact points should be explained: {exact:?}"
    );
    for (j, (a, b)) in exact.coefficients.iter().zip(&alpha).enumerate() {
        assert!((a - b).abs() < 0.02, "component {j}: fitted {a}, true {b}");
    }
    // The prior shrinks towards the template: a strong one leaves less of the person.
    let shrunk = fit(&IdentityConfig {
        prior: 10.0,
        ..config.clone()
    });
    let norm = |a: &[f32]| a.iter().map(|x| x * x).sum::<f32>().sqrt();
    assert!(norm(&shrunk.coefficients) < 0.9 * norm(&exact.coefficients));
}

#[test]
fn bad_settings_and_empty_clips_are_refused() {
    let model = common::face_model();
    let template = &model.template;
    let base = model.template_blendshapes();
    let points = dense_points(template);
    let refiner = Refiner::with_points(&base, &points).unwrap_or_else(|e| panic!("{e}"));
    let empty = LandmarkObservations::new();
    let frames = [ClipFrame {
        params: FaceParams::default(),
        observations: &empty,
    }];
    let run = |config: &IdentityConfig, frames: &[ClipFrame], start: &[f32]| {
        fit_identity(
            template,
            &refiner,
            &camera(),
            frames,
            &RefineConfig::default(),
            config,
            start,
        )
    };
    let ok = IdentityConfig::default();
    for (bad, what) in [
        (
            IdentityConfig {
                components: 0,
                ..ok.clone()
            },
            "components",
        ),
        (
            IdentityConfig {
                components: template.identity_count + 1,
                ..ok.clone()
            },
            "components",
        ),
        (
            IdentityConfig {
                prior: f32::NAN,
                ..ok.clone()
            },
            "prior",
        ),
        (
            IdentityConfig {
                prior: 0.0,
                ..ok.clone()
            },
            "prior",
        ),
        (
            IdentityConfig {
                iterations: 0,
                ..ok.clone()
            },
            "iterations",
        ),
    ] {
        let e = run(&bad, &frames, &[])
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(e.contains(what), "{what}: {e}");
    }
    let e = run(&ok, &frames, &[])
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("no frame"), "{e}");
    let e = run(&ok, &frames, &[1.0])
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("starting identity"), "{e}");
    let e = with_identity(template, &base, &vec![0.0; template.identity_count + 1])
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
    assert!(e.contains("identity coefficients"), "{e}");
}
