//! Recall and speed of each face detector (issue 32, item 7), frame by frame with nothing
//! followed: OpenSeeFace's detector, BlazeFace on the whole frame, BlazeFace with its tiled
//! search where the whole frame finds nothing, and RetinaFace; then the two search chains
//! the followers use (OpenSeeFace's then RetinaFace; BlazeFace, then RetinaFace, then tiles),
//! and the followers themselves on a first frame (their landmark checks included; the Face
//! Mesh follower's hit is the points' centroid).
//!
//! - Held-out synthetic clips (every frame; a hit is a detection whose box centre lies in
//!   the true 68 landmarks' box).
//! - Real photographs that scikit-image ships, written by
//!   `tracking/tests/reference/write_real_faces.py DIR` (the venv scripts/setup.sh makes):
//!   the 100 LFW face crops (25 x 25 grey, scaled to 200 x 200) alone as close-ups and in a
//!   640 x 480 grey frame, the 100 LFW background crops the same way (any detection there
//!   is a false one), and the astronaut (colour and grey) and cameraman photographs as they
//!   are and pasted small into a 1280 x 720 frame (a hit: the box centre within the face
//!   marked by eye).
//!
//! `cargo run --release -p tracking --example detectors -- [--real DIR] [--clips DIR]`

use std::path::{Path, PathBuf};
use std::time::Instant;

use glam::Vec2;
use image::{Rgb, RgbImage};
use tracking::BackendKind;
use tracking::evaluate::{Clip, default_clips_dir};
use tracking::mediapipe::{MESH_TO_IBUG68, MediaPipe, MeshFollower, single_points};
use tracking::openseeface::{FaceFollower, OpenSeeFace};
use tracking::preprocess::Rect;
use tracking::retinaface::RetinaFace;

type AnyResult<T> = Result<T, Box<dyn std::error::Error>>;

fn main() {
    if let Err(e) = run() {
        eprintln!("error: {e}");
        std::process::exit(1);
    }
}

const DETECTORS: [&str; 8] = [
    "OpenSeeFace",
    "BlazeFace (whole frame)",
    "BlazeFace + tiles",
    "RetinaFace",
    "OpenSeeFace, then RetinaFace",
    "BlazeFace, then RetinaFace, then tiles",
    "OpenSeeFace's follower, first frame (+ landmark confidence)",
    "Face Mesh follower, first frame (+ Face Mesh presence)",
];

struct Detectors {
    openseeface: OpenSeeFace,
    blazeface: MediaPipe,
    retinaface: RetinaFace,
    /// The followers as tracking runs them, reset before every frame: what a first frame
    /// (or one after a loss) finds once their landmark checks have run.
    face_follower: FaceFollower,
    mesh_follower: MeshFollower,
}

/// What one detector run found: box centres, and its milliseconds.
struct Found {
    centres: Vec<Vec2>,
    ms: f64,
}

impl Detectors {
    /// The box centres each of [`DETECTORS`] finds in `image`, with the time it took.
    fn run(&mut self, image: &RgbImage) -> AnyResult<[Found; 8]> {
        let timed = |f: &mut dyn FnMut() -> AnyResult<Vec<Vec2>>| -> AnyResult<Found> {
            let started = Instant::now();
            let centres = f()?;
            Ok(Found {
                centres,
                ms: started.elapsed().as_secs_f64() * 1e3,
            })
        };
        let osf = timed(&mut || {
            Ok(self
                .openseeface
                .detect(image)?
                .iter()
                .map(|d| d.face_box.centre())
                .collect())
        })?;
        let blaze = timed(&mut || {
            Ok(self
                .blazeface
                .detect(image)?
                .iter()
                .map(|d| d.face_box.centre())
                .collect())
        })?;
        let tiles = if blaze.centres.is_empty() {
            let found = timed(&mut || {
                Ok(self
                    .blazeface
                    .detect_tiled(image)?
                    .iter()
                    .map(|d| d.face_box.centre())
                    .collect())
            })?;
            Found {
                centres: found.centres,
                ms: blaze.ms + found.ms,
            }
        } else {
            Found {
                centres: blaze.centres.clone(),
                ms: blaze.ms,
            }
        };
        let retina = timed(&mut || {
            Ok(self
                .retinaface
                .detect(image)?
                .iter()
                .map(|d| d.face_box.centre())
                .collect())
        })?;
        let chain = |first: &Found, then: &[&Found]| -> Found {
            let mut ms = first.ms;
            let mut centres = first.centres.clone();
            for next in then {
                if !centres.is_empty() {
                    break;
                }
                ms += next.ms;
                centres = next.centres.clone();
            }
            Found { centres, ms }
        };
        let tiles_only = Found {
            centres: if blaze.centres.is_empty() {
                tiles.centres.clone()
            } else {
                Vec::new()
            },
            ms: tiles.ms - blaze.ms,
        };
        let osf_chain = chain(&osf, &[&retina]);
        let mesh_chain = chain(&blaze, &[&retina, &tiles_only]);
        self.face_follower.reset();
        let face_follower = timed(&mut || {
            Ok(self
                .face_follower
                .step(image)?
                .map(|f| f.face_box.centre())
                .into_iter()
                .collect())
        })?;
        self.mesh_follower.reset();
        let mesh_follower = timed(&mut || {
            Ok(self
                .mesh_follower
                .step(image)?
                .map(|f| f.mesh.points_2d().sum::<Vec2>() / f.mesh.points.len() as f32)
                .into_iter()
                .collect())
        })?;
        Ok([
            osf,
            blaze,
            tiles,
            retina,
            osf_chain,
            mesh_chain,
            face_follower,
            mesh_follower,
        ])
    }
}

