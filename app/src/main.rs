use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use likeness::demo::DemoConfig;
use likeness::headless::{
    ensure_output_folder, offscreen, render_view, save_png, write_demo_views, write_session_views,
};
use likeness::scene::{Orbit, Scene, StudioView, parse_weights};
use likeness::settings::STUDIO_APP_ID;
use likeness::studio::StudioApp;
use likeness::studio_session::StudioSession;
use likeness::studio_shots::write_studio_panels;

/// Likeness: a personalized face model you can see, measure and export.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    /// The face template: ict_face_model.safetensors, or the upstream ICT FaceKit
    /// FaceXModel folder. Default: $LIKENESS_FACEMODEL, else
    /// ../shared/facemodel/ict_face_model.safetensors beside the repository.
    #[arg(long, global = true, value_name = "PATH")]
    facemodel: Option<PathBuf>,

    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Open the studio on its built-in demo (the default). Without a display, writes the
    /// demo's views to --out instead.
    Studio {
        /// Where the views go when no display is available.
        #[arg(long, default_value = "likeness-demo")]
        out: PathBuf,
        /// Measure the window's frame rate: play the demo on --panel for this many seconds
        /// (after a 3 s warm-up), print the frame times and close.
        #[arg(long, value_name = "SECONDS")]
        measure_fps: Option<f64>,
        /// The panel --measure-fps plays: overlay, face, puppet, person_b, or any panel of
        /// `demo --headless` (input, blendshapes, static_albedo, ...).
        #[arg(long, default_value = "puppet")]
        panel: String,
        /// Window size in points, WIDTHxHEIGHT.
        #[arg(long, default_value = "1280x800")]
        size: String,
        /// Wait for the display's refresh (vsync); off by default with --measure-fps, so it
        /// measures what the studio can sustain rather than the refresh rate.
        #[arg(long)]
        vsync: Option<bool>,
        /// Render the puppet view at half size while a clip plays (default: on without a
        /// GPU); the File menu has the same choice.
        #[arg(long)]
        reduce_3d_while_playing: Option<bool>,
        /// How frames reach the window: `swapchain` (eframe's wgpu surface), `software`
        /// (drawn offscreen and shown through shared memory; for CPU adapters, whose
        /// swapchain may copy every frame through the X socket), or `auto` (software on a
        /// CPU adapter, else swapchain). --vsync applies to the swapchain only.
        #[arg(long, value_enum, default_value_t = Present::Auto)]
        present: Present,
    },
    /// Write the demo's views to PNG files without opening a window.
    Demo {
        /// Kept for symmetry with the studio; the demo command never opens a window.
        #[arg(long)]
        headless: bool,
        #[arg(long, default_value = "likeness-demo")]
        out: PathBuf,
    },
    /// Write the data the Python training code shares with Rust (attention masks, the
    /// sampling function F, mean albedo, parsing map, and a parity reference for
    /// equations (2) and (3)) to OUT/face_fixture.safetensors.
    ExportFixture {
        #[arg(long, default_value = "training/.cache")]
        out: PathBuf,
    },
    /// Drive a glTF/GLB/VRM puppet with tracked motion and export the result. Prints the
    /// mapping report (what drives what, what is unmapped or ambiguous).
    ///
    /// Absurd values in the tracks are refused with the frame (JSON) or line (CSV) and the
    /// field named: times must be finite, within 0 to 24 h (86,400 s), increasing, and at
    /// least 0.0001 s apart as 32-bit floats (near 24 h: 1/128 s); weights must be finite
    /// and within [-0.5, 1.5] (then clamped to [0, 1]); head angles within ±360 degrees
    /// (±2π rad in a CSV); a `translation` within ±10,000 cm. Live Link timecodes must be
    /// HH:MM:SS:FF.fff with FF below 60. An --out that is the tracks, the puppet or the
    /// mapping file is refused.
    Retarget {
        /// Tracking JSON (`likeness track`, or any file with `arkit_names` and frames of
        /// `arkit_weights`) or a Live Link Face CSV.
        #[arg(long)]
        tracks: PathBuf,
        /// The puppet: .glb, .gltf or .vrm.
        #[arg(long)]
        puppet: PathBuf,
        /// Mapping data (JSON). Default: PUPPET.mapping.json beside the puppet if it
        /// exists, else automatic mapping by names.
        #[arg(long)]
        mapping: Option<PathBuf>,
        /// anim.glb (the puppet with a glTF animation), anim.csv (Live Link Face) or
        /// anim.json (per-frame morph weights), chosen by the extension.
        #[arg(long)]
        out: PathBuf,
    },
    /// Regenerate the project's own puppets (assets/puppets/*.glb) from their code.
    GeneratePuppets {
        #[arg(long, default_value = "assets/puppets")]
        out: PathBuf,
    },
    /// Track faces in footage: per-frame blendshape weights (ICT and ARKit names), head
    /// pose, lighting, landmarks and face box, as JSON (schema in the README) and
    /// optionally as a Live Link Face CSV.
    Track {
        /// An image, a folder of images, a video file, `webcam[:DEVICE]`, or
        /// `ffmpeg:FORMAT:INPUT` (any FFmpeg input read live, e.g. ffmpeg:lavfi:testsrc2).
        input: String,
        /// The tracking JSON to write (not the input, nor the --csv file).
        #[arg(long)]
        out: PathBuf,
        /// Also write a Live Link Face CSV (not the input, nor the --out file).
        #[arg(long)]
        csv: Option<PathBuf>,
        #[command(flatten)]
        tracking: TrackingArgs,
    },
    /// Learn a person's personalized model (ModelNet on N diverse frames) and save it with
    /// the tracking of the first input as a session file.
    Personalize {
        /// Footage of one person: images, folders, videos (as for `track`).
        #[arg(required = true)]
        inputs: Vec<String>,
        /// The session file to write (person.likeness).
        #[arg(long)]
        out: PathBuf,
        /// How many frames ModelNet sees (chosen for expression and pose diversity).
        #[arg(long, default_value_t = tracking::personalize::DEFAULT_FRAMES,
              value_parser = clap::value_parser!(usize))]
        frames: usize,
        #[command(flatten)]
        tracking: TrackingArgs,
    },
    /// Time the studio playing the demo clip on its live panels (input with overlay, face,
    /// puppet, person B) at a window size, without a display; prints a table.
    BenchStudio {
        #[arg(long, default_value = "1280x720")]
        size: String,
        /// Frames timed per panel.
        #[arg(long, default_value_t = 120)]
        frames: usize,
        /// Comma-separated panels (any of `demo --headless`'s: input, overlay, face,
        /// blendshapes, ..., puppet, person_b), or `all`. A `:full` suffix keeps the
        /// panel's 3D view at full size while playing (`puppet:full`), to compare with the
        /// half size a CPU adapter gets by default.
        #[arg(long, default_value = "overlay,face,puppet,person_b")]
        panels: String,
    },
    /// Render one view of the face to a PNG file without a window.
    Screenshot {
        #[arg(long)]
        out: PathBuf,
        /// Blendshape weights, e.g. jawOpen=0.8,eyeBlinkLeft=1 (ICT or ARKit names).
        #[arg(long, default_value = "")]
        weights: String,
        /// shaded, albedo, normals, wireframe, landmarks or mask:NAME.
        #[arg(long, default_value = "shaded")]
        view: String,
        /// Image size as WIDTHxHEIGHT.
        #[arg(long, default_value = "800x800")]
        size: String,
        /// Head yaw in degrees (positive turns the face to its left).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f32,
        /// Head pitch in degrees.
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        pitch: f32,
    },
}

