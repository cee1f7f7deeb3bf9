//! How close each face locator's own 68 landmarks come to the truth on the held-out
//! synthetic clips (issue 32, items 3 and 5), by region, before TrackNet or refinement:
//! OpenSeeFace's 66 points, Face Mesh's points through the common iBUG subset
//! (`MESH_TO_IBUG68`), and Face Mesh's points over the template's landmark vertices (the
//! ICT correspondence, three points weighted per landmark: what the `mediapipe` locator
//! hands on). NME is the mean distance
//! over sqrt(area of the true landmark box); frames a locator finds no face in count once
//! in its "found" column and not in its NME.
//!
//! `cargo run --release -p tracking --example locators [-- --backend tract]`

use std::sync::Arc;

use face::{FaceModel, Template};
use glam::Vec2;
use tracking::BackendChoice;
use tracking::evaluate::{Clip, default_clips_dir};
use tracking::mediapipe::{
    self, IctCorrespondence, MESH_TO_IBUG68, MediaPipe, MeshFollower, single_points,
};
use tracking::openseeface::{self, FaceFollower, OpenSeeFace};
use tracking::preprocess::Rect;
use tracking::source::{FrameSource, Next};

/// jaw, brows, nose, eyes, lips (iBUG ranges).
const REGIONS: [(&str, std::ops::Range<usize>); 5] = [
    ("jaw", 0..17),
    ("brows", 17..27),
    ("nose", 27..36),
    ("eyes", 36..48),
    ("lips", 48..68),
];

#[derive(Default)]
struct Tally {
    all: f64,
    regions: [f64; 5],
    found: usize,
    frames: usize,
}

impl Tally {
    fn add(&mut self, points: Option<&[Option<(Vec2, f32)>; 68]>, truth: &[[f32; 2]]) {
        self.frames += 1;
        let Some(points) = points else { return };
        let truth: Vec<Vec2> = truth.iter().map(|p| Vec2::from(*p)).collect();
        let Some(bounds) = Rect::bounding(truth.iter().copied()) else {
            return;
        };
        let norm = (bounds.width * bounds.height).sqrt();
        let error = |range: std::ops::Range<usize>| {
            let d: Vec<f32> = range
                .filter_map(|i| points[i].map(|(p, _)| (p - truth[i]).length() / norm))
                .collect();
            f64::from(d.iter().sum::<f32>()) / d.len().max(1) as f64
        };
        self.found += 1;
        self.all += error(0..68);
        for (sum, (_, range)) in self.regions.iter_mut().zip(REGIONS) {
            *sum += error(range);
        }
    }

    fn row(&self, name: &str) -> String {
        let n = self.found.max(1) as f64;
        let regions: Vec<String> = self
            .regions
            .iter()
            .map(|r| format!("{:.2} %", 100.0 * r / n))
            .collect();
        format!(
            "| {name} | {:.2} % | {} | {:.0} % |",
            100.0 * self.all / n,
            regions.join(" | "),
            100.0 * self.found as f64 / self.frames.max(1) as f64
        )
    }
}

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

fn run() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let backend: BackendChoice = match args.iter().position(|a| a == "--backend") {
        Some(i) => args.get(i + 1).ok_or("--backend needs a value")?.parse()?,
        None => BackendChoice::Auto,
    };
    let kind = backend.resolve()?;
    let face = Arc::new(FaceModel::new(Template::load_default(None)?));
    let over_template =
        IctCorrespondence::load(&mediapipe::default_models_dir())?.ibug68_points(&face.template)?;
    let clips = Clip::load_all(&default_clips_dir())?;
    let mut tallies: [Tally; 3] = Default::default();
    for clip in &clips {
        let mut openseeface = FaceFollower::new(OpenSeeFace::load(
            &openseeface::default_models_dir(),
            kind,
            1,
        )?);
        let mut mesh = MeshFollower::new(
            MediaPipe::load(&mediapipe::default_models_dir(), kind, 1)?,
            over_template,
        );
        let mut source = clip.source();
        let mut k = 0;
        while let Next::Frame(frame) = source.next_frame()? {
            let truth = &clip.truth.frames[k].landmarks_68;
            let found = openseeface.step(&frame.image)?;
            tallies[0].add(found.map(|f| f.landmarks.to_ibug68()).as_ref(), truth);
            let found = mesh.step(&frame.image)?;
            tallies[1].add(
                found
                    .as_ref()
                    .map(|f| f.mesh.to_ibug68(&single_points(&MESH_TO_IBUG68)))
                    .as_ref(),
                truth,
            );
            tallies[2].add(
                found
                    .as_ref()
                    .map(|f| f.mesh.to_ibug68(&over_template))
                    .as_ref(),
                truth,
            );
            k += 1;
        }
    }
    println!(
        "{} held-out clips ({}), {} frames, backend {kind}\n",
        clips.len(),
        default_clips_dir().display(),
        tallies[0].frames
    );
    println!(
        "| locator's 68 points | NME | jaw | brows | nose | eyes | lips | face found |\n|---|---|---|---|---|---|---|---|"
    );
    for (tally, name) in tallies.iter().zip([
        "OpenSeeFace (66 points)",
        "Face Mesh, common iBUG subset",
        "Face Mesh over the template's landmarks (the `mediapipe` locator)",
    ]) {
        println!("{}", tally.row(name));
    }
    Ok(())
}
