//! CPU cost of the paper's equation (2) on the full template (26,719 vertices):
//! personalising (sampling dS_0 and all 53 masked dS_i through F) and evaluating the shape
//! with all 53 weights non-zero. Run: `cargo bench -p face --bench equation2`.

use criterion::{Criterion, criterion_group, criterion_main};
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{BlendshapeWeights, FaceModel, NUM_BLENDSHAPES, PersonalCorrections, Template};

fn corrections() -> PersonalCorrections {
    let map = |k: f32| {
        UvMap::from_fn(CORRECTION_SIZE, CORRECTION_SIZE, 3, move |uv| {
            vec![
                0.1 * (k * uv.x).sin(),
                0.1 * (k * uv.y).cos(),
                0.05 * k.sin(),
            ]
        })
    };
    PersonalCorrections {
        identity_shape: map(3.0),
        expression_shapes: (0..NUM_BLENDSHAPES).map(|i| map(i as f32 + 1.0)).collect(),
        static_albedo: map(2.0),
        dynamic_albedo: (0..NUM_BLENDSHAPES).map(|i| map(i as f32 + 0.5)).collect(),
    }
}

fn bench(c: &mut Criterion) {
    let template = match Template::load_default(None) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("equation2 bench needs the template: {e}");
            std::process::exit(1);
        }
    };
    let model = FaceModel::new(template);
    let corrections = corrections();
    let weights = BlendshapeWeights(std::array::from_fn(|i| {
        0.5 / NUM_BLENDSHAPES as f32 * (1 + i % 3) as f32
    }));
    let person = model.personalize(&corrections).expect("valid corrections");

    let mut group = c.benchmark_group("equation2");
    group.sample_size(20);
    group.bench_function("personalize_all_53_corrections", |b| {
        b.iter(|| model.personalize(&corrections).expect("valid corrections"))
    });
    group.bench_function("shape_all_53_weights", |b| {
        b.iter(|| person.shape(&weights))
    });
    group.bench_function("attention_masks_build", |b| {
        b.iter(|| face::masks::AttentionMasks::build(&model.template))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
