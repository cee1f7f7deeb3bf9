//! Accuracy tables: expression MAE (all channels and the visible ones, beside w = 0 and
//! each channel's mean on the same frames), landmark NME (box and inter-ocular) and pose
//! error on the held-out synthetic clips for TrackNet alone, with refinement, with the
//! personalized model and with smoothing, and per channel (MAE, correlation, F1) for the
//! first two; and on the real face crop in ../shared/testdata, how far the model's
//! landmarks are from OpenSeeFace's with and without refinement.
//!
//! `cargo run --release -p tracking --example evaluate [-- --backend tract]
//! [--weight-prior X] [--rotation-prior X] [--translation-prior X] [--smooth SPEC]`
//! (the priors and smoothing default to the tracker's defaults).

use std::sync::Arc;

use face::{FaceModel, Template};
use tracking::backend::BackendChoice;
use tracking::evaluate::{Clip, default_clips_dir, evaluate, real_crop_agreement};
use tracking::pipeline::TrackerConfig;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let backend: BackendChoice = args
        .iter()
        .position(|a| a == "--backend")
        .and_then(|i| args.get(i + 1))
        .map_or(Ok(BackendChoice::Auto), |b| b.parse())?;
    let face = Arc::new(FaceModel::new(Template::load_default(None)?));
    let value = |name: &str| -> Result<Option<f32>, Box<dyn std::error::Error>> {
        match args
            .iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
        {
            Some(v) => Ok(Some(v.parse::<f32>().map_err(|e| format!("{name}: {e}"))?)),
            None => Ok(None),
        }
    };
    let mut refine = tracking::refine::RefineConfig::default();
    if let Some(v) = value("--weight-prior")? {
        refine.weight_prior = v;
    }
    if let Some(v) = value("--rotation-prior")? {
        refine.rotation_prior = v;
    }
    if let Some(v) = value("--translation-prior")? {
        refine.translation_prior = v;
    }
    refine.validate()?;
    let smoothing = match args
        .iter()
        .position(|a| a == "--smooth")
        .and_then(|i| args.get(i + 1))
    {
        Some(spec) => spec.parse()?,
        None => tracking::smooth::SmoothingConfig::default(),
    };
    let config = TrackerConfig {
        backend,
        refine: Some(refine),
        smoothing,
        ..TrackerConfig::default()
    };
    let clips = Clip::load_all(&default_clips_dir())?;
    let evaluation = evaluate(
        face.clone(),
        &clips,
        &config,
        tracking::personalize::DEFAULT_FRAMES,
    )?;
    println!(
        "## Held-out synthetic clips ({})\n",
        default_clips_dir().display()
    );
    println!("{}", evaluation.table());
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
