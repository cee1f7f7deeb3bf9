//! Accuracy tables: expression MAE, landmark NME and pose error on the held-out synthetic
//! clips for TrackNet alone, with refinement, with the personalized model and with
//! smoothing; and on the real face crop in ../shared/testdata, how far the model's
//! landmarks are from OpenSeeFace's with and without refinement.
//!
//! `cargo run --release -p tracking --example evaluate [-- --backend tract]`

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
    let config = TrackerConfig {
        backend,
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