/// Options shared by `track` and `personalize`.
#[derive(clap::Args)]
struct TrackingArgs {
    /// Temporal smoothing: `default`, `off`, or One-Euro parameters such as
    /// `min_cutoff=1.0,beta=0.3` or `weights.beta=2,rotation.min_cutoff=0.5`.
    /// Always off for a single image.
    #[arg(long, default_value = "default")]
    smooth: String,
    /// Skip test-time refinement (TrackNet's output as is).
    #[arg(long)]
    no_refine: bool,
    /// Inference engine: auto (ONNX Runtime if its library loads, else tract),
    /// onnxruntime or tract.
    #[arg(long, default_value = "auto")]
    backend: String,
    /// ONNX Runtime threads per tracking network. Tracking already runs two stages at once
    /// (decoding and landmarks on one thread, TrackNet and refinement on another), so 1
    /// keeps a core per stage; ModelNet, which runs alone, uses all cores.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// How faces are found: auto or openseeface (OpenSeeFace detection and 66 landmarks; a
    /// missing, mistyped or broken --models folder is an error that says what it should
    /// hold), mediapipe (MediaPipe's BlazeFace and 468-point Face Mesh), or precropped
    /// (every image is taken as a face crop framed like the training images, without the
    /// models; the output's settings say `"locator": "precropped"`).
    #[arg(long, default_value = "auto")]
    locator: String,
    /// Do not search with RetinaFace when the locator's fast detector finds no face
    /// (close-ups, small or grey faces). It runs on ONNX Runtime only, from
    /// retinaface_640x640_opt.onnx beside the OpenSeeFace models; without either, tracking
    /// goes on without it.
    #[arg(long)]
    no_fallback_detector: bool,
    /// Folder of the locator's models: OpenSeeFace's (mnv3_detection_opt.onnx and
    /// lm_model0_opt.onnx for ONNX Runtime; the *_plain_b1.onnx rewrites for tract), or
    /// with --locator mediapipe MediaPipe's (face_detection_short_range.onnx,
    /// face_landmark.onnx). Default: $LIKENESS_MODELS/openseeface (or /mediapipe), else
    /// ../shared/models/openseeface (or mediapipe) beside the repository.
    #[arg(long, value_name = "DIR")]
    models: Option<PathBuf>,
    /// Folder of Likeness's networks (manifest.json, track_net.onnx, model_net.onnx).
    /// Default: $LIKENESS_NETWORKS, else assets/models.
    #[arg(long, value_name = "DIR")]
    networks: Option<PathBuf>,
    /// Horizontal field of view of the camera in degrees (default 50 for footage).
    #[arg(long, allow_hyphen_values = true)]
    fov: Option<f32>,
    /// Frame rate given to image folders.
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// Stop after this many frames (a camera runs until Ctrl-C otherwise).
    #[arg(long)]
    max_frames: Option<usize>,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

impl TrackingArgs {
    fn options(&self, single_image: bool) -> Result<likeness::track_cli::TrackOptions> {
        use tracking::pipeline::TrackerConfig;
        let mut config = TrackerConfig {
            backend: self.backend.parse()?,
            threads: self.threads.clamp(1, 64),
            locator: self.locator.parse()?,
            fov_deg: likeness::track_cli::parse_fov(self.fov)?,
            fallback_detector: !self.no_fallback_detector,
            ..TrackerConfig::default()
        };
        if let Some(dir) = &self.networks {
            config.networks_dir = dir.clone();
        }
        if let Some(dir) = &self.models {
            match config.locator {
                tracking::pipeline::LocatorChoice::MediaPipe => config.mediapipe_dir = dir.clone(),
                _ => config.models_dir = dir.clone(),
            }
        }
        if self.no_refine {
            config.refine = None;
        }
        config.smoothing = if single_image {
            tracking::smooth::SmoothingConfig::off()
        } else {
            self.smooth.parse().context("--smooth")?
        };
        if !(self.fps.is_finite() && self.fps > 0.0 && self.fps <= 1000.0) {
            bail!("--fps {} is outside (0, 1000]", self.fps);
        }
        Ok(likeness::track_cli::TrackOptions {
            config,
            fps: self.fps,
            max_frames: self.max_frames,
            progress: !self.quiet,
        })
    }
}

fn load_face(facemodel: Option<&std::path::Path>) -> Result<Arc<face::FaceModel>> {
    let template = face::Template::load_default(facemodel)?;
    Ok(Arc::new(face::FaceModel::new(template)))
}

fn parse_size(text: &str) -> Result<(u32, u32)> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .with_context(|| format!("size `{text}` is not WIDTHxHEIGHT"))?;
    let w: u32 = w
        .trim()
        .parse()
        .with_context(|| format!("width in `{text}` is not a number"))?;
    let h: u32 = h
        .trim()
        .parse()
        .with_context(|| format!("height in `{text}` is not a number"))?;
    if !(16..=8192).contains(&w) || !(16..=8192).contains(&h) {
        bail!("size {w}x{h} is outside 16..8192 pixels per side");
    }
    Ok((w, h))
}

