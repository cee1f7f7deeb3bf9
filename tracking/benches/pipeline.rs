//! The tracking pipeline's latency per stage and end-to-end frame rate on a 640x480 clip
//! (decoded from an H.264 file by ffmpeg), OpenSeeFace against MediaPipe as the face
//! locator and ONNX Runtime against tract, all in one run, and ModelNet for N = 1, 4, 8.
//! Prints Markdown tables.
//!
//! `cargo bench -p tracking --bench pipeline` (the clip comes from
//! `python -m likeness_train.clips`, which training/setup.sh runs; LIKENESS_CLIPS overrides
//! the folder). Set LIKENESS_BENCH_FRAMES to limit the frames per pass.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;
use std::time::Instant;

use face::{FaceModel, Template};
use tracking::backend::{BackendChoice, BackendKind, onnxruntime_status};
use tracking::evaluate::{Clip, default_clips_dir};
use tracking::networks::{Manifest, ModelNet, default_networks_dir};
use tracking::personalize::stack;
use tracking::pipeline::{LocatorChoice, StageTimes, TrackEvent, Tracker, TrackerConfig};
use tracking::preprocess::{Rect, sample_rect};
use tracking::source::{FfmpegSource, FrameSource, Next, read_image};

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn encode_clip(clip: &Clip) -> Result<PathBuf, String> {
    let out = std::env::temp_dir().join(format!("likeness-bench-{}.mp4", std::process::id()));
    let pattern = clip.dir.join("frame_%04d.png");
    let status = Command::new("ffmpeg")
        .args(["-nostdin", "-v", "error", "-y", "-framerate", "30", "-i"])
        .arg(&pattern)
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p", "-crf", "18"])
        .arg(&out)
        .status()
        .map_err(|e| format!("ffmpeg: {e}"))?;
    if !status.success() {
        return Err(format!("ffmpeg could not encode {}", pattern.display()));
    }
    Ok(out)
}

struct Row {
    backend: BackendKind,
    decode: Vec<f64>,
    stages: Vec<StageTimes>,
    total: Vec<f64>,
    frames_with_face: usize,
}

/// A tracker for the clip as footage (detection and landmarks) on one backend.
fn footage_tracker(
    face: &Arc<FaceModel>,
    clip: &Clip,
    kind: BackendKind,
    threads: usize,
    locator: LocatorChoice,
) -> Result<Tracker, String> {
    let config = TrackerConfig {
        backend: BackendChoice::Only(kind),
        threads,
        locator,
        fov_deg: Some(clip.fov_deg()),
        ..TrackerConfig::default()
    };
    Tracker::new(face.clone(), config, true).map_err(|e| e.to_string())
}

fn run_pipeline(
    face: &Arc<FaceModel>,
    video: &Path,
    clip: &Clip,
    kind: BackendKind,
    threads: usize,
    locator: LocatorChoice,
    limit: usize,
) -> Result<Row, String> {
    let mut tracker = footage_tracker(face, clip, kind, threads, locator)?;
    let mut row = Row {
        backend: kind,
        decode: vec![],
        stages: vec![],
        total: vec![],
        frames_with_face: 0,
    };
    // Pass 0 warms up (allocations, tract plans); pass 1 is measured.
    for pass in 0..2 {
        tracker.reset();
        let mut source = FfmpegSource::video(video).map_err(|e| e.to_string())?;
        for _ in 0..limit {
            let t0 = Instant::now();
            let frame = match source.next_frame().map_err(|e| e.to_string())? {
                Next::Frame(f) => f,
                Next::Skipped(s) => return Err(s.error.to_string()),
                Next::End => break,
            };
            let decode = t0.elapsed().as_secs_f64() * 1e3;
            let out = tracker.process(&frame);
            let total = t0.elapsed().as_secs_f64() * 1e3;
            if pass == 1 {
                row.decode.push(decode);
                row.stages.push(out.times);
                row.total.push(total);
                row.frames_with_face += usize::from(out.record.face);
            }
        }
    }
    Ok(row)
}

