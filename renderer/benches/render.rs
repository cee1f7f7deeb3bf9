//! Frame time of a face-sized synthetic mesh: ~27k vertices, K = 53 blendshapes, all
//! weights non-zero (the worst case for blending), 1280x720, shaded view.
//!
//! Every case is one frame = record + submit + wait for the device to go idle (no
//! readback), over all combinations of
//! - blend path: `prepass` (blend once per weight change into a texture) vs `pervertex`
//!   (the fallback: every vertex shader blends) vs `cpu` (the CPU sums the non-zero deltas
//!   and uploads that texture; the synthetic shapes move every vertex, the worst case for
//!   it, where the ICT shapes move a part of the face each),
//! - MSAA: `msaa4` (default, goldens) vs `msaa1`,
//! - weights: `changing` (a different set of 53 non-zero weights every frame, so the
//!   pre-pass runs every frame) vs `static` (set once; the pre-pass is skipped).
//!
//! Criterion reports each case; a table of the per-frame medians is printed at the end.
//!
//! A second group, `albedo_upload`, times what a clip with a per-frame albedo (equation 3)
//! uploads each frame: the whole 6-layer 512x512 array (`set_albedo`) against its face
//! layer alone (`set_albedo_layer`, what the demo clip does), each until the GPU has it,
//! and prints the two medians and their ratio.
//!
//! Run: `XDG_RUNTIME_DIR=/tmp/xdg cargo bench -p renderer --bench render`.

use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Mat4, Vec3};
use renderer::synthetic::{checker_albedo, uv_sphere};
use renderer::{BlendPath, Camera, FrameParams, OffscreenOptions, OffscreenRenderer};
use std::time::{Duration, Instant};

const K: usize = 53;
const WIDTH: u32 = 1280;
const HEIGHT: u32 = 720;

/// All 53 weights non-zero; `phase` shifts them so consecutive frames differ.
fn weights(phase: usize) -> Vec<f32> {
    (0..K)
        .map(|k| 0.2 + 0.6 * (((k + phase) * 37 % 53) as f32 / 53.0))
        .collect()
}

fn median_ms(samples: &mut [Duration]) -> f64 {
    samples.sort();
    samples
        .get(samples.len() / 2)
        .map_or(f64::NAN, |d| d.as_secs_f64() * 1e3)
}

fn bench(c: &mut Criterion) {
    // (164 - 1) * 166 + 2 = 27060 vertices.
    let mesh = uv_sphere(164, 166, K);
    let albedo = checker_albedo(1024, 16);
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
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(5));
    let mut table = Vec::new();
    for blend_path in [BlendPath::PrePass, BlendPath::PerVertex, BlendPath::Cpu] {
        for samples in [4, 1] {
            let mut r = OffscreenRenderer::with_options(
                &mesh,
                &albedo,
                OffscreenOptions {
                    sample_count: Some(samples),
                    blend_path: Some(blend_path),
                    cull_back_faces: false,
                    backends: None,
                },
            )
            .expect("renderer");
            if table.is_empty() {
                eprintln!(
                    "adapter {:?}, {} vertices, {} corners, {} triangles, K = {}",
                    r.adapter_info().name,
                    mesh.vertex_count(),
                    mesh.corners.len(),
                    mesh.indices.len() / 3,
                    mesh.shape_count(),
                );
            }
            let path = match blend_path {
                BlendPath::PrePass => "prepass",
                BlendPath::PerVertex => "pervertex",
                BlendPath::Cpu => "cpu",
            };
            for changing in [true, false] {
                let name = format!(
                    "{path}/msaa{samples}/{}",
                    if changing { "changing" } else { "static" }
                );
                r.face.set_weights(&r.queue, &weights(0)).expect("weights");
                // Untimed first frame: creates the attachments (and the blend).
                r.render_and_wait(WIDTH, HEIGHT, &params).expect("render");
                let mut phase = 0;
                // Each frame is also timed on its own for the summary table.
                let mut frames = Vec::new();
                group.bench_function(&name, |b| {
                    b.iter_custom(|iters| {
                        let start = Instant::now();
                        for _ in 0..iters {
                            let t = Instant::now();
                            if changing {
                                phase += 1;
                                r.face
                                    .set_weights(&r.queue, &weights(phase))
                                    .expect("weights");
                            }
                            r.render_and_wait(WIDTH, HEIGHT, &params).expect("render");
                            frames.push(t.elapsed());
                        }
                        start.elapsed()
                    })
                });
                table.push((path, samples, changing, median_ms(&mut frames)));
            }
        }
    }
    group.finish();

    eprintln!("\nmedian ms per frame (render + wait), {WIDTH}x{HEIGHT}, {K} active weights:");
    eprintln!(
        "{:<10} {:>5} {:>16} {:>16}",
        "path", "msaa", "weights changing", "weights static"
    );
    for row in table.chunks(2) {
        let [(path, samples, _, changing), (_, _, _, fixed)] = row else {
            continue;
        };
        eprintln!("{path:<10} {samples:>5} {changing:>16.1} {fixed:>16.1}");
    }
}

fn albedo_upload(c: &mut Criterion) {
    // The face template's layout: six 512 x 512 layers (face::albedo::ALBEDO_SIZE).
    let checker = checker_albedo(512, 16);
    let mut albedo = checker.clone();
    albedo.layers = (0..6)
        .map(|l| checker.layers[l % checker.layers.len()].clone())
        .collect();
    let mut r = OffscreenRenderer::new(&uv_sphere(16, 16, 1), &albedo).expect("renderer");
    let mut group = c.benchmark_group("albedo_upload_6x512x512");
    group.sample_size(20);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
    let mut medians = Vec::new();
    for whole in [true, false] {
        let mut frames = Vec::new();
        let name = if whole { "whole_array" } else { "face_layer" };
        group.bench_function(name, |b| {
            b.iter_custom(|iters| {
                let start = Instant::now();
                for _ in 0..iters {
                    let t = Instant::now();
                    if whole {
                        r.face.set_albedo(&r.queue, &albedo).expect("albedo");
                    } else {
                        r.face
                            .set_albedo_layer(&r.queue, 0, &albedo.layers[0])
                            .expect("layer");
                    }
                    r.queue.submit([]);
                    r.device
                        .poll(wgpu::PollType::wait_indefinitely())
                        .expect("poll");
                    frames.push(t.elapsed());
                }
                start.elapsed()
            })
        });
        medians.push(median_ms(&mut frames));
    }
    group.finish();
    eprintln!("\nmedian ms per albedo upload (6 layers of 512x512, mips included):");
    eprintln!("{:>12} {:>12} {:>8}", "whole array", "face layer", "ratio");
    eprintln!(
        "{:>12.2} {:>12.2} {:>7.1}x",
        medians[0],
        medians[1],
        medians[0] / medians[1]
    );
}

criterion_group!(benches, bench, albedo_upload);
criterion_main!(benches);
