//! Accuracy tables: expression MAE (all channels and the visible ones, beside w = 0 and
//! each channel's mean on the same frames), landmark NME (box and inter-ocular) and pose
//! error on the held-out synthetic clips for TrackNet alone, with refinement, with the
//! personalized model and with smoothing, and per channel (MAE, correlation, F1) for the
//! first two; and on the real face crop in ../shared/testdata, how far the model's
//! landmarks are from OpenSeeFace's with and without refinement.
//!
//! `cargo run --release -p tracking --example evaluate [-- --backend tract]
//! [--weight-prior X] [--weight-sparsity X] [--rotation-prior X] [--translation-prior X]
//! [--smooth SPEC] [--locator openseeface|mediapipe [--no-dense]] [--tune DIR [--sparsity-grid A,B,...]
//! [--prior-grid A,B,...] [--rotation-grid A,B,...] [--translation-grid A,B,...]] [--tune-identity DIR]
//! [--identity-prior X] [--identity-components K]` (the priors and smoothing default to the tracker's defaults,
//! the locator to OpenSeeFace).
//!
//! `--tune DIR` first compares refinement with each weight prior and sparsity of the grids on the
//! clips in DIR (a seed of their own, `python -m likeness_train.clips --seed 9002`; the
//! held-out clips' seed is refused), takes the one with the lowest expression MAE there,
//! and only then evaluates it on the held-out clips, printing whether refinement kept the
//! held-out MAE at or below TrackNet's.

use std::sync::Arc;

