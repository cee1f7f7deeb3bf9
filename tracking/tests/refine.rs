//! Test-time refinement on the real template against known synthetic truth: landmarks
//! projected exactly from known parameters, then perturbed, noised, slid along the jaw or
//! corrupted, and the refinement judged by how close it returns to the truth.

mod common;

use std::sync::OnceLock;

use face::camera::{HeadPose, Intrinsics};
use face::names::ict_index;
use face::{BlendshapeWeights, NUM_LANDMARKS, PersonalizedBlendshapes, Template};
use glam::{Vec2, Vec3};
use tracking::refine::{
    JAW_CONTOUR, LandmarkObservations, PhotometricObservation, RefineConfig, Refiner, refine,
};
use tracking::{FaceParams, TrackingError};

struct Fixture {
    template: Template,
    blendshapes: PersonalizedBlendshapes,
    refiner: Refiner,
}

fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| {
        let model = common::face_model();
        let blendshapes = model.template_blendshapes();
        let refiner = Refiner::new(&blendshapes, &model.template).unwrap_or_else(|e| panic!("{e}"));
        Fixture {
            template: model.template.clone(),
            blendshapes,
            refiner,
        }
    })
}

fn noise(seed: u32) -> f32 {
    common::noise(seed) as f32
}

fn idx(name: &str) -> usize {
    ict_index(name).unwrap_or_else(|| panic!("no blendshape {name}"))
}

fn camera() -> Intrinsics {
    Intrinsics::centered(640, 480, 600.0)
}

/// Some expression (smile, open jaw, raised brow, half blink), yaw 20 degrees.
fn truth() -> FaceParams {
    let mut p = FaceParams::default();
    for (name, w) in [
        ("jawOpen", 0.45),
        ("mouthSmile_L", 0.6),
        ("mouthSmile_R", 0.4),
        ("browInnerUp_L", 0.5),
        ("browInnerUp_R", 0.5),
        ("eyeBlink_L", 0.5),
        ("mouthFunnel", 0.2),
    ] {
        p.weights[idx(name)] = w;
    }
    p.pose = HeadPose::from_degrees(20.0, -5.0, 3.0, Vec3::new(2.0, -1.0, -55.0));
    p
}

/// TrackNet-like start: pose off by a few degrees and centimetres, several weights off by
/// about 0.2.
fn perturbed(truth: &FaceParams) -> FaceParams {
    let mut p = *truth;
    p.pose.euler_rad += Vec3::new(3.0, -2.5, 2.0) * (std::f32::consts::PI / 180.0);
    p.pose.translation += Vec3::new(1.0, -0.8, 2.0);
    for (name, dw) in [
        ("jawOpen", -0.2),
        ("mouthSmile_L", -0.2),
        ("mouthSmile_R", 0.2),
        ("browInnerUp_L", -0.2),
        ("eyeBlink_L", 0.2),
        ("mouthPucker", 0.2),
    ] {
        let i = idx(name);
        p.weights[i] = (p.weights[i] + dw).clamp(0.0, 1.0);
    }
    p
}

/// The 68 landmarks of `params` projected exactly; weights are not clamped, so `params`
/// may hold values outside [0, 1] to make observations the bounded fit cannot reach.
fn project(params: &FaceParams) -> [Vec2; NUM_LANDMARKS] {
    let f = fixture();
    let points = f
        .blendshapes
        .landmarks(&f.template, &BlendshapeWeights(params.weights));
    points.map(|p| {
        camera()
            .project(params.pose.transform(p))
            .unwrap_or_else(|| panic!("landmark behind the camera"))
    })
}

fn rms_to(points: &[Vec2; NUM_LANDMARKS], params: &FaceParams) -> f32 {
    let projected = project(params);
    let sum: f32 = projected
        .iter()
        .zip(points)
        .map(|(a, b)| (*a - *b).length_squared())
        .sum();
    (sum / NUM_LANDMARKS as f32).sqrt()
}

