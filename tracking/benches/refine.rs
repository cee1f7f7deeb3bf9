//! Cost of one test-time refinement (5 Levenberg-Marquardt iterations on all 68 landmarks
//! of the template), which runs every frame: with a prepared [`Refiner`] (the per-frame
//! path) and through the one-call `refine` (which gathers the landmark rows each time).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use face::camera::{HeadPose, Intrinsics};
use face::{BlendshapeWeights, FaceModel, Template};
use glam::{Vec2, Vec3};
use tracking::FaceParams;
use tracking::refine::{LandmarkObservations, RefineConfig, Refiner, refine};

fn bench_refine(c: &mut Criterion) {
    let path = face::template::default_template_path();
    let template = match Template::load_safetensors(&path) {
        Ok(t) => t,
        Err(e) => panic!("the benchmark needs the template at {path:?}: {e}"),
    };
    let model = FaceModel::new(template);
    let blendshapes = model.template_blendshapes();
    let intrinsics = Intrinsics::centered(640, 480, 600.0);

    let mut truth = FaceParams::default();
    for (i, w) in [(26, 0.45), (45, 0.6), (46, 0.4), (2, 0.5), (10, 0.5)] {
        truth.weights[i] = w;
    }
    truth.pose = HeadPose::from_degrees(20.0, -5.0, 3.0, Vec3::new(2.0, -1.0, -55.0));
    let landmarks = blendshapes.landmarks(&model.template, &BlendshapeWeights(truth.weights));
    // Exact projections plus a deterministic wobble of about 1 px, like a good detector.
    let points = std::array::from_fn(|k| {
        let p = intrinsics
            .project(truth.pose.transform(landmarks[k]))
            .unwrap_or(Vec2::ZERO);
        p + Vec2::new((k as f32 * 1.7).sin(), (k as f32 * 2.3).cos())
    });
    let observations = LandmarkObservations::from_68(&points);
    let mut init = truth;
    init.pose.euler_rad += Vec3::new(0.05, -0.04, 0.03);
    init.pose.translation += Vec3::new(1.0, -0.8, 2.0);
    init.weights[26] -= 0.2;
    init.weights[45] -= 0.2;
    init.weights[10] += 0.2;
    // Tolerance 0 so that all 5 iterations always run.
    let config = RefineConfig {
        tolerance: 0.0,
        ..RefineConfig::default()
    };

    let refiner = match Refiner::new(&blendshapes, &model.template) {
        Ok(r) => r,
        Err(e) => panic!("{e}"),
    };
    c.bench_function(
        "refine 5 iterations, 68 landmarks (prepared Refiner)",
        |b| {
            b.iter(|| {
                refiner
                    .refine(
                        &intrinsics,
                        black_box(&init),
                        black_box(&observations),
                        &config,
                    )
                    .map(|r| r.params)
            })
        },
    );
    c.bench_function("refine 5 iterations, 68 landmarks (one-call refine)", |b| {
        b.iter(|| {
            refine(
                &blendshapes,
                &model.template,
                &intrinsics,
                black_box(&init),
                black_box(&observations),
                &config,
            )
            .map(|r| r.params)
        })
    });
}

criterion_group!(benches, bench_refine);
criterion_main!(benches);