/// Steady-state frame interval of [`Tracker::track_source`] (decoding and landmarks on one
/// thread, the rest on another): the wall time from the first frame out to the last over
/// the frames in between, so ffmpeg's start and the first frame's detection are not
/// counted. Median of 3 measured passes after a warm-up pass; returns (frames, ms).
fn run_pipelined(
    face: &Arc<FaceModel>,
    video: &Path,
    clip: &Clip,
    kind: BackendKind,
    threads: usize,
    locator: LocatorChoice,
    limit: usize,
) -> Result<(usize, f64), String> {
    let mut tracker = footage_tracker(face, clip, kind, threads, locator)?;
    let mut intervals = Vec::new();
    let mut frames = 0usize;
    for pass in 0..4 {
        let mut source = FfmpegSource::video(video).map_err(|e| e.to_string())?;
        let mut out_times = Vec::new();
        tracker
            .track_source(&mut source, |_: TrackEvent| {
                out_times.push(Instant::now());
                if out_times.len() >= limit {
                    ControlFlow::Break(())
                } else {
                    ControlFlow::Continue(())
                }
            })
            .map_err(|e| e.to_string())?;
        if let (true, Some(first), Some(last)) = (pass > 0, out_times.first(), out_times.last())
            && out_times.len() > 1
        {
            frames = out_times.len();
            intervals.push((*last - *first).as_secs_f64() * 1e3 / (frames - 1) as f64);
        }
    }
    Ok((frames, median(intervals)))
}