#[derive(Clone, Default)]
struct Tally {
    hits: usize,
    false_found: usize,
    frames: usize,
    ms: Vec<f64>,
}

impl Tally {
    /// A frame whose face is `truth` (None: a frame without a face).
    fn add(&mut self, found: &Found, truth: Option<Rect>) {
        self.frames += 1;
        self.ms.push(found.ms);
        match truth {
            Some(face) => {
                if found.centres.iter().any(|c| contains(face, *c)) {
                    self.hits += 1;
                }
            }
            None => {
                if !found.centres.is_empty() {
                    self.false_found += 1;
                }
            }
        }
    }

    fn median_ms(&self) -> f64 {
        let mut ms = self.ms.clone();
        ms.sort_by(f64::total_cmp);
        ms.get(ms.len() / 2).copied().unwrap_or(f64::NAN)
    }
}

fn contains(r: Rect, p: Vec2) -> bool {
    p.x >= r.x && p.x <= r.x + r.width && p.y >= r.y && p.y <= r.y + r.height
}

fn grey_frame(width: u32, height: u32) -> RgbImage {
    RgbImage::from_pixel(width, height, Rgb([128, 128, 128]))
}

/// `image` scaled to `side` pixels tall, pasted at `at` into `frame`; the pasted rectangle.
fn paste(frame: &mut RgbImage, image: &RgbImage, side: u32, at: (u32, u32)) -> (RgbImage, f32) {
    let scale = side as f32 / image.height() as f32;
    let width = ((image.width() as f32 * scale).round() as u32).max(1);
    let scaled = image::imageops::resize(image, width, side, image::imageops::FilterType::Triangle);
    image::imageops::replace(frame, &scaled, i64::from(at.0), i64::from(at.1));
    (scaled, scale)
}

fn print_table(title: &str, tallies: &[Tally; 8], with_faces: bool) {
    println!("\n{title}\n");
    if with_faces {
        println!("| detector | found | median ms per frame |");
    } else {
        println!("| detector | frames with a (false) face | median ms per frame |");
    }
    println!("|---|---|---|");
    for (name, t) in DETECTORS.iter().zip(tallies) {
        let count = if with_faces { t.hits } else { t.false_found };
        println!(
            "| {name} | {count} of {} ({:.0} %) | {:.1} |",
            t.frames,
            100.0 * count as f64 / t.frames.max(1) as f64,
            t.median_ms()
        );
    }
}

fn read(path: &Path) -> AnyResult<RgbImage> {
    Ok(image::open(path)
        .map_err(|e| format!("{}: {e}", path.display()))?
        .to_rgb8())
}

