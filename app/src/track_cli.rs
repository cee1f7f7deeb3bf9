//! `likeness track` and `likeness personalize`: footage in, tracking JSON / Live Link Face
//! CSV / a personalized session out, with progress bars, and partial results kept when
//! the footage breaks off or the user presses Ctrl-C.

use std::ops::ControlFlow;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{Context, Result, bail};
use face::FaceModel;
use files::write_atomically;
use indicatif::{ProgressBar, ProgressStyle};
use tracking::backend::BackendKind;
use tracking::pipeline::{FrameOutput, TrackEvent, Tracker, TrackerConfig};
use tracking::record::{FrameRecord, TracksDocument};
use tracking::session::{Session, SessionInfo};
use tracking::source::InputSpec;

/// Set by Ctrl-C: stop reading footage, keep what was tracked.
static STOP: AtomicBool = AtomicBool::new(false);

fn install_ctrl_c() {
    // A second install (personalize after track in one process) is harmless to ignore.
    let _ = ctrlc::set_handler(|| STOP.store(true, Ordering::SeqCst));
}

/// Common options of `track` and `personalize`.
pub struct TrackOptions {
    pub config: TrackerConfig,
    pub fps: f64,
    pub max_frames: Option<usize>,
    pub progress: bool,
}

fn progress_bar(len: Option<usize>, show: bool, what: &str) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = match len {
        Some(n) => ProgressBar::new(n as u64),
        None => ProgressBar::new_spinner(),
    };
    let template = if len.is_some() {
        "{prefix} [{bar:30}] {pos}/{len} frames, {per_sec}, eta {eta} {msg}"
    } else {
        "{prefix} {spinner} {pos} frames, {per_sec} {msg}"
    };
    if let Ok(style) = ProgressStyle::with_template(template) {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_prefix(what.to_string());
    bar
}

/// Tracks every frame of one input. Returns the document (complete or not) and the frame
/// outputs when `keep_outputs` (for personalization).
pub fn track_input(
    tracker: &mut Tracker,
    input: &str,
    options: &TrackOptions,
    keep_outputs: bool,
) -> Result<(TracksDocument, Vec<FrameOutput>, (u32, u32))> {
    let spec = InputSpec::parse(input).with_context(|| format!("input `{input}`"))?;
    let mut source = spec
        .open(options.fps)
        .with_context(|| format!("input `{input}`"))?;
    let mut doc = TracksDocument::new(source.describe(), source.fps());
    let bar = progress_bar(source.len_hint(), options.progress, "tracking");
    let mut outputs = Vec::new();
    let mut size = (0, 0);
    let mut first_size = None;
    let mut faces = 0usize;
    let live = source.is_live();
    // Decoding and landmarks run a frame ahead on a second thread (Tracker::track_source).
    let result = tracker.track_source(source.as_mut(), |event| {
        match event {
            TrackEvent::Skipped(skip) => {
                tracing::warn!("frame {}: {}", skip.index, skip.error);
                doc.frames.push(FrameRecord::no_face(
                    skip.index,
                    skip.time_s,
                    Some(skip.error.to_string()),
                ));
            }
            TrackEvent::Frame(frame, out) => {
                // A folder of images of different sizes: each has its own camera (the
                // tracker starts a new sequence by itself); the document names the first.
                if first_size.is_none() {
                    first_size = Some(frame.image.dimensions());
                }
                size = frame.image.dimensions();
                if out.record.face {
                    faces += 1;
                }
                doc.frames.push(out.record.clone());
                if keep_outputs {
                    outputs.push(*out);
                }
            }
        }
        bar.inc(1);
        bar.set_message(format!("{faces} with a face"));
        if STOP.load(Ordering::SeqCst) {
            // Ctrl-C on a live camera is how it ends; on a file it cuts the clip short.
            if !live {
                doc.complete = false;
                doc.error = Some("stopped by the user".into());
            }
            return ControlFlow::Break(());
        }
        if options.max_frames.is_some_and(|m| doc.frames.len() >= m) {
            return ControlFlow::Break(());
        }
        ControlFlow::Continue(())
    });
    doc.camera = first_size.map(|(w, h)| tracker.camera_record(w, h));
    if let Err(e) = result {
        // The footage broke off: keep everything tracked so far.
        doc.complete = false;
        doc.error = Some(e.to_string());
    }
    bar.finish_and_clear();
    Ok((doc, outputs, size))
}