fn has_display() -> bool {
    ["DISPLAY", "WAYLAND_DISPLAY"]
        .iter()
        .any(|v| std::env::var_os(v).is_some_and(|s| !s.is_empty()))
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| {
                "likeness=info,face=info,renderer=info,tracking=warn,retarget=warn,wgpu=error,naga=error"
                    .into()
            }),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let command = cli.command.unwrap_or(Command::Studio {
        out: "likeness-demo".into(),
        measure_fps: None,
        panel: "puppet".into(),
        size: "1280x800".into(),
        vsync: None,
        reduce_3d_while_playing: None,
        present: Present::Auto,
    });
    let load_scene = || Scene::load(cli.facemodel.as_deref());
    refuse_overwriting_inputs(&command, cli.facemodel.as_deref())?;
    match command {
        Command::Retarget {
            tracks,
            puppet,
            mapping,
            out,
        } => likeness::retarget_cli::run(&tracks, &puppet, mapping.as_deref(), &out)?,
        Command::Track {
            input,
            out,
            csv,
            tracking,
        } => {
            let single = matches!(
                tracking::source::InputSpec::parse(&input),
                Ok(tracking::source::InputSpec::Image(_))
            );
            let options = tracking.options(single)?;
            likeness::track_cli::run_track(
                load_face(cli.facemodel.as_deref())?,
                &input,
                &out,
                csv.as_deref(),
                options,
            )?
        }
        Command::Personalize {
            inputs,
            out,
            frames,
            tracking,
        } => {
            if !(1..=64).contains(&frames) {
                bail!("--frames {frames} is outside 1..64");
            }
            let options = tracking.options(false)?;
            likeness::track_cli::run_personalize(
                load_face(cli.facemodel.as_deref())?,
                &inputs,
                &out,
                frames,
                options,
            )?
        }
        Command::GeneratePuppets { out } => {
            for path in retarget::generator::write_all(&out)? {
                println!("wrote {}", path.display());
            }
        }
        Command::Studio {
            measure_fps: Some(_),
            ..
        } if !has_display() => {
            bail!("--measure-fps needs a display (for example Xvfb with DISPLAY set)")
        }
        Command::Studio { out, .. } if !has_display() => {
            eprintln!(
                "No display found: writing the studio's demo views to {} instead.",
                out.display()
            );
            report_written(&write_all_demo_views(load_scene()?, &out)?);
        }
        Command::Studio {
            measure_fps,
            panel,
            size,
            vsync,
            reduce_3d_while_playing,
            present,
            ..
        } => {
            let size = parse_size(&size)?;
            let measure = match measure_fps {
                Some(secs) if secs.is_finite() && (0.5..=3600.0).contains(&secs) => {
                    Some((panel, secs))
                }
                Some(secs) => bail!("--measure-fps {secs} is outside 0.5..3600 seconds"),
                None => None,
            };
            let vsync = vsync.unwrap_or(measure.is_none());
            let window = StudioWindow {
                size,
                vsync,
                present,
                reduce_3d_while_playing,
            };
            run_studio(load_scene()?, window, measure)?
        }
        Command::Demo { out, .. } => {
            report_written(&write_all_demo_views(load_scene()?, &out)?);
        }
        Command::ExportFixture { out } => {
            let path = likeness::fixture::export_fixture(&load_scene()?.model, &out)?;
            println!("wrote {}", path.display());
        }
        Command::BenchStudio {
            size,
            frames,
            panels,
        } => {
            let (w, h) = parse_size(&size)?;
            let panels: Vec<String> = if panels.trim() == "all" {
                likeness::studio_shots::panel_file_names()
                    .iter()
                    .filter_map(|f| f.strip_prefix("panel_")?.strip_suffix(".png"))
                    .map(str::to_owned)
                    .collect()
            } else {
                panels.split(',').map(|p| p.trim().to_owned()).collect()
            };
            let scene = load_scene()?;
            let session = demo_session(&scene)?;
            let rows = likeness::studio_shots::bench_studio(
                Arc::new(scene),
                session,
                [w, h],
                frames,
                &panels,
            )?;
            println!(
                "studio at {w}x{h}, demo clip playing at a 60 Hz step, {frames} frames per panel"
            );
            println!(
                "{:<24} {:>8} {:>8} {:>6} {:>7} {:>9} {:>11} {:>9} {:>10} {:>10} {:>10}",
                "panel",
                "mean ms",
                "p95 ms",
                "fps",
                "ui ms",
                "3D ms",
                "paint+rb ms",
                "3D frames",
                "triangles",
                "covered Mpx",
                "draw calls"
            );
            for r in &rows {
                println!(
                    "{:<24} {:>8.2} {:>8.2} {:>6.1} {:>7.2} {:>9.2} {:>11.2} {:>9} {:>10} {:>10.2} {:>10}",
                    r.panel,
                    r.mean_ms,
                    r.p95_ms,
                    r.fps(),
                    r.ui_ms,
                    r.views_ms,
                    r.paint_ms,
                    format!("{}/{}", r.frames_with_3d, r.frames),
                    r.triangles,
                    r.covered_megapixels,
                    r.draw_calls
                );
            }
        }
        Command::Screenshot {
            out,
            weights,
            view,
            size,
            yaw,
            pitch,
        } => {
            ensure_output_folder(&out)?;
            let (weights, clamped) = parse_weights(&weights)?;
            for message in clamped {
                eprintln!("warning: {message}");
            }
            let view = StudioView::parse(&view)?;
            let size = parse_size(&size)?;
            if !yaw.is_finite() || !pitch.is_finite() {
                bail!("yaw and pitch must be numbers");
            }
            let orbit = Orbit {
                yaw_deg: yaw,
                pitch_deg: pitch,
                ..Orbit::default()
            };
            let scene = load_scene()?;
            let mut renderer = offscreen(&scene)?;
            let image = render_view(&scene, &mut renderer, view, &weights, &orbit, size)?;
            save_png(&image, &out)?;
            println!("wrote {}", out.display());
        }
    }
    Ok(())
}