fn main() {
    if std::env::args().any(|a| a == "--list") {
        return;
    }
    // `cargo test --all-targets` runs this without `--bench`: a quick pass over a few
    // frames and N = 1 checks that the benchmark still works without timing anything
    // meaningful.
    let quick = !std::env::args().any(|a| a == "--bench");
    let clips = default_clips_dir();
    let clip = match Clip::load_all(&clips) {
        Ok(mut c) if !c.is_empty() => c.remove(0),
        Ok(_) | Err(_) => {
            eprintln!(
                "no clips in {}: run training/setup.sh (python -m likeness_train.clips)",
                clips.display()
            );
            std::process::exit(1);
        }
    };
    let limit: usize = std::env::var("LIKENESS_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(usize::MAX);
    let template = match Template::load_default(None) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let face = Arc::new(FaceModel::new(template));
    let video = match encode_clip(&clip) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let mut kinds = vec![BackendKind::Tract];
    match onnxruntime_status() {
        Ok(()) => kinds.insert(0, BackendKind::OnnxRuntime),
        Err(e) => eprintln!("ONNX Runtime unavailable ({e}); tract only"),
    }
    println!(
        "## Tracking latency per stage, {} ({}x{}, H.264), median ms per frame, {} threads available\n",
        clip.dir.display(),
        clip.truth.width,
        clip.truth.height,
        std::thread::available_parallelism().map_or(1, |n| n.get())
    );
    println!(
        "| locator | backend | decode | detect | landmarks | crop | TrackNet | refinement | smoothing | end to end | fps (1000 / mean) | frames with a face |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|---|");
    const LOCATORS: [(LocatorChoice, &str); 2] = [
        (LocatorChoice::Landmarks, "OpenSeeFace"),
        (LocatorChoice::MediaPipe, "MediaPipe"),
    ];
    let mut runs: Vec<(BackendKind, usize)> = kinds
        .iter()
        .map(|&k| (k, if k == BackendKind::Tract { 1 } else { 2 }))
        .collect();
    if kinds.contains(&BackendKind::OnnxRuntime) {
        runs.insert(1, (BackendKind::OnnxRuntime, 1));
    }
    for ((kind, threads), (locator, locator_name)) in LOCATORS
        .iter()
        .flat_map(|l| runs.iter().map(move |r| (*r, *l)))
    {
        match run_pipeline(&face, &video, &clip, kind, threads, locator, limit) {
            Ok(r) => {
                let col = |f: fn(&StageTimes) -> f64| median(r.stages.iter().map(f).collect());
                let mean_total = r.total.iter().sum::<f64>() / r.total.len().max(1) as f64;
                println!(
                    "| {locator_name} | {} ({} thread{}) | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} | {:.3} | {:.2} | {:.0} | {}/{} |",
                    r.backend,
                    if kind == BackendKind::Tract {
                        1
                    } else {
                        threads
                    },
                    if threads > 1 && kind != BackendKind::Tract {
                        "s"
                    } else {
                        ""
                    },
                    median(r.decode.clone()),
                    col(|s| s.detect_ms),
                    col(|s| s.landmarks_ms),
                    col(|s| s.crop_ms),
                    col(|s| s.tracknet_ms),
                    col(|s| s.refine_ms),
                    col(|s| s.smooth_ms),
                    median(r.total.clone()),
                    1000.0 / mean_total,
                    r.frames_with_face,
                    r.total.len()
                );
            }
            Err(e) => {
                println!("| {locator_name} | {kind} | failed: {e} |");
                std::process::exit(1);
            }
        }
    }
    println!(
        "\n## Pipelined (`Tracker::track_source`: decode and landmarks on one thread, crop, TrackNet, refinement and smoothing on another)\n"
    );
    println!(
        "| locator | backend | frames | ms per frame (steady state, median of 3 passes) | fps |\n|---|---|---|---|---|"
    );
    for ((kind, threads), (locator, locator_name)) in LOCATORS
        .iter()
        .flat_map(|l| runs.iter().map(move |r| (*r, *l)))
    {
        match run_pipelined(&face, &video, &clip, kind, threads, locator, limit) {
            Ok((frames, interval_ms)) => println!(
                "| {locator_name} | {kind} ({threads} thread{}) | {frames} | {interval_ms:.2} | {:.0} |",
                if threads > 1 { "s" } else { "" },
                1000.0 / interval_ms
            ),
            Err(e) => {
                println!("| {locator_name} | {kind} | failed: {e} |");
                std::process::exit(1);
            }
        }
    }
    println!(
        "\n(OpenSeeFace's detector runs only when the face is lost, so its median over all frames is 0 while the follower keeps the face; MediaPipe's BlazeFace runs on every frame. Each detector's cost when it runs:)\n"
    );
    // The detector alone, on the first frame.
    let first = read_image(&clip.frames[0]);
    if let Ok(image) = &first {
        println!(
            "| backend | OpenSeeFace detector | BlazeFace (ms, median of 10) |\n|---|---|---|"
        );
        for &kind in &kinds {
            let mut models = match tracking::openseeface::OpenSeeFace::load(
                &tracking::openseeface::default_models_dir(),
                kind,
                2,
            ) {
                Ok(m) => m,
                Err(e) => {
                    println!("| {kind} | {e} |");
                    continue;
                }
            };
            let times: Vec<f64> = (0..11)
                .map(|_| {
                    let t = Instant::now();
                    let _ = models.detect(image);
                    t.elapsed().as_secs_f64() * 1e3
                })
                .skip(1)
                .collect();
            let blazeface = match tracking::mediapipe::MediaPipe::load(
                &tracking::mediapipe::default_models_dir(),
                kind,
                2,
            ) {
                Ok(mut m) => {
                    let times: Vec<f64> = (0..11)
                        .map(|_| {
                            let t = Instant::now();
                            let _ = m.detect(image);
                            t.elapsed().as_secs_f64() * 1e3
                        })
                        .skip(1)
                        .collect();
                    format!("{:.2}", median(times))
                }
                Err(e) => e.to_string(),
            };
            println!("| {kind} | {:.2} | {blazeface} |", median(times));
        }
    }
    // ModelNet for N = 1, 4, 8.
    println!("\n## ModelNet (personalization), median ms of 5 runs\n");
    println!("| backend | N = 1 | N = 4 | N = 8 |\n|---|---|---|---|");
    let manifest = match Manifest::load(&default_networks_dir()) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let s = manifest.input_size;
    let crops: Vec<_> = clip
        .frames
        .iter()
        .take(8)
        .filter_map(|p| read_image(p).ok())
        .filter_map(|img| {
            let side = img.width().min(img.height()) as f32;
            let c = glam::Vec2::new(img.width() as f32, img.height() as f32) * 0.5;
            sample_rect(&img, Rect::square(c, side), s, s, manifest.normalisation).ok()
        })
        .collect();
    for &kind in &kinds {
        let mut net = match ModelNet::load(&manifest, kind, 2) {
            Ok(n) => n,
            Err(e) => {
                println!("| {kind} | {e} | | |");
                continue;
            }
        };
        let mut cells = Vec::new();
        for n in if quick { vec![1usize] } else { vec![1, 4, 8] } {
            let refs: Vec<_> = crops.iter().cycle().take(n).collect();
            let Ok(batch) = stack(&refs) else {
                cells.push("-".to_string());
                continue;
            };
            let _ = net.run(&batch);
            let times: Vec<f64> = (0..5)
                .map(|_| {
                    let t = Instant::now();
                    let _ = net.run(&batch);
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            cells.push(format!("{:.0}", median(times)));
        }
        println!("| {kind} | {} |", cells.join(" | "));
    }
    let _ = std::fs::remove_file(&video);
}