use face::{FaceModel, Template};
use tracking::backend::BackendChoice;
use tracking::evaluate::{Clip, default_clips_dir, evaluate, real_crop_agreement, tune_refinement};
use tracking::pipeline::TrackerConfig;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let face = Arc::new(FaceModel::new(Template::load_default(None)?));
    let text = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .cloned()
    };
    let value = |name: &str| -> Result<Option<f32>, Box<dyn std::error::Error>> {
        text(name)
            .map(|v| v.parse::<f32>().map_err(|e| format!("{name}: {e}").into()))
            .transpose()
    };
    let backend: BackendChoice =
        text("--backend").map_or(Ok(BackendChoice::Auto), |b| b.parse())?;
    let mut refine = tracking::refine::RefineConfig::default();
    if let Some(v) = value("--weight-prior")? {
        refine.weight_prior = v;
    }
    if let Some(v) = value("--weight-sparsity")? {
        refine.weight_sparsity = v;
    }
    if let Some(v) = value("--rotation-prior")? {
        refine.rotation_prior = v;
    }
    if let Some(v) = value("--translation-prior")? {
        refine.translation_prior = v;
    }
    refine.validate()?;
    let smoothing = match text("--smooth") {
        Some(spec) => spec.parse()?,
        None => tracking::smooth::SmoothingConfig::default(),
    };
    let locator = match text("--locator") {
        Some(l) => l.parse()?,
        None => tracking::pipeline::LocatorChoice::Auto,
    };
    let mut config = TrackerConfig {
        backend,
        locator,
        dense_fit: !args.iter().any(|a| a == "--no-dense"),
        refine: Some(refine.clone()),
        smoothing,
        ..TrackerConfig::default()
    };
    let clips = Clip::load_all(&default_clips_dir())?;
    if let Some(dir) = text("--tune") {
        let tuning_clips = Clip::load_all(std::path::Path::new(&dir))?;
        tracking::evaluate::check_tuning_clips(&tuning_clips, &clips)?;
        let grid = |name: &str, default: String| -> Result<Vec<f32>, String> {
            text(name)
                .unwrap_or(default)
                .split(',')
                .map(|v| {
                    v.trim()
                        .parse::<f32>()
                        .map_err(|e| format!("{name}: {v:?}: {e}"))
                })
                .collect()
        };
        let priors = grid("--prior-grid", refine.weight_prior.to_string())?;
        let sparsities = grid("--sparsity-grid", "0,0.1,0.2,0.4,0.8,1.6,3.2".into())?;
        // Of candidates with equal errors the first listed is chosen: the grids go up.
        let rotations = grid("--rotation-grid", refine.rotation_prior.to_string())?;
        let translations = grid("--translation-grid", refine.translation_prior.to_string())?;
        let mut candidates = Vec::new();
        for &rotation_prior in &rotations {
            for &translation_prior in &translations {
                for &weight_prior in &priors {
                    for &weight_sparsity in &sparsities {
                        candidates.push(tracking::refine::RefineConfig {
                            weight_prior,
                            weight_sparsity,
                            rotation_prior,
                            translation_prior,
                            ..refine.clone()
                        });
                    }
                }
            }
        }
        let tuning = tune_refinement(face.clone(), &tuning_clips, &config, &candidates)?;
        println!("## Weight sparsity chosen on the tuning clips ({dir})\n");
        println!("{}", tuning.table());
        config.refine = Some(tuning.rows[tuning.chosen].0.clone());
    }
    let mut identity = tracking::identity::IdentityConfig::default();
    if let Some(v) = value("--identity-prior")? {
        identity.prior = v;
    }
    if let Some(v) = text("--identity-components") {
        identity.components = v
            .parse()
            .map_err(|e| format!("--identity-components {v:?}: {e}"))?;
    }
    if let Some(dir) = text("--tune-identity") {
        let tuning_clips = Clip::load_all(std::path::Path::new(&dir))?;
        tracking::evaluate::check_tuning_clips(&tuning_clips, &clips)?;
        let mut candidates = Vec::new();
        for components in [10usize, 20, 40, 100] {
            for prior in [0.005f32, 0.02, 0.05, 0.2, 1.0] {
                candidates.push(tracking::identity::IdentityConfig {
                    components,
                    prior,
                    ..identity.clone()
                });
            }
        }
        let (template, rows) =
            tracking::evaluate::tune_identity(face.clone(), &tuning_clips, &config, &candidates)?;
        println!("## Identity fitted to each tuning clip ({dir})\n");
        println!(
            "| identity | expression MAE (all 53) | landmark NME (box) | NME (inter-ocular) |\n|---|---|---|---|"
        );
        println!(
            "| none (template) | {:.4} | {:.2} % | {:.2} % |",
            template.expression_mae,
            100.0 * template.landmark_nme,
            100.0 * template.landmark_nme_iod
        );
        for (c, m) in &rows {
            println!(
                "| {} components, prior {} | {:.4} | {:.2} % | {:.2} % |",
                c.components,
                c.prior,
                m.expression_mae,
                100.0 * m.landmark_nme,
                100.0 * m.landmark_nme_iod
            );
        }
        return Ok(());
    }
    let evaluation = evaluate(
        face.clone(),
        &clips,
        &config,
        tracking::personalize::DEFAULT_FRAMES,
        &identity,
    )?;
    println!(
        "## Held-out synthetic clips ({})\n",
        default_clips_dir().display()
    );
    println!("{}", evaluation.table());
    if let [(_, tracknet), (_, refined), ..] = evaluation.rows.as_slice() {
        println!(
            "Refinement (weight prior {}, sparsity {}) {} the held-out expression MAE: {:.4} -> {:.4}\n",
            config.refine.as_ref().map_or(0.0, |r| r.weight_prior),
            config.refine.as_ref().map_or(0.0, |r| r.weight_sparsity),
            if refined.expression_mae <= tracknet.expression_mae {
                "keeps or lowers"
            } else {
                "RAISES"
            },
            tracknet.expression_mae,
            refined.expression_mae
        );
    }
    for (row, report) in evaluation.rows.iter().zip(&evaluation.reports).take(2) {
        println!("### Per channel: {}\n", row.0);
        println!("{}", report.table());
    }
    let crop = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/testdata/faces/openseeface-raw1.png");
    let agreement = real_crop_agreement(face, &crop, &config)?;
    println!("## Real face crop ({})\n", crop.display());
    println!("| variant | NME against OpenSeeFace's landmarks (60 common points) |\n|---|---|");
    println!(
        "| TrackNet only | {:.2} % |",
        100.0 * agreement.tracknet_nme
    );
    println!("| + refinement | {:.2} % |", 100.0 * agreement.refined_nme);
    Ok(())
}