fn pose_error(a: &FaceParams, b: &FaceParams) -> (f32, f32) {
    let degrees = (a.pose.degrees() - b.pose.degrees()).abs().max_element();
    let cm = (a.pose.translation - b.pose.translation).length();
    (degrees, cm)
}

fn weight_distance(a: &FaceParams, b: &FaceParams) -> f32 {
    a.weights
        .iter()
        .zip(&b.weights)
        .map(|(x, y)| (x - y).powi(2))
        .sum::<f32>()
        .sqrt()
}

fn run(
    init: &FaceParams,
    obs: &LandmarkObservations,
    config: &RefineConfig,
) -> (FaceParams, tracking::refine::RefineReport) {
    let r = fixture()
        .refiner
        .refine(&camera(), init, obs, config)
        .unwrap_or_else(|e| panic!("{e}"));
    (r.params, r.report)
}

#[test]
fn recovers_exact_landmarks_from_a_perturbed_start() {
    let truth = truth();
    let points = project(&truth);
    let obs = LandmarkObservations::from_68(&points);
    let init = perturbed(&truth);
    let before = rms_to(&points, &init);
    assert!(
        before > 5.0,
        "the perturbation moves landmarks by {before} px"
    );
    let config = RefineConfig {
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let (refined, report) = run(&init, &obs, &config);
    let after = rms_to(&points, &refined);
    let (degrees, cm) = pose_error(&refined, &truth);
    assert!(after < 0.05, "RMS {before} px -> {after} px ({report:?})");
    assert!(
        degrees < 0.05 && cm < 0.05,
        "pose off by {degrees} deg, {cm} cm"
    );
    assert!(
        (report.initial_rms_px - before).abs() < 1e-3 * before,
        "{report:?}"
    );
    assert!((report.final_rms_px - after).abs() < 1e-2, "{report:?}");
    assert!(report.final_energy < report.initial_energy);
    assert_eq!(
        refined.gamma, init.gamma,
        "gamma needs the photometric term"
    );
    // The default priors hold the rotation near TrackNet's (on the held-out clips the
    // detector's systematic offsets otherwise turn into pose error; tracking/README.md),
    // so from a start 3 degrees off the fit stops short of exact, but five iterations
    // still remove most of the error and do not move the rotation away from the truth.
    let (regularised, report) = run(&init, &obs, &RefineConfig::default());
    let after = rms_to(&points, &regularised);
    assert!(
        after < 0.15 * before,
        "default: {before} px -> {after} px ({report:?})"
    );
    assert!(report.iterations <= 5);
    let (start_degrees, start_cm) = pose_error(&init, &truth);
    let (degrees, cm) = pose_error(&regularised, &truth);
    assert!(
        degrees <= start_degrees + 1e-3 && cm < 0.5 * start_cm,
        "default: pose off by {degrees} deg, {cm} cm (start {start_degrees} deg, {start_cm} cm)"
    );
}

#[test]
fn the_free_function_matches_the_refiner() {
    let f = fixture();
    let truth = truth();
    let obs = LandmarkObservations::from_68(&project(&truth));
    let init = perturbed(&truth);
    let config = RefineConfig::default();
    let a = refine(&f.blendshapes, &f.template, &camera(), &init, &obs, &config)
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!((a.params, a.report), run(&init, &obs, &config));
}

#[test]
fn a_66_point_subset_recovers_too() {
    // The OpenSeeFace layout lacks the inner mouth corners 60 and 64.
    let truth = truth();
    let points = project(&truth);
    let mut obs = LandmarkObservations::new();
    for (k, p) in points.iter().enumerate() {
        if k != 60 && k != 64 {
            obs.push(k, *p, 1.0);
        }
    }
    let config = RefineConfig {
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let (refined, _) = run(&perturbed(&truth), &obs, &config);
    assert!(rms_to(&points, &refined) < 0.1);
}

#[test]
fn priors_keep_noisy_fits_near_the_start_and_in_range() {
    let truth = truth();
    let clean = project(&truth);
    // Detector noise of about 1.5 % of the face box (~3 px here) on every landmark.
    let mut noisy = clean;
    for (k, p) in noisy.iter_mut().enumerate() {
        *p += Vec2::new(noise(k as u32 * 2 + 11), noise(k as u32 * 2 + 12)) * 3.0;
    }
    let obs = LandmarkObservations::from_68(&noisy);
    let init = perturbed(&truth);
    let (free, _) = run(&init, &obs, &RefineConfig::unregularised());
    let (regularised, report) = run(&init, &obs, &RefineConfig::default());
    for p in [&free, &regularised] {
        assert!(p.weights.iter().all(|w| (0.0..=1.0).contains(w)));
    }
    let d_free = weight_distance(&free, &init);
    let d_reg = weight_distance(&regularised, &init);
    assert!(
        d_reg < 0.7 * d_free,
        "|w - w0|: {d_reg} with priors, {d_free} without"
    );
    // The fit still improves on the start against the clean truth.
    assert!(
        rms_to(&clean, &regularised) < rms_to(&clean, &init),
        "{report:?}"
    );
    assert!(report.final_rms_px < report.initial_rms_px);
}

#[test]
fn weights_stay_within_bounds_when_the_landmarks_ask_for_more() {
    let mut target = truth();
    let jaw = idx("jawOpen");
    let smile = idx("mouthSmile_L");
    target.weights[jaw] = 1.4;
    target.weights[smile] = -0.4;
    let obs = LandmarkObservations::from_68(&project(&target));
    let mut init = truth();
    init.weights[jaw] = 0.9;
    init.weights[smile] = 0.1;
    for config in [RefineConfig::default(), RefineConfig::unregularised()] {
        let (refined, _) = run(&init, &obs, &config);
        assert!(refined.weights.iter().all(|w| (0.0..=1.0).contains(w)));
        assert_eq!(refined.weights[jaw], 1.0);
    }
    // Without priors nothing holds the smile back from its bound. With the default ones the
    // weight prior (lambda_w = 32) pulls it back towards its start of 0.1 about as hard as
    // the few lip points it moves pull it down (a small landmark curvature), so it stops
    // just inside the bound: below its start, never below 0.
    let (free, _) = run(&init, &obs, &RefineConfig::unregularised());
    assert_eq!(free.weights[smile], 0.0);
    let (held, _) = run(&init, &obs, &RefineConfig::default());
    assert!(
        (0.0..0.05).contains(&held.weights[smile]),
        "{}",
        held.weights[smile]
    );
}

#[test]
fn pose_only_refinement_keeps_the_weights() {
    let truth = truth();
    let obs = LandmarkObservations::from_68(&project(&truth));
    let mut init = truth;
    init.pose.euler_rad.x += 0.05;
    init.pose.translation.z += 1.5;
    let config = RefineConfig {
        refine_weights: false,
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let (refined, report) = run(&init, &obs, &config);
    assert_eq!(refined.weights, init.weights);
    let (degrees, cm) = pose_error(&refined, &truth);
    assert!(
        degrees < 0.02 && cm < 0.02,
        "{degrees} deg, {cm} cm ({report:?})"
    );
}

#[test]
fn jaw_points_may_slide_along_the_contour() {
    // A detector places jaw points on the silhouette, shifted along it relative to the
    // template's vertices; moving them tangentially by 6 px must not drag the pose.
    let truth = truth();
    let mut points = project(&truth);
    let exact = points;
    for k in JAW_CONTOUR {
        let prev = exact[k.saturating_sub(1)];
        let next = exact[(k + 1).min(16)];
        let tangent = (next - prev).normalize();
        points[k] += tangent * 6.0;
    }
    let obs = LandmarkObservations::from_68(&points);
    let init = perturbed(&truth);
    let sliding = RefineConfig {
        contour_slide: 0.0,
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let point_to_point = RefineConfig {
        contour_slide: 1.0,
        ..sliding
    };
    let (a, _) = run(&init, &obs, &sliding);
    let (b, _) = run(&init, &obs, &point_to_point);
    let (deg_a, cm_a) = pose_error(&a, &truth);
    let (deg_b, cm_b) = pose_error(&b, &truth);
    // The tangent is taken from the shifted points, so sliding is not exactly free on a
    // curved contour; it must still beat point-to-point clearly.
    assert!(rms_to(&exact, &a) < 0.5 * rms_to(&exact, &b));
    assert!(
        deg_a < 0.5 * deg_b || cm_a < 0.5 * cm_b,
        "{deg_a}/{cm_a} vs {deg_b}/{cm_b}"
    );
}

#[test]
fn the_robust_loss_bounds_an_outlier() {
    let truth = truth();
    let clean = project(&truth);
    let mut points = clean;
    points[33] += Vec2::new(60.0, -40.0); // nose tip, e.g. a hand in front of it
    let obs = LandmarkObservations::from_68(&points);
    let init = perturbed(&truth);
    let robust = RefineConfig {
        iterations: 10,
        huber_scale: 1.0,
        ..RefineConfig::unregularised()
    };
    let plain = RefineConfig {
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let (a, _) = run(&init, &obs, &robust);
    let (b, _) = run(&init, &obs, &plain);
    let (deg_a, cm_a) = pose_error(&a, &truth);
    let (deg_b, cm_b) = pose_error(&b, &truth);
    assert!(
        deg_a < deg_b && cm_a < cm_b,
        "{deg_a}/{cm_a} vs {deg_b}/{cm_b}"
    );
}

#[test]
fn non_finite_inputs_are_rejected() {
    let truth = truth();
    let points = project(&truth);
    let expect_invalid = |result: Result<_, TrackingError>, what: &str| match result {
        Err(TrackingError::InvalidInput(msg)) => msg,
        Err(e) => panic!("{what}: wrong error {e}"),
        Ok(_) => panic!("{what}: accepted"),
    };
    let f = &fixture().refiner;
    let config = RefineConfig::default();
    for (k, pixel, weight) in [
        (10, Vec2::new(f32::NAN, 3.0), 1.0),
        (11, Vec2::new(3.0, f32::INFINITY), 1.0),
        (12, Vec2::new(3.0, 4.0), f32::NAN),
        (13, Vec2::new(3.0, 4.0), -1.0),
        (68, Vec2::new(3.0, 4.0), 1.0),
    ] {
        let mut obs = LandmarkObservations::from_68(&points);
        obs.push(k, pixel, weight);
        let msg = expect_invalid(f.refine(&camera(), &truth, &obs, &config), "observation");
        assert!(msg.contains(&k.to_string()), "{msg}");
    }
    let obs = LandmarkObservations::from_68(&points);
    let mut bad = truth;
    bad.weights[3] = f32::NAN;
    expect_invalid(f.refine(&camera(), &bad, &obs, &config), "NaN weight");
    let mut bad = truth;
    bad.pose.translation.z = f32::INFINITY;
    expect_invalid(
        f.refine(&camera(), &bad, &obs, &config),
        "infinite translation",
    );
    let mut behind = truth;
    behind.pose.translation.z = 30.0;
    expect_invalid(
        f.refine(&camera(), &behind, &obs, &config),
        "behind the camera",
    );
    let bad_config = RefineConfig {
        weight_prior: f32::NAN,
        ..config
    };
    let msg = expect_invalid(f.refine(&camera(), &truth, &obs, &bad_config), "config");
    assert!(msg.contains("weight_prior"), "{msg}");
}

#[test]
fn no_observations_return_the_start_unchanged() {
    let init = perturbed(&truth());
    let config = RefineConfig::default();
    let (refined, report) = run(&init, &LandmarkObservations::new(), &config);
    assert_eq!(refined, init);
    assert_eq!(report.iterations, 0);
    let mut zero_weights = LandmarkObservations::from_68(&project(&truth()));
    zero_weights.points.iter_mut().for_each(|o| o.weight = 0.0);
    let (refined, _) = run(&init, &zero_weights, &config);
    assert_eq!(refined, init);
}

#[test]
fn photometric_term_recovers_the_lighting() {
    let f = fixture();
    let truth = truth();
    let intrinsics = camera();
    let pose = truth.pose;
    let shape = f.blendshapes.shape(&BlendshapeWeights(truth.weights));
    let normals = face::geometry::vertex_normals(&shape, &f.template.triangles);
    // Sparse front-facing face vertices, at least 6 px apart on screen, each painted as a
    // flat 6 x 6 patch of its true shaded colour (so bilinear taps around the exact
    // projection all see that colour).
    let mut gamma_true = face::sh::studio_light();
    for (i, g) in gamma_true.iter_mut().enumerate() {
        *g += 0.08 * noise(300 + i as u32);
    }
    let mut image = image::RgbImage::from_pixel(640, 480, image::Rgb([40, 40, 40]));
    let mut chosen: Vec<(u32, Vec2)> = Vec::new();
    for v in f.template.face_vertices().step_by(7) {
        let p = pose.transform(shape[v as usize]);
        let n = pose.rotation() * normals[v as usize];
        if n.dot(-p.normalize()) < 0.3 {
            continue;
        }
        let Some(px) = intrinsics.project(p) else {
            continue;
        };
        if chosen
            .iter()
            .any(|(_, q)| (*q - px).abs().max_element() < 7.0)
        {
            continue;
        }
        chosen.push((v, px));
    }
    assert!(chosen.len() > 60, "{} vertices", chosen.len());
    let albedo: Vec<Vec3> = (0..chosen.len())
        .map(|i| Vec3::new(0.7, 0.55, 0.45) + 0.1 * noise(800 + i as u32))
        .collect();
    for ((v, px), a) in chosen.iter().zip(&albedo) {
        let n = pose.rotation() * normals[*v as usize];
        let c = face::sh::shade(*a, n, &gamma_true).clamp(Vec3::ZERO, Vec3::ONE) * 255.0;
        let rgb = image::Rgb(c.round().to_array().map(|x| x as u8));
        let (x0, y0) = (px.x.floor() as i64 - 3, px.y.floor() as i64 - 3);
        for y in y0..y0 + 7 {
            for x in x0..x0 + 7 {
                if (0..640).contains(&x) && (0..480).contains(&y) {
                    image.put_pixel(x as u32, y as u32, rgb);
                }
            }
        }
    }
    let subset: Vec<u32> = chosen.iter().map(|(v, _)| *v).collect();
    let refiner = Refiner::with_photometric(&f.blendshapes, &f.template, &subset)
        .unwrap_or_else(|e| panic!("{e}"));
    let obs = LandmarkObservations::from_68(&project(&truth));
    let mut init = truth;
    init.gamma = face::sh::studio_light();
    let photo = PhotometricObservation {
        image: &image,
        albedo: &albedo,
    };
    let config = RefineConfig {
        iterations: 10,
        photometric_huber: f32::INFINITY,
        ..RefineConfig::unregularised()
    };
    let r = refiner
        .refine_photometric(&intrinsics, &init, &obs, &photo, &config)
        .unwrap_or_else(|e| panic!("{e}"));
    let (refined, report) = (r.params, r.report);
    // Judge the lighting by what it does to the chosen vertices (the irradiance they see;
    // the raw band-2 coefficients are only weakly determined by a half sphere of normals).
    let shading_error = |gamma: &[f32; 27]| {
        chosen
            .iter()
            .map(|(v, _)| {
                let n = pose.rotation() * normals[*v as usize];
                (face::sh::irradiance(n, gamma) - face::sh::irradiance(n, &gamma_true))
                    .abs()
                    .max_element()
            })
            .fold(0.0f32, f32::max)
    };
    let before = shading_error(&init.gamma);
    let after = shading_error(&refined.gamma);
    assert!(before > 0.05, "{before}");
    assert!(
        after < 0.01,
        "irradiance error {before} -> {after} ({report:?})"
    );
    assert!(rms_to(&project(&truth), &refined) < 0.05);
}

/// Issue 32, item 2: the same fit on Face Mesh's 468 points through their ICT
/// correspondence (the face oval as one contour chain) recovers the truth from the same
/// perturbed start, and recovers the weights better than the 68 points when both are given
/// the same pixel noise, because many more points see each blendshape.
#[test]
fn the_dense_points_of_face_mesh_recover_the_truth_and_the_weights_better() {
    use tracking::mediapipe::{IctCorrespondence, default_models_dir};
    use tracking::refine::FitPoints;
    let f = fixture();
    let correspondence =
        IctCorrespondence::load(&default_models_dir()).unwrap_or_else(|e| panic!("{e}"));
    // MediaPipe's face oval, in order around the face.
    let oval = [
        10, 338, 297, 332, 284, 251, 389, 356, 454, 323, 361, 288, 397, 365, 379, 378, 400, 377,
        152, 148, 176, 149, 150, 136, 172, 58, 132, 93, 234, 127, 162, 21, 54, 103, 67, 109,
    ];
    let points = FitPoints {
        vertices: correspondence.vertices.clone(),
        contours: vec![oval.to_vec()],
    };
    let dense = Refiner::with_points(&f.blendshapes, &points).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(dense.point_count(), 468);
    let project_dense = |params: &FaceParams| -> Vec<Vec2> {
        let w = BlendshapeWeights(params.weights);
        points
            .vertices
            .iter()
            .map(|&v| {
                let p = f.blendshapes.vertex(v as usize, &w);
                camera()
                    .project(params.pose.transform(p))
                    .unwrap_or_else(|| panic!("behind"))
            })
            .collect()
    };
    let truth = truth();
    let init = perturbed(&truth);
    let exact = project_dense(&truth);
    let mut obs = LandmarkObservations::new();
    for (k, p) in exact.iter().enumerate() {
        obs.push(k, *p, 1.0);
    }
    let config = RefineConfig {
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let refined = dense
        .refine(&camera(), &init, &obs, &config)
        .unwrap_or_else(|e| panic!("{e}"));
    let (degrees, cm) = pose_error(&refined.params, &truth);
    assert!(
        degrees < 0.05 && cm < 0.05,
        "pose off by {degrees} deg, {cm} cm"
    );
    assert!(
        weight_distance(&refined.params, &truth) < 0.01,
        "{:?}",
        refined.report
    );

    // The same 1.5 px noise on every point: the weights come closer with 468 points.
    let noisy =
        |k: usize, p: Vec2| p + 1.5 * Vec2::new(noise(3 * k as u32 + 1), noise(3 * k as u32 + 2));
    let mut dense_obs = LandmarkObservations::new();
    for (k, p) in exact.iter().enumerate() {
        dense_obs.push(k, noisy(k, *p), 1.0);
    }
    let sparse_points = project(&truth);
    let mut sparse_obs = LandmarkObservations::new();
    for (k, p) in sparse_points.iter().enumerate() {
        sparse_obs.push(k, noisy(k + 1000, *p), 1.0);
    }
    // Without priors, so that only the points speak (the energy averages over the points,
    // so the default priors weigh the same against 468 points as against 68 and hold both
    // fits near the start; a dense detector calls for weaker ones, RefineConfig says why).
    let regular = RefineConfig {
        iterations: 10,
        ..RefineConfig::unregularised()
    };
    let from_dense = dense
        .refine(&camera(), &init, &dense_obs, &regular)
        .unwrap_or_else(|e| panic!("{e}"));
    let (from_sparse, _) = run(&init, &sparse_obs, &regular);
    let (d, s) = (
        weight_distance(&from_dense.params, &truth),
        weight_distance(&from_sparse, &truth),
    );
    eprintln!(
        "weight error with noisy points: 468 -> {d}, 68 -> {s}, start {}",
        weight_distance(&init, &truth)
    );
    assert!(d < s, "468 points: {d}, 68 points: {s}");
}