fn run() -> AnyResult<()> {
    let args: Vec<String> = std::env::args().collect();
    let value = |name: &str| {
        args.iter()
            .position(|a| a == name)
            .and_then(|i| args.get(i + 1))
            .map(PathBuf::from)
    };
    let threads = 2;
    let mut detectors = Detectors {
        openseeface: OpenSeeFace::load(
            &tracking::openseeface::default_models_dir(),
            BackendKind::OnnxRuntime,
            threads,
        )?,
        blazeface: MediaPipe::load(
            &tracking::mediapipe::default_models_dir(),
            BackendKind::OnnxRuntime,
            threads,
        )?,
        retinaface: RetinaFace::load(&tracking::openseeface::default_models_dir(), threads)?,
        face_follower: FaceFollower::new(OpenSeeFace::load(
            &tracking::openseeface::default_models_dir(),
            BackendKind::OnnxRuntime,
            threads,
        )?)
        .with_fallback(RetinaFace::load(
            &tracking::openseeface::default_models_dir(),
            threads,
        )?),
        mesh_follower: MeshFollower::new(
            MediaPipe::load(
                &tracking::mediapipe::default_models_dir(),
                BackendKind::OnnxRuntime,
                threads,
            )?,
            single_points(&MESH_TO_IBUG68),
        )
        .with_fallback(RetinaFace::load(
            &tracking::openseeface::default_models_dir(),
            threads,
        )?),
    };
    println!("ONNX Runtime, {threads} threads; nothing followed from frame to frame");

    let clips_dir = value("--clips").unwrap_or_else(default_clips_dir);
    let clips = Clip::load_all(&clips_dir)?;
    let mut tallies: [Tally; 8] = Default::default();
    for clip in &clips {
        for (path, truth) in clip.frames.iter().zip(&clip.truth.frames) {
            let image = read(path)?;
            let [x, y, w, h] = truth.face_box;
            let face = Rect {
                x,
                y,
                width: w,
                height: h,
            };
            for (t, f) in tallies.iter_mut().zip(detectors.run(&image)?) {
                t.add(&f, Some(face));
            }
        }
    }
    print_table(
        &format!(
            "Synthetic clips ({}, {} frames)",
            clips_dir.display(),
            tallies[0].frames
        ),
        &tallies,
        true,
    );

    let Some(real) = value("--real") else {
        println!("\n(no --real DIR: the real photographs were not measured)");
        return Ok(());
    };
    // LFW: 100 faces and 100 backgrounds, 25 x 25, scaled to 200 x 200.
    let side = 200u32;
    let mut close: [Tally; 8] = Default::default();
    let mut framed: [Tally; 8] = Default::default();
    let mut close_bg: [Tally; 8] = Default::default();
    let mut framed_bg: [Tally; 8] = Default::default();
    for i in 0..100 {
        for (kind, close_t, framed_t) in [
            ("face", &mut close, &mut framed),
            ("background", &mut close_bg, &mut framed_bg),
        ] {
            let crop = read(&real.join(format!("lfw-{kind}-{i:03}.png")))?;
            let alone =
                image::imageops::resize(&crop, side, side, image::imageops::FilterType::Triangle);
            let is_face = kind == "face";
            let whole = Rect {
                x: 0.0,
                y: 0.0,
                width: side as f32,
                height: side as f32,
            };
            for (t, f) in close_t.iter_mut().zip(detectors.run(&alone)?) {
                t.add(&f, is_face.then_some(whole));
            }
            let mut frame = grey_frame(640, 480);
            paste(&mut frame, &crop, side, (220, 140));
            let placed = Rect {
                x: 220.0,
                y: 140.0,
                ..whole
            };
            for (t, f) in framed_t.iter_mut().zip(detectors.run(&frame)?) {
                t.add(&f, is_face.then_some(placed));
            }
        }
    }
    print_table(
        "LFW faces (scikit-image's subset), 200 x 200 close-ups",
        &close,
        true,
    );
    print_table("LFW faces, 200 x 200 in a 640 x 480 frame", &framed, true);
    print_table("LFW backgrounds, 200 x 200 alone", &close_bg, false);
    print_table(
        "LFW backgrounds, 200 x 200 in a 640 x 480 frame",
        &framed_bg,
        false,
    );

    // Photographs with faces marked by eye (x, y, width, height in the 512 x 512 image).
    let photos: [(&str, Rect); 3] = [
        (
            "astronaut.png",
            Rect {
                x: 175.0,
                y: 70.0,
                width: 100.0,
                height: 115.0,
            },
        ),
        (
            "astronaut-grey.png",
            Rect {
                x: 175.0,
                y: 70.0,
                width: 100.0,
                height: 115.0,
            },
        ),
        (
            "camera.png",
            Rect {
                x: 180.0,
                y: 95.0,
                width: 75.0,
                height: 95.0,
            },
        ),
    ];
    println!("\nPhotographs (found: the detector's box centre within the face marked by eye)\n");
    print!("| photograph | face height / frame height |");
    for name in DETECTORS {
        print!(" {name} |");
    }
    println!("\n|---|---|{}", "---|".repeat(DETECTORS.len()));
    for (name, face) in photos {
        let photo = read(&real.join(name))?;
        // As it is, then pasted 360 and 180 px tall into 1280 x 720.
        for height in [None, Some(360u32), Some(180)] {
            let (image, face_in_frame) = match height {
                None => (photo.clone(), face),
                Some(h) => {
                    let mut frame = grey_frame(1280, 720);
                    let at = (700u32, 100u32);
                    let (_, scale) = paste(&mut frame, &photo, h, at);
                    let f = Rect {
                        x: at.0 as f32 + face.x * scale,
                        y: at.1 as f32 + face.y * scale,
                        width: face.width * scale,
                        height: face.height * scale,
                    };
                    (frame, f)
                }
            };
            print!(
                "| {name}{} | 1/{:.0} |",
                height.map_or(String::new(), |h| format!(", {h} px tall in 1280 x 720")),
                image.height() as f32 / face_in_frame.height
            );
            for found in detectors.run(&image)? {
                let hit = found.centres.iter().any(|c| contains(face_in_frame, *c));
                print!(" {} ({:.0} ms) |", if hit { "yes" } else { "no" }, found.ms);
            }
            println!();
        }
    }
    Ok(())
}