/// Refuses a command whose output file is one of its input files (checked as files, not
/// by name: see `files::same_file`). `track` and `personalize` also check their
/// footage, networks and models themselves; here every writing command is checked against
/// the face template, and `retarget` against its tracks, puppet and mapping.
fn refuse_overwriting_inputs(command: &Command, facemodel: Option<&std::path::Path>) -> Result<()> {
    use likeness::track_cli::refuse_same_files;
    let template = (
        "the face template (--facemodel)".to_string(),
        face::template::resolve_template_path(facemodel),
    );
    let fixture;
    let outputs: Vec<(&str, &std::path::Path)> = match command {
        Command::Retarget {
            tracks,
            puppet,
            mapping,
            out,
        } => {
            let mut inputs = vec![
                ("--tracks".to_string(), tracks.clone()),
                ("--puppet".to_string(), puppet.clone()),
            ];
            match mapping {
                Some(m) => inputs.push(("--mapping".to_string(), m.clone())),
                None => inputs.push((
                    "the puppet's mapping file".to_string(),
                    retarget::mapping::sidecar_path(puppet),
                )),
            }
            // A `.gltf`'s buffers and images are inputs too.
            inputs.extend(
                retarget::puppet::external_files(puppet)
                    .into_iter()
                    .map(|(what, path)| (format!("the puppet's {what}"), path)),
            );
            return refuse_same_files(&inputs, &[("--out", out.as_path())]);
        }
        Command::Track { out, csv, .. } => {
            let mut outputs = vec![("--out", out.as_path())];
            outputs.extend(csv.as_deref().map(|c| ("--csv", c)));
            outputs
        }
        Command::Personalize { out, .. } | Command::Screenshot { out, .. } => {
            vec![("--out", out.as_path())]
        }
        Command::ExportFixture { out } => {
            fixture = out.join(likeness::fixture::FIXTURE_FILE);
            vec![("--out", fixture.as_path())]
        }
        // Folders of fixed PNG names, puppets made from code, or nothing written.
        Command::Studio { .. }
        | Command::Demo { .. }
        | Command::GeneratePuppets { .. }
        | Command::BenchStudio { .. } => Vec::new(),
    };
    refuse_same_files(&[template], &outputs)
}

