//! What landmark refinement can do for the expression weights at best (issue 32, item 2 and
//! its 0.8x target): refinement started from TrackNet, fed points of increasing quality
//! (detected, then true), fitted on the template or on the clip's true person (their
//! `person.safetensors`: dS_0 and the dS_i), with the shipped priors and with none. The
//! truth points are the person's own vertices under the true weights and pose, projected
//! with the tracker's camera (the 68 are checked against the clip's `landmarks_68`).
//!
//! Run it on tuning clips (`python -m likeness_train.clips --out .cache/clips-s9002 --seed
//! 9002 --clips 6`), not on the held-out ones:
//! `cargo run --release -p tracking --example refinement_bounds -- training/.cache/clips-s9002`

use std::path::Path;
use std::sync::Arc;

use face::{FaceModel, NUM_BLENDSHAPES, NUM_LANDMARKS, Template};
use glam::Vec2;
use tracking::evaluate::{Clip, TruthFrame, track_clip_unrefined};
use tracking::mediapipe::{IctCorrespondence, default_models_dir};
use tracking::pipeline::LocatorChoice;
use tracking::refine::{FitPoints, LandmarkObservations, RefineConfig, Refiner};

type AnyResult<T> = Result<T, Box<dyn std::error::Error>>;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn weight_mae(weights: &[f32], t: &TruthFrame) -> f64 {
    weights
        .iter()
        .zip(&t.weights)
        .map(|(a, b)| f64::from((a - b).abs()))
        .sum::<f64>()
        / NUM_BLENDSHAPES as f64
}

/// Standard normal numbers, reproducible run to run (splitmix64 and Box-Muller: the
/// example needs nothing more than that, and no new dependency for it).
struct StdNormal(u64);

impl StdNormal {
    fn uniform(&mut self) -> f32 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        ((z >> 40) as f32 + 0.5) / (1u64 << 24) as f32
    }

    fn next(&mut self) -> f32 {
        let (u, v) = (self.uniform(), self.uniform());
        (-2.0 * u.ln()).sqrt() * (std::f32::consts::TAU * v).cos()
    }
}

#[derive(Default)]
struct Mean(f64, usize);

impl Mean {
    fn add(&mut self, x: f64) {
        self.0 += x;
        self.1 += 1;
    }
    fn get(&self) -> f64 {
        self.0 / self.1.max(1) as f64
    }
}

