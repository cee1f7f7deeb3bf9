//! How far Face Mesh's 468 points lie from the truth on synthetic clips, and how much of it
//! is a fixed offset per clip (issue 32, item 2's 0.8x target). Each point is compared with
//! the clip's true person's own vertex under its ICT correspondence, under the true weights
//! and pose (`person.safetensors`; the refinement_bounds example shows those truth points
//! reproduce the clips' landmarks within 0.05 px). Per group of points (face oval, eyelids,
//! lips, brows, the rest) it prints the rms error, what is left when each point's mean
//! error over its clip is removed (what a per-clip correction could absorb at best: identity,
//! correspondence, the detector's bias on that face) and the frame-to-frame jitter
//! (consecutive frames' difference / sqrt 2), in pixels and in % of the face box sqrt(w h).
//!
//! Run it on tuning clips, not on the held-out ones:
//! `cargo run --release -p tracking --example mesh_residuals -- training/.cache/clips-s9002`

use std::path::Path;
use std::sync::Arc;

use face::{FaceModel, Template};
use glam::Vec2;
use tracking::evaluate::{Clip, track_clip_unrefined};
use tracking::mediapipe::{
    FACE_OVAL, FEATURE_LINES, IctCorrespondence, MESH_POINTS, default_models_dir,
};
use tracking::pipeline::LocatorChoice;

type AnyResult<T> = Result<T, Box<dyn std::error::Error>>;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> AnyResult<()> {
    let dir = std::env::args()
        .nth(1)
        .ok_or("give the clips' folder (tuning clips, seed 9002)")?;
    let face = Arc::new(FaceModel::new(Template::load_default(None)?));
    let clips = Clip::load_all(Path::new(&dir))?;
    let correspondence = IctCorrespondence::load(&default_models_dir())?;
    let mut group_of = [4usize; MESH_POINTS];
    for &k in &FACE_OVAL {
        group_of[k] = 0;
    }
    for (l, line) in FEATURE_LINES.iter().enumerate() {
        for &k in *line {
            group_of[k] = 1 + l / 4;
        }
    }
    let names = ["face oval", "eyelids", "lips", "brows", "the rest"];
    // Per group: squared error, squared error about the clip-point mean, squared
    // frame-to-frame difference; each in px^2 and in (% of the box)^2, with counts.
    let mut raw = [[0.0f64; 3]; 5];
    let mut centred = [[0.0f64; 3]; 5];
    let mut jitter = [[0.0f64; 3]; 5];
    let mut frames = 0usize;
    for clip in &clips {
        let person = clip.true_person(&face)?;
        let (mesh, intrinsics) =
            track_clip_unrefined(face.clone(), clip, LocatorChoice::MediaPipe)?;
        // Per point, this clip's (residual, face box) per frame where Face Mesh saw it.
        let mut residuals: Vec<Vec<(Vec2, f64)>> = vec![Vec::new(); MESH_POINTS];
        for (m, t) in mesh.iter().zip(&clip.truth.frames) {
            let Some(seen) = m.dense_observations.as_ref() else {
                continue;
            };
            frames += 1;
            let truth = t.project_vertices(&person, &intrinsics, &correspondence.vertices)?;
            let box_px = f64::from(t.face_box[2] * t.face_box[3]).sqrt();
            for o in &seen.points {
                residuals[o.index].push((o.pixel - truth[o.index], box_px));
            }
        }
        for (k, r) in residuals.iter().enumerate() {
            if r.is_empty() {
                continue;
            }
            let g = group_of[k];
            let mean = r.iter().map(|(e, _)| *e).sum::<Vec2>() / r.len() as f32;
            for (e, b) in r {
                let pct = 100.0 / b;
                let (e2, c2) = (
                    f64::from(e.length_squared()),
                    f64::from((*e - mean).length_squared()),
                );
                raw[g] = [raw[g][0] + e2, raw[g][1] + e2 * pct * pct, raw[g][2] + 1.0];
                centred[g] = [
                    centred[g][0] + c2,
                    centred[g][1] + c2 * pct * pct,
                    centred[g][2] + 1.0,
                ];
            }
            for pair in r.windows(2) {
                let d2 = f64::from((pair[1].0 - pair[0].0).length_squared()) / 2.0;
                let pct = 100.0 / pair[0].1;
                jitter[g] = [
                    jitter[g][0] + d2,
                    jitter[g][1] + d2 * pct * pct,
                    jitter[g][2] + 1.0,
                ];
            }
        }
    }
    println!(
        "{} clips, {frames} frames where Face Mesh found the face\n",
        clips.len()
    );
    println!("| points | rms error | per-clip mean removed | frame-to-frame |");
    println!("|---|---|---|---|");
    let cell = |s: [f64; 3]| {
        let n = s[2].max(1.0);
        format!("{:.2} px ({:.2} %)", (s[0] / n).sqrt(), (s[1] / n).sqrt())
    };
    let total = |a: &[[f64; 3]; 5]| {
        a.iter()
            .fold([0.0; 3], |t, s| [t[0] + s[0], t[1] + s[1], t[2] + s[2]])
    };
    for (g, name) in names.iter().enumerate() {
        println!(
            "| {name} | {} | {} | {} |",
            cell(raw[g]),
            cell(centred[g]),
            cell(jitter[g])
        );
    }
    println!(
        "| all 468 | {} | {} | {} |",
        cell(total(&raw)),
        cell(total(&centred)),
        cell(total(&jitter))
    );
    Ok(())
}