fn report_written(paths: &[PathBuf]) {
    for p in paths {
        println!("wrote {}", p.display());
    }
}

/// The built-in demo session: a synthetic person rendered, tracked and personalized by the
/// real pipeline (about 10 s on 2 cores).
fn demo_session(scene: &Scene) -> Result<Arc<StudioSession>> {
    let face = Arc::new(face::FaceModel::new(scene.model.template.clone()));
    let demo = likeness::demo::build_demo(scene, face, DemoConfig::default(), |step| {
        tracing::info!("demo: {step}")
    })?;
    Ok(Arc::new(StudioSession::from_demo(&scene.model, demo)))
}

/// What `demo --headless` writes: the 3D views, then every panel of the studio on the demo
/// session (`panel_*.png`) and the session's input frames. The 3D views need only the
/// template; the session also needs the networks and the OpenSeeFace models, so without
/// them the 3D views are still written and the reason is printed.
fn write_all_demo_views(scene: Scene, out: &std::path::Path) -> Result<Vec<PathBuf>> {
    let mut written = write_demo_views(&scene, out, (800, 800))?;
    match demo_session(&scene) {
        Ok(session) => {
            written.extend(write_session_views(session.as_ref(), out)?);
            written.extend(write_studio_panels(Arc::new(scene), session, None, out)?);
        }
        Err(e) => {
            eprintln!("The demo session could not be built, so its panels are missing: {e:#}")
        }
    }
    Ok(written)
}

