//! Frame time of a face-sized synthetic mesh: ~27k vertices, K = 53 blendshapes, all
//! weights non-zero (the worst case for the vertex shader), 1280x720.
//!
//! `render_readback`: record + submit + copy to a buffer + map (waits for the GPU).
//! `render_wait`: record + submit + wait for the device to go idle, no readback.
//!
//! Run: `XDG_RUNTIME_DIR=/tmp/xdg cargo bench -p renderer --bench render`.

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Mat4, Vec3};
use renderer::synthetic::{checker_albedo, uv_sphere};
use renderer::{Camera, FrameParams, OffscreenRenderer};
use std::time::Duration;

const K: usize = 53;
const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;

fn bench(c: &mut Criterion) {
    // (164 - 1) * 166 + 2 = 27060 vertices.
    let mesh = uv_sphere(164, 166, K);
    let mut r = OffscreenRenderer::new(&mesh, &checker_albedo(1024, 16)).expect("renderer");
    eprintln!(
        "adapter {:?}, {} vertices, {} corners, {} triangles, K = {}, msaa x{}",
        r.adapter_info().name,
        mesh.vertex_count(),
        mesh.corners.len(),
        mesh.indices.len() / 3,
        mesh.shape_count(),
        r.face.sample_count()
    );
    let weights: Vec<f32> = (0..K)
        .map(|k| 0.2 + 0.6 * ((k * 37 % 53) as f32 / 53.0))
        .collect();
    r.face.set_weights(&r.queue, &weights).expect("weights");
    let h = HEIGHT as f32;
    let camera = Camera::from_intrinsics(
        1.2 * h,
        WIDTH as f32 / 2.0,
        h / 2.0,
        WIDTH,
        HEIGHT,
        0.1,
        20.0,
        Mat4::from_translation(Vec3::new(0.0, 0.0, -3.2)),
    );
    let params = FrameParams::new(camera);

    let mut group = c.benchmark_group("face_1280x720_27k_v_53_shapes");
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(2));
    group.measurement_time(Duration::from_secs(8));
    group.bench_function("render_readback", |b| {
        b.iter(|| r.render_image(WIDTH, HEIGHT, &params).expect("render"))
    });
    group.bench_function("render_wait", |b| {
        b.iter(|| r.render_and_wait(WIDTH, HEIGHT, &params).expect("render"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