/// `likeness track INPUT --out tracks.json [--csv tracks.csv]`.
pub fn run_track(
    face: Arc<FaceModel>,
    input: &str,
    out: &Path,
    csv: Option<&Path>,
    options: TrackOptions,
) -> Result<()> {
    check_output(out)?;
    let mut outputs = vec![("--out", out)];
    if let Some(csv) = csv {
        check_output(csv)?;
        outputs.push(("--csv", csv));
    }
    refuse_same_files(&tracking_inputs(&[input], &options.config), &outputs)?;
    install_ctrl_c();
    // `auto` never takes frames as face crops by itself: without the OpenSeeFace models it
    // is an error that says where they were looked for and how to pick `precropped`.
    let mut tracker = Tracker::new(face, options.config.clone(), true)?;
    let (mut doc, _, _) = track_input(&mut tracker, input, &options, false)?;
    doc.settings = settings_json(&tracker, &options);
    doc.save(out)?;
    if let Some(csv) = csv {
        write_csv(&doc, csv)?;
    }
    report(&doc, out);
    if let Some(e) = &doc.error {
        bail!(
            "tracking stopped early ({e}); the {} frames before it are in {}",
            doc.frames.len(),
            out.display()
        );
    }
    Ok(())
}

/// `likeness personalize INPUT... --out person.likeness`.
pub fn run_personalize(
    face: Arc<FaceModel>,
    inputs: &[String],
    out: &Path,
    frames: usize,
    options: TrackOptions,
) -> Result<()> {
    check_output(out)?;
    if inputs.is_empty() {
        bail!("personalize needs at least one input");
    }
    let named: Vec<&str> = inputs.iter().map(String::as_str).collect();
    refuse_same_files(&tracking_inputs(&named, &options.config), &[("--out", out)])?;
    install_ctrl_c();
    // As for `track`: `auto` without the landmark models is an error, never a silent crop.
    let mut tracker = Tracker::new(face.clone(), options.config.clone(), true)?;
    let mut docs = Vec::new();
    for input in inputs {
        let (doc, outputs, size) = track_input(&mut tracker, input, &options, true)?;
        if let Some(e) = &doc.error {
            tracing::warn!(
                "{input}: {e} (using the {} frames before it)",
                doc.frames.len()
            );
        }
        docs.push((doc, outputs, size));
    }
    // ModelNet over the frames of all inputs (one person), moved into one list rather
    // than copied: each keeps its network input. The first input's frames come first.
    let mut docs = docs.into_iter();
    let Some((mut tracks, first_outputs, size)) = docs.next() else {
        bail!("personalize needs at least one input");
    };
    let first_len = first_outputs.len();
    let mut owned = first_outputs;
    for (_, outputs, _) in docs {
        owned.extend(outputs);
    }
    let kind = tracker.backend();
    // ModelNet runs alone (tracking has finished): all cores.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut model_net = tracking::networks::ModelNet::load(
        &tracker.manifest,
        kind,
        options.config.threads.max(cores),
    )?;
    let bar = progress_bar(None, options.progress, "personalizing");
    bar.enable_steady_tick(std::time::Duration::from_millis(120));
    let (corrections, picked) = tracking::personalize::personalize(&mut model_net, &owned, frames)?;
    bar.finish_and_clear();
    let blendshapes = Arc::new(face.personalize(&corrections)?);
    tracker.set_blendshapes(blendshapes)?;
    // Track the first input again with the person's own blendshapes (refinement and
    // smoothing only).
    tracker.reset();
    tracks.frames = owned[..first_len]
        .iter()
        .map(|o| tracker.retrack(o, size.0, size.1))
        .collect();
    let selected_frames = picked.iter().map(|&i| owned[i].record.index).collect();
    tracks.settings = settings_json(&tracker, &options);
    let session = Session {
        info: SessionInfo {
            created_by: format!("likeness {}", env!("CARGO_PKG_VERSION")),
            source: inputs.join(", "),
            selected_frames,
            backend: kind.to_string(),
            networks: tracker.manifest.dir.display().to_string(),
        },
        corrections,
        tracks,
        footage: None,
        observations: Vec::new(),
    };
    session.save(out)?;
    println!(
        "wrote {} (ModelNet on {} frames: {:?}; {} frames tracked)",
        out.display(),
        picked.len(),
        session.info.selected_frames,
        session.tracks.frames.len()
    );
    Ok(())
}

fn settings_json(tracker: &Tracker, options: &TrackOptions) -> serde_json::Value {
    serde_json::json!({
        "backend": tracker.backend().to_string(),
        "locator": tracker.locator_name(),
        "refinement": options.config.refine.is_some(),
        "smoothing": options.config.smoothing.to_string(),
        "fov_deg": options.config.fov_deg,
    })
}

fn check_output(path: &Path) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        bail!("the folder of {} does not exist", path.display());
    }
    if path.is_dir() {
        bail!("{} is a folder; give a file name", path.display());
    }
    Ok(())
}