/// How the studio's frames reach the window (`likeness studio --present`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum Present {
    Auto,
    Swapchain,
    Software,
}

/// The window the studio opens.
struct StudioWindow {
    size: (u32, u32),
    vsync: bool,
    present: Present,
    reduce_3d_while_playing: Option<bool>,
}

/// The adapter the software window draws with, when `present` chooses it: always for
/// `software`, and for `auto` when the adapter is a CPU one.
fn software_render_state(present: Present) -> Result<Option<egui_wgpu::RenderState>> {
    if present == Present::Swapchain {
        return Ok(None);
    }
    let options = likeness::studio_shots::window_renderer_options();
    let mut render_state = match likeness::studio_shots::headless_render_state(options) {
        Ok(rs) => rs,
        // eframe's own window reports the missing adapter in its words.
        Err(_) if present == Present::Auto => return Ok(None),
        Err(e) => return Err(e),
    };
    let on_cpu = render_state.adapter.get_info().device_type == wgpu::DeviceType::Cpu;
    if present == Present::Auto && !on_cpu {
        return Ok(None);
    }
    likeness::soft_window::retarget_for_soft_window(&mut render_state, options);
    Ok(Some(render_state))
}

/// Opens the studio window on the demo. With `measure` (panel, seconds) the window plays
/// that panel, prints its frame times and closes.
fn run_studio(scene: Scene, window: StudioWindow, measure: Option<(String, f64)>) -> Result<()> {
    let session = demo_session(&scene);
    if measure.is_some() && session.is_err() {
        return session.map(|_| ()).context("the demo could not be built");
    }
    let scene = Arc::new(scene);
    let size = window.size;
    let reduce_3d_while_playing = window.reduce_3d_while_playing;
    let viewport = egui::ViewportBuilder::default()
        .with_title(STUDIO_APP_ID)
        .with_inner_size([size.0 as f32, size.1 as f32]);
    let report = Arc::new(std::sync::Mutex::new(None));
    let report_slot = report.clone();
    let setup_error = Arc::new(std::sync::Mutex::new(None::<String>));
    let setup_slot = setup_error.clone();
    let create = move |cc: &eframe::CreationContext<'_>| -> Box<dyn eframe::App> {
        let app = StudioApp::new(cc, scene.clone());
        let mut app = match session {
            Ok(session) => app.with_session(session),
            Err(e) => {
                let mut app = app;
                app.state
                    .notices
                    .error(format!("the demo could not be built: {e:#}"));
                app
            }
        };
        app.window_cleared_to_panel_colour = true;
        app.window_on_cpu_adapter = cc
            .wgpu_render_state
            .as_ref()
            .is_some_and(|rs| rs.adapter.get_info().device_type == wgpu::DeviceType::Cpu);
        if reduce_3d_while_playing.is_some() {
            app.settings.reduce_3d_while_playing = reduce_3d_while_playing;
        }
        if let Some((panel, secs)) = measure {
            if let Err(e) = likeness::studio_shots::set_up_panel(&mut app, &scene, &panel) {
                if let Ok(mut slot) = setup_slot.lock() {
                    *slot = Some(format!("{e:#}"));
                }
                cc.egui_ctx.send_viewport_cmd(egui::ViewportCommand::Close);
            }
            app.state.playback.playing = true;
            let mut probe = likeness::fps_probe::FpsProbe::new(
                &panel,
                std::time::Duration::from_secs(3),
                std::time::Duration::from_secs_f64(secs),
            );
            probe.report = report_slot;
            app.fps_probe = Some(probe);
        }
        Box::new(app)
    };
    let presented = match software_render_state(window.present)? {
        Some(render_state) => {
            likeness::soft_window::run_soft_window(STUDIO_APP_ID, viewport, render_state, create)
                .context("cannot run the studio window")?;
            "software".to_string()
        }
        None => {
            let options = eframe::NativeOptions {
                renderer: eframe::Renderer::Wgpu,
                wgpu_options: likeness::studio_shots::window_wgpu_configuration(window.vsync),
                viewport,
                dithering: likeness::studio_shots::window_renderer_options().dithering,
                ..Default::default()
            };
            eframe::run_native(STUDIO_APP_ID, options, Box::new(move |cc| Ok(create(cc))))
                .map_err(|e| anyhow::anyhow!("cannot open the studio window: {e}"))?;
            format!(
                "swapchain, vsync {}",
                if window.vsync { "on" } else { "off" }
            )
        }
    };
    if let Some(e) = setup_error.lock().ok().and_then(|mut e| e.take()) {
        bail!(e);
    }
    if let Some(r) = report.lock().ok().and_then(|mut r| r.take()) {
        println!(
            "studio window {}x{} (present {presented}, half-size 3D while playing {}), panel {}, \
             demo clip playing: {} frames in {:.1} s",
            size.0,
            size.1,
            match reduce_3d_while_playing {
                Some(true) => "on",
                Some(false) => "off",
                None => "by adapter",
            },
            r.panel,
            r.frames,
            r.seconds
        );
        println!(
            "fps {:.1}; frame interval mean {:.2} ms, median {:.2} ms, p95 {:.2} ms, worst {:.2} ms",
            r.fps(),
            r.mean_ms,
            r.median_ms,
            r.p95_ms,
            r.worst_ms
        );
    }
    Ok(())
}