fn run() -> AnyResult<()> {
    let dir = std::env::args()
        .nth(1)
        .ok_or("give the clips' folder (tuning clips, seed 9002)")?;
    let face = Arc::new(FaceModel::new(Template::load_default(None)?));
    let clips = Clip::load_all(Path::new(&dir))?;
    let correspondence = IctCorrespondence::load(&default_models_dir())?;
    let dense = correspondence.fit_points();
    let sparse = FitPoints::ibug68(&face.template);
    let template = face.template_blendshapes();
    let configs = [
        ("shipped priors", RefineConfig::default()),
        (
            "weak priors (w 1, sparsity 0.8)",
            RefineConfig {
                weight_prior: 1.0,
                weight_sparsity: 0.8,
                iterations: 30,
                ..RefineConfig::default()
            },
        ),
        (
            "no priors, 30 iterations",
            RefineConfig {
                iterations: 30,
                ..RefineConfig::unregularised()
            },
        ),
    ];
    // Rows: (label, model is the true person, points: None detected, Some(noise px) true
    // plus independent Gaussian noise, dense).
    let rows = [
        ("template, OpenSeeFace's 68", false, None, false),
        ("template, Face Mesh's 468", false, None, true),
        ("true person, Face Mesh's 468", true, None, true),
        ("template, true 68", false, Some(0.0), false),
        ("true person, true 68", true, Some(0.0), false),
        ("true person, true 468", true, Some(0.0), true),
        (
            "true person, true 468 + 0.5 px noise",
            true,
            Some(0.5),
            true,
        ),
        ("true person, true 468 + 1 px noise", true, Some(1.0), true),
        ("true person, true 468 + 2 px noise", true, Some(2.0), true),
    ];
    let mut noise = StdNormal(0x9e37_79b9_7f4a_7c15);
    let mut mae: Vec<[Mean; 3]> = rows.iter().map(|_| Default::default()).collect();
    let mut rms: Vec<[Mean; 3]> = rows.iter().map(|_| Default::default()).collect();
    let mut tracknet = Mean::default();
    let mut truth_check = Mean::default();
    for clip in &clips {
        let person = clip.true_person(&face)?;
        let refiners = [
            [
                Refiner::with_points(&template, &sparse)?,
                Refiner::with_points(&template, &dense)?,
            ],
            [
                Refiner::with_points(&person, &sparse)?,
                Refiner::with_points(&person, &dense)?,
            ],
        ];
        let (osf, intrinsics) = track_clip_unrefined(face.clone(), clip, LocatorChoice::Landmarks)?;
        let (mesh, _) = track_clip_unrefined(face.clone(), clip, LocatorChoice::MediaPipe)?;
        for ((o, m), t) in osf.iter().zip(&mesh).zip(&clip.truth.frames) {
            // Frames both locators found, started from the same TrackNet run (OpenSeeFace's crop).
            let (Some(init), Some(sparse_seen), Some(dense_seen)) = (
                o.tracknet.as_ref(),
                o.observations.as_ref(),
                m.dense_observations.as_ref(),
            ) else {
                continue;
            };
            tracknet.add(weight_mae(&init.weights, t));
            let true_68 = t.project_vertices(&person, &intrinsics, &face.template.landmarks_68)?;
            let recorded: [Vec2; NUM_LANDMARKS] =
                std::array::from_fn(|i| Vec2::new(t.landmarks_68[i][0], t.landmarks_68[i][1]));
            for (p, q) in true_68.iter().zip(&recorded) {
                truth_check.add(f64::from(p.distance(*q)));
            }
            let dense_truth = t.project_vertices(&person, &intrinsics, &dense.vertices)?;
            let true_68 = LandmarkObservations::from_68(&recorded);
            for (r, &(_, true_model, true_points, is_dense)) in rows.iter().enumerate() {
                let noisy_468;
                let observations = match (true_points, is_dense) {
                    (None, false) => sparse_seen,
                    (None, true) => dense_seen,
                    (Some(_), false) => &true_68,
                    (Some(sigma), true) => {
                        let mut o = LandmarkObservations::new();
                        for (k, p) in dense_truth.iter().enumerate() {
                            o.push(k, *p + sigma * Vec2::new(noise.next(), noise.next()), 1.0);
                        }
                        noisy_468 = o;
                        &noisy_468
                    }
                };
                let refiner = &refiners[usize::from(true_model)][usize::from(is_dense)];
                for (c, (_, config)) in configs.iter().enumerate() {
                    let refined = refiner.refine(&intrinsics, init, observations, config)?;
                    mae[r][c].add(weight_mae(&refined.params.weights, t));
                    rms[r][c].add(f64::from(refined.report.final_rms_px));
                }
            }
        }
    }
    println!(
        "{} clips, {} frames both locators found; the true 68 reproduce the clips' own within {:.3} px\n",
        clips.len(),
        tracknet.1,
        truth_check.get()
    );
    print!("| refinement from TrackNet (MAE {:.4}) |", tracknet.get());
    for (label, _) in &configs {
        print!(" {label} |");
    }
    println!("\n|---|{}", "---|".repeat(configs.len()));
    for (r, (label, ..)) in rows.iter().enumerate() {
        print!("| {label} |");
        for c in 0..configs.len() {
            print!(" {:.4} ({:.2} px) |", mae[r][c].get(), rms[r][c].get());
        }
        println!();
    }
    println!("\nexpression MAE over all 53 channels (final rms point residual)");
    Ok(())
}