fn write_csv(doc: &TracksDocument, path: &Path) -> Result<()> {
    let tracks = retarget::tracks::Tracks::parse(&doc.to_json())
        .map_err(|e| anyhow::anyhow!("cannot convert the tracking to CSV: {e}"))?;
    write_atomically(
        path,
        retarget::export::live_link_csv_raw(&tracks).as_bytes(),
    )?;
    Ok(())
}

fn report(doc: &TracksDocument, out: &Path) {
    let faces = doc.frames.iter().filter(|f| f.face).count();
    println!(
        "wrote {} ({} frames, {} with a face)",
        out.display(),
        doc.frames.len(),
        faces
    );
}

/// The files `track` and `personalize` read: the footage named by `inputs` (a file, or a
/// folder whose images are read; live inputs name no file unless they are one) and the
/// network and landmark model files. (`main` adds the face template.)
pub fn tracking_inputs(inputs: &[&str], config: &TrackerConfig) -> Vec<(String, PathBuf)> {
    let mut paths = Vec::new();
    for input in inputs {
        let path = match InputSpec::parse(input) {
            Ok(InputSpec::Image(p) | InputSpec::Folder(p) | InputSpec::Video(p)) => p,
            Ok(InputSpec::Webcam(device)) => PathBuf::from(device),
            Ok(InputSpec::FfmpegLive { input, .. }) => PathBuf::from(input),
            // Reading it fails later with its own message.
            Err(_) => continue,
        };
        paths.push((format!("the input {input}"), path));
    }
    for name in ["manifest.json", "track_net.onnx", "model_net.onnx"] {
        paths.push((
            format!("the network file {name}"),
            config.networks_dir.join(name),
        ));
    }
    for kind in [BackendKind::OnnxRuntime, BackendKind::Tract] {
        let (detector, landmarks) = tracking::openseeface::model_files(&config.models_dir, kind);
        paths.push(("the OpenSeeFace detector".into(), detector));
        paths.push(("the OpenSeeFace landmark model".into(), landmarks));
    }
    paths.push((
        "the MediaPipe detector".into(),
        config
            .mediapipe_dir
            .join(tracking::mediapipe::DETECTOR_FILE),
    ));
    paths.push((
        "the MediaPipe Face Mesh model".into(),
        config.mediapipe_dir.join(tracking::mediapipe::MESH_FILE),
    ));
    paths
}

/// Refuses an output that is one of the `inputs` or another output, named by the option
/// or role given with it. Paths are compared as files (see [`files::same_file`]), so a relative
/// path, a symbolic link or a hard link to an input is caught. An output that would land
/// among the images of an input folder under an image's name is refused too.
pub fn refuse_same_files<I, O>(inputs: &[(I, PathBuf)], outputs: &[(O, &Path)]) -> Result<()>
where
    I: AsRef<str>,
    O: AsRef<str>,
{
    for (k, (out_role, out)) in outputs.iter().enumerate() {
        let out_role = out_role.as_ref();
        for (in_role, input) in inputs {
            let in_role = in_role.as_ref();
            if files::same_file(out, input) {
                bail!(
                    "{out_role} {} is the same file as {in_role} ({}): writing it would destroy \
                     what is read; choose another output file",
                    out.display(),
                    input.display()
                );
            }
            let in_folder = input.is_dir()
                && tracking::source::is_image_path(out)
                && out.exists()
                && out.parent().is_some_and(|dir| {
                    files::same_file(
                        if dir.as_os_str().is_empty() {
                            Path::new(".")
                        } else {
                            dir
                        },
                        input,
                    )
                });
            if in_folder {
                bail!(
                    "{out_role} {} is one of the images of {in_role} ({}): writing it would \
                     destroy a frame; choose another output file",
                    out.display(),
                    input.display()
                );
            }
        }
        for (other_role, other) in &outputs[k + 1..] {
            if files::same_file(out, other) {
                bail!(
                    "{out_role} {} and {} {} are the same file: one would overwrite the \
                     other; give them different names",
                    out.display(),
                    other_role.as_ref(),
                    other.display()
                );
            }
        }
    }
    Ok(())
}

/// Parses `--fov`.
pub fn parse_fov(v: Option<f32>) -> Result<Option<f32>> {
    match v {
        Some(f) if !(f.is_finite() && (5.0..=170.0).contains(&f)) => {
            bail!("--fov {f} is outside 5..170 degrees")
        }
        other => Ok(other),
    }
}

pub fn default_out(input: &str) -> PathBuf {
    PathBuf::from(format!("{}.tracks.json", input.trim_end_matches('/')))
}
