//! The built-in demo (issue 6, deliverable 10): a synthetic person made at start,
//! deterministic in a seed, with known personal corrections (dS_0, dS_i, dR_0, dR_i); a
//! short clip of that person rendered by the project's own renderer; and that clip tracked
//! and personalized by the real pipeline (OpenSeeFace landmarks, TrackNet, refinement,
//! ModelNet), exactly as a user's footage would be.
//!
//! The person's truth is kept beside what ModelNet learned so the studio can show both.
//! Nothing here reads third-party data except the template and the networks the rest of
//! the program uses.

use std::sync::Arc;

use anyhow::{Context, Result, bail};
use face::camera::{HeadPose, Intrinsics};
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{
    BlendshapeWeights, FaceModel, ICT_NAMES, NUM_BLENDSHAPES, PersonalCorrections,
    PersonalizedBlendshapes,
};
use glam::{Vec2, Vec3};
use image::RgbImage;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use renderer::{Camera, FrameParams, MeshData, OffscreenRenderer, TextureLayers, ViewMode};
use tracking::pipeline::{FrameOutput, TrackEvent, Tracker, TrackerConfig};
use tracking::record::FrameRecord;
use tracking::source::{Frame, FrameSource, Next};

use crate::scene::{Scene, mesh_data, rgba8_texels, texture_layers};

/// What the demo makes.
#[derive(Clone, Debug)]
pub struct DemoConfig {
    pub seed: u64,
    pub frames: usize,
    pub width: u32,
    pub height: u32,
    pub fps: f64,
    /// Horizontal field of view of the demo camera.
    pub fov_deg: f32,
    /// Height of the 68 landmarks' bounding box in pixels at the start.
    pub face_px: f32,
    /// Frames ModelNet sees.
    pub personalize_frames: usize,
}

impl Default for DemoConfig {
    fn default() -> Self {
        Self {
            seed: 7,
            frames: 96,
            width: 640,
            height: 480,
            fps: 30.0,
            fov_deg: 50.0,
            face_px: 190.0,
            personalize_frames: tracking::personalize::DEFAULT_FRAMES,
        }
    }
}

/// The scripted performance: per frame, the true weights, head pose and lighting.
#[derive(Clone, Debug)]
pub struct DemoMotion {
    pub weights: Vec<BlendshapeWeights>,
    pub poses: Vec<HeadPose>,
    /// SH lighting gamma (27), constant over the clip.
    pub gamma: [f32; 27],
}

/// The person's true personal corrections (what a perfect ModelNet would predict).
pub fn synthetic_person(
    model: &FaceModel,
    mean_albedo_face: &UvMap,
    seed: u64,
) -> PersonalCorrections {
    let mut rng = StdRng::seed_from_u64(seed);
    let n = CORRECTION_SIZE;
    // Where the face tile has texels at all: the union of the attention masks, widened by
    // where the mean albedo is painted (masks cover only the moving parts).
    let face_texels: Vec<usize> = (0..n * n)
        .filter(|&t| {
            mean_albedo_at(mean_albedo_face, t, n)
                .iter()
                .any(|c| *c > 0.02)
        })
        .collect();
    let mut corrections = PersonalCorrections::zeros();
    // dS_0: identity, smooth bumps of up to ~4 mm (wider nose, fuller cheeks, longer chin).
    corrections.identity_shape = bump_field(&mut rng, &face_texels, n, 14, (6.0, 16.0), 0.35);
    // dS_i: how this person moves differently; larger around the mouth and jaw, where
    // people differ most (the paper's motivating examples).
    for (i, name) in ICT_NAMES.iter().enumerate() {
        let mask = model.masks.mask(i);
        let inside: Vec<usize> = (0..n * n).filter(|&t| mask.data[t] > 0.5).collect();
        if inside.is_empty() {
            continue;
        }
        let amplitude = if name.starts_with("mouth") || name.starts_with("jaw") {
            0.45
        } else {
            0.25
        };
        corrections.expression_shapes[i] =
            bump_field(&mut rng, &inside, n, 4, (4.0, 10.0), amplitude);
    }
    // dR_0: skin tone (a scale of R_0^t, as an additive correction) and soft blotches.
    let tone: f32 = rng.random_range(0.8..1.08);
    let warmth: f32 = rng.random_range(-0.03..0.03);
    let blotches = bump_field(&mut rng, &face_texels, n, 10, (3.0, 9.0), 0.05);
    let mut static_albedo = UvMap::zeros(n, n, 3);
    for &t in &face_texels {
        let mean = mean_albedo_at(mean_albedo_face, t, n);
        let blotch = blotches.data[t * 3].abs() * 0.6;
        for (c, (out, m)) in static_albedo.data[t * 3..t * 3 + 3]
            .iter_mut()
            .zip(mean)
            .enumerate()
        {
            let tint = if c == 0 { warmth } else { -0.5 * warmth };
            *out = (tone - 1.0) * m + tint - blotch;
        }
    }
    corrections.static_albedo = static_albedo;
    // dR_i: folds that darken the skin with the expression (smile lines, forehead lines,
    // crow's feet), inside A_i, only for the shapes that fold skin.
    for (i, name) in ICT_NAMES.iter().enumerate() {
        let folds = [
            "mouthSmile",
            "browInnerUp",
            "browOuterUp",
            "eyeSquint",
            "cheekSquint",
            "noseSneer",
            "browDown",
        ]
        .iter()
        .any(|p| name.starts_with(p));
        if !folds {
            continue;
        }
        let mask = model.masks.mask(i);
        let inside: Vec<usize> = (0..n * n).filter(|&t| mask.data[t] > 0.5).collect();
        if inside.is_empty() {
            continue;
        }
        let field = bump_field(&mut rng, &inside, n, 3, (1.5, 4.0), 0.12);
        let mut dynamic = UvMap::zeros(n, n, 3);
        for t in 0..n * n {
            // Darker and slightly redder, never lighter.
            let d = -field.data[t * 3].abs();
            dynamic.data[t * 3] = 0.8 * d;
            dynamic.data[t * 3 + 1] = d;
            dynamic.data[t * 3 + 2] = d;
        }
        corrections.dynamic_albedo[i] = dynamic;
    }
    corrections
}

/// The mean albedo R_0^t (any size) averaged over the footprint of texel `t` of an n x n
/// grid.
fn mean_albedo_at(mean: &UvMap, t: usize, n: usize) -> [f32; 3] {
    let (x, y) = (t % n, t / n);
    let (fx, fy) = (mean.width / n, mean.height / n);
    let mut sum = [0.0f32; 3];
    for yy in y * fy..(y + 1) * fy {
        for xx in x * fx..(x + 1) * fx {
            for (s, v) in sum.iter_mut().zip(mean.texel(xx, yy)) {
                *s += v;
            }
        }
    }
    let count = (fx * fy).max(1) as f32;
    sum.map(|s| s / count)
}

/// A smooth random vector field on an n x n UV grid: `count` Gaussian bumps (sigma in
/// texels drawn from `sigma_range`) centred on texels of `support`, each with a random
/// 3-vector amplitude, scaled so the largest magnitude is `max_abs`.
fn bump_field(
    rng: &mut StdRng,
    support: &[usize],
    n: usize,
    count: usize,
    sigma_range: (f32, f32),
    max_abs: f32,
) -> UvMap {
    let mut field = UvMap::zeros(n, n, 3);
    if support.is_empty() {
        return field;
    }
    for _ in 0..count {
        let centre = support[rng.random_range(0..support.len())];
        let (cx, cy) = ((centre % n) as f32, (centre / n) as f32);
        let sigma: f32 = rng.random_range(sigma_range.0..sigma_range.1);
        let amplitude = Vec3::new(
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
            rng.sample(StandardNormal),
        );
        let reach = (3.0 * sigma).ceil() as i64;
        for dy in -reach..=reach {
            for dx in -reach..=reach {
                let (x, y) = (cx as i64 + dx, cy as i64 + dy);
                if x < 0 || y < 0 || x >= n as i64 || y >= n as i64 {
                    continue;
                }
                let g = (-((dx * dx + dy * dy) as f32) / (2.0 * sigma * sigma)).exp();
                let t = (y as usize * n + x as usize) * 3;
                for c in 0..3 {
                    field.data[t + c] += g * amplitude[c];
                }
            }
        }
    }
    let peak = field
        .data
        .chunks_exact(3)
        .map(|v| Vec3::new(v[0], v[1], v[2]).length())
        .fold(0.0f32, f32::max);
    if peak > 0.0 {
        let scale = max_abs / peak;
        field.data.iter_mut().for_each(|v| *v *= scale);
    }
    field
}

/// Keyframes of the performance: (frame fraction, [(ICT name, weight)], yaw, pitch, roll).
type Keyframe = (f32, &'static [(&'static str, f32)], f32, f32, f32);

const KEYFRAMES: [Keyframe; 9] = [
    (0.0, &[], 0.0, 0.0, 0.0),
    (
        0.12,
        &[
            ("mouthSmile_L", 0.9),
            ("mouthSmile_R", 0.9),
            ("cheekSquint_L", 0.4),
            ("cheekSquint_R", 0.4),
        ],
        12.0,
        -3.0,
        2.0,
    ),
    (
        0.25,
        &[
            ("jawOpen", 0.75),
            ("browInnerUp_L", 0.5),
            ("browInnerUp_R", 0.5),
        ],
        4.0,
        4.0,
        0.0,
    ),
    (
        0.37,
        &[("eyeBlink_L", 1.0), ("eyeBlink_R", 1.0)],
        -6.0,
        0.0,
        -2.0,
    ),
    (
        0.5,
        &[
            ("browOuterUp_L", 0.9),
            ("browOuterUp_R", 0.9),
            ("eyeWide_L", 0.6),
            ("eyeWide_R", 0.6),
        ],
        -16.0,
        -5.0,
        -4.0,
    ),
    (0.62, &[("mouthPucker", 0.9)], -8.0, 2.0, 0.0),
    (
        0.75,
        &[
            ("mouthSmile_L", 1.0),
            ("jawOpen", 0.3),
            ("eyeSquint_L", 0.5),
        ],
        10.0,
        6.0,
        5.0,
    ),
    (
        0.87,
        &[
            ("jawOpen", 0.5),
            ("mouthFunnel", 0.6),
            ("browDown_L", 0.6),
            ("browDown_R", 0.6),
        ],
        18.0,
        -2.0,
        3.0,
    ),
    (1.0, &[], 0.0, 0.0, 0.0),
];

fn keyframe_weights(entries: &[(&str, f32)]) -> [f32; NUM_BLENDSHAPES] {
    let mut w = [0.0; NUM_BLENDSHAPES];
    for (name, value) in entries {
        if let Some(i) = face::names::ict_index(name) {
            w[i] = *value;
        }
    }
    w
}

/// The performance: keyframes eased with smoothstep, the face centred at the demo
/// camera's distance for `face_px`, lit by one soft key light.
pub fn demo_motion(
    model: &FaceModel,
    person: &PersonalizedBlendshapes,
    config: &DemoConfig,
) -> DemoMotion {
    let intrinsics = Intrinsics::from_fov(config.width, config.height, config.fov_deg);
    let neutral = person.landmarks(&model.template, &BlendshapeWeights::default());
    let (lo, hi) = neutral.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| {
        (lo.min(*p), hi.max(*p))
    });
    let centre = 0.5 * (lo + hi);
    let distance_cm = intrinsics.focal_px * (hi.y - lo.y) / config.face_px.max(8.0);
    let frames = config.frames.max(1);
    let mut weights = Vec::with_capacity(frames);
    let mut poses = Vec::with_capacity(frames);
    for k in 0..frames {
        let s = if frames == 1 {
            0.0
        } else {
            k as f32 / (frames - 1) as f32
        };
        let next = KEYFRAMES
            .iter()
            .position(|kf| kf.0 >= s)
            .unwrap_or(KEYFRAMES.len() - 1)
            .max(1);
        let (a, b) = (&KEYFRAMES[next - 1], &KEYFRAMES[next]);
        let u = ((s - a.0) / (b.0 - a.0).max(1e-6)).clamp(0.0, 1.0);
        let e = u * u * (3.0 - 2.0 * u);
        let (wa, wb) = (keyframe_weights(a.1), keyframe_weights(b.1));
        weights.push(BlendshapeWeights(std::array::from_fn(|i| {
            wa[i] + (wb[i] - wa[i]) * e
        })));
        let lerp = |x: f32, y: f32| x + (y - x) * e;
        let pose =
            HeadPose::from_degrees(lerp(a.2, b.2), lerp(a.3, b.3), lerp(a.4, b.4), Vec3::ZERO);
        // Keep the face centre on the optical axis at the chosen distance.
        let translation = Vec3::new(0.0, 0.0, -distance_cm) - pose.rotation() * centre;
        poses.push(HeadPose {
            translation,
            ..pose
        });
    }
    let key =
        face::sh::directional_light(Vec3::new(0.35, 0.45, 0.82).normalize(), [0.55, 0.53, 0.5]);
    let ambient = face::sh::constant_light(0.62);
    let gamma = std::array::from_fn(|i| key[i] + ambient[i]);
    DemoMotion {
        weights,
        poses,
        gamma,
    }
}

/// Renders the clip: the person's own blendshapes and albedo (equations 2 and 3 with the
/// true corrections) under the scripted motion, on a flat studio backdrop.
pub fn render_clip(
    scene: &Scene,
    person: &PersonalCorrections,
    personalized: &PersonalizedBlendshapes,
    motion: &DemoMotion,
    config: &DemoConfig,
) -> Result<Vec<RgbImage>> {
    let mesh = mesh_data(&scene.model.template, personalized);
    let textures = texture_layers(&scene.albedo);
    let mut renderer = OffscreenRenderer::new(&mesh, &textures).context(
        "no GPU adapter for rendering the demo (on Debian install mesa-vulkan-drivers for lavapipe)",
    )?;
    let mut frames = Vec::with_capacity(motion.weights.len());
    for k in 0..motion.weights.len() {
        let params = prepare_clip_frame(&mut renderer, scene, person, motion, config, k)?;
        let rgba = renderer.render_image(config.width, config.height, &params)?;
        frames.push(image::DynamicImage::ImageRgba8(rgba).to_rgb8());
    }
    Ok(frames)
}

/// Sets the renderer up for frame `k` of the clip (the person's blendshapes at the frame's
/// weights, equation 3's albedo) and returns the frame's camera and lighting.
fn prepare_clip_frame(
    renderer: &mut OffscreenRenderer,
    scene: &Scene,
    person: &PersonalCorrections,
    motion: &DemoMotion,
    config: &DemoConfig,
    k: usize,
) -> Result<FrameParams> {
    let (Some(weights), Some(pose)) = (motion.weights.get(k), motion.poses.get(k)) else {
        bail!("the demo clip has no frame {k}");
    };
    renderer.face.set_weights(&renderer.queue, &weights.0)?;
    let albedo = scene.model.albedo(scene.albedo.face(), person, weights)?;
    // Only the face layer changes from frame to frame.
    let face_layer = face::albedo::AlbedoLayer::Face.index() as u32;
    renderer
        .face
        .set_albedo_layer(&renderer.queue, face_layer, &rgba8_texels(&albedo))?;
    let intrinsics = Intrinsics::from_fov(config.width, config.height, config.fov_deg);
    let mut params = FrameParams::new(Camera {
        view_from_model: pose.view_from_model(),
        clip_from_view: intrinsics.clip_from_view(1.0, 1000.0),
    });
    params.view = ViewMode::Shaded;
    params.sh_coefficients = motion.gamma;
    params.background = [0.32, 0.34, 0.37, 1.0];
    Ok(params)
}

/// Frames already in memory as a [`FrameSource`].
pub struct MemoryFrames {
    frames: std::vec::IntoIter<RgbImage>,
    next_index: usize,
    len: usize,
    fps: f64,
}

impl MemoryFrames {
    pub fn new(frames: Vec<RgbImage>, fps: f64) -> Self {
        Self {
            len: frames.len(),
            frames: frames.into_iter(),
            next_index: 0,
            fps,
        }
    }
}

impl FrameSource for MemoryFrames {
    fn next_frame(&mut self) -> tracking::Result<Next> {
        Ok(match self.frames.next() {
            Some(image) => {
                let index = self.next_index;
                self.next_index += 1;
                Next::Frame(Frame {
                    index,
                    time_s: index as f64 / self.fps,
                    image,
                    path: None,
                })
            }
            None => Next::End,
        })
    }
    fn len_hint(&self) -> Option<usize> {
        Some(self.len)
    }
    fn fps(&self) -> f64 {
        self.fps
    }
    fn describe(&self) -> String {
        "built-in demo".into()
    }
}

/// The demo after the real pipeline ran on it.
pub struct DemoSession {
    pub config: DemoConfig,
    pub frames: Vec<RgbImage>,
    pub motion: DemoMotion,
    /// The person's true corrections and the blendshapes they make.
    pub truth: PersonalCorrections,
    pub truth_blendshapes: PersonalizedBlendshapes,
    /// What ModelNet learned from `selected_frames`, and the blendshapes it makes.
    pub learned: PersonalCorrections,
    pub learned_blendshapes: Arc<PersonalizedBlendshapes>,
    pub selected_frames: Vec<usize>,
    /// Per frame: TrackNet, landmarks and the template-based record.
    pub outputs: Vec<FrameOutput>,
    /// Per frame: tracked again with the learned blendshapes (what the puppet follows).
    pub records: Vec<FrameRecord>,
    pub intrinsics: Intrinsics,
}

/// Makes the demo: person, clip, tracking, personalization, re-tracking. `progress` is
/// told what is happening (for a splash screen or log).
pub fn build_demo(
    scene: &Scene,
    face: Arc<FaceModel>,
    config: DemoConfig,
    mut progress: impl FnMut(&str),
) -> Result<DemoSession> {
    progress("making a synthetic person");
    let truth = synthetic_person(&scene.model, scene.albedo.face(), config.seed);
    let truth_blendshapes = scene.model.personalize(&truth)?;
    let motion = demo_motion(&scene.model, &truth_blendshapes, &config);
    progress("rendering the demo clip");
    let frames = render_clip(scene, &truth, &truth_blendshapes, &motion, &config)?;
    progress("tracking");
    let tracker_config = TrackerConfig {
        threads: 1,
        fov_deg: Some(config.fov_deg),
        ..TrackerConfig::default()
    };
    let mut tracker = Tracker::new(face.clone(), tracker_config, true)
        .context("the demo tracks its clip like footage")?;
    let mut outputs = Vec::with_capacity(frames.len());
    let mut kept_frames = Vec::with_capacity(frames.len());
    tracker.track_source(&mut MemoryFrames::new(frames, config.fps), |event| {
        if let TrackEvent::Frame(frame, out) = event {
            kept_frames.push(frame.image);
            outputs.push(*out);
        }
        std::ops::ControlFlow::Continue(())
    })?;
    let with_face = outputs.iter().filter(|o| o.record.face).count();
    if with_face == 0 {
        bail!("the tracker found no face in the demo clip");
    }
    progress("personalizing (ModelNet)");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut model_net =
        tracking::networks::ModelNet::load(&tracker.manifest, tracker.backend(), cores)?;
    let (learned, picked) =
        tracking::personalize::personalize(&mut model_net, &outputs, config.personalize_frames)?;
    let learned_blendshapes = Arc::new(face.personalize(&learned)?);
    tracker.set_blendshapes(learned_blendshapes.clone())?;
    tracker.reset();
    let records = outputs
        .iter()
        .map(|o| tracker.retrack(o, config.width, config.height))
        .collect();
    let selected_frames = picked.iter().map(|&i| outputs[i].record.index).collect();
    Ok(DemoSession {
        intrinsics: tracker.intrinsics(config.width, config.height),
        config,
        frames: kept_frames,
        motion,
        truth,
        truth_blendshapes,
        learned,
        learned_blendshapes,
        selected_frames,
        outputs,
        records,
    })
}

/// Mean distance in pixels between the true 68 landmarks of each frame and `points`
/// (per frame), over the frames where both exist, divided by the face height: the same
/// normalised error the tracking evaluation reports.
pub fn landmark_nme(
    model: &FaceModel,
    session: &DemoSession,
    points: impl Fn(usize) -> Option<Vec<Vec2>>,
) -> Option<f32> {
    let mut total = 0.0;
    let mut count = 0usize;
    for (k, (w, pose)) in session
        .motion
        .weights
        .iter()
        .zip(&session.motion.poses)
        .enumerate()
    {
        let Some(found) = points(k) else { continue };
        let truth: Vec<Vec2> = session
            .truth_blendshapes
            .landmarks(&model.template, w)
            .iter()
            .filter_map(|p| session.intrinsics.project(pose.transform(*p)))
            .collect();
        if truth.len() != found.len() {
            continue;
        }
        let (lo, hi) = truth.iter().fold((Vec2::MAX, Vec2::MIN), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
        let size = ((hi.x - lo.x) * (hi.y - lo.y)).sqrt().max(1.0);
        let error: f32 = truth
            .iter()
            .zip(&found)
            .map(|(a, b)| a.distance(*b))
            .sum::<f32>()
            / truth.len() as f32;
        total += error / size;
        count += 1;
    }
    (count > 0).then(|| total / count as f32)
}

/// [`build_demo`] in steps on the caller's thread, for the browser (no threads, and GPU
/// readbacks that arrive between event-loop turns): [`SteppedDemo::step`] is called once per
/// UI frame and does a slice of the work (render a clip frame, track a frame, ModelNet).
pub struct SteppedDemo {
    config: DemoConfig,
    scene: Arc<Scene>,
    face: Arc<FaceModel>,
    networks: Arc<tracking::bundle::NetworkBytes>,
    truth: PersonalCorrections,
    truth_blendshapes: PersonalizedBlendshapes,
    motion: DemoMotion,
    renderer: Option<OffscreenRenderer>,
    /// Clip frames rendered so far, and whether the next one is being read back.
    rendered: Vec<RgbImage>,
    in_flight: bool,
    tracking: Option<crate::stepped::SteppedTracking>,
    pub progress: crate::footage::Progress,
    /// Locates faces in the clip beside this thread (the browser's worker), if set before
    /// tracking starts.
    pub remote_locator: Option<Box<dyn crate::stepped::RemoteFaceLocator>>,
}

impl SteppedDemo {
    /// Makes the person and the performance, and readies `renderer` (made on the studio's
    /// device with the person's mesh, [`mesh_data`]) to film them.
    pub fn new(
        scene: Arc<Scene>,
        networks: Arc<tracking::bundle::NetworkBytes>,
        config: DemoConfig,
        make_renderer: impl FnOnce(&MeshData, &TextureLayers) -> Result<OffscreenRenderer>,
    ) -> Result<Self> {
        let truth = synthetic_person(&scene.model, scene.albedo.face(), config.seed);
        let truth_blendshapes = scene.model.personalize(&truth)?;
        let motion = demo_motion(&scene.model, &truth_blendshapes, &config);
        let mesh = mesh_data(&scene.model.template, &truth_blendshapes);
        let textures = texture_layers(&scene.albedo);
        let renderer = make_renderer(&mesh, &textures)?;
        let face = Arc::new(FaceModel::new(scene.model.template.clone()));
        Ok(Self {
            progress: crate::footage::Progress {
                stage: "rendering the demo clip",
                done: 0,
                total: Some(config.frames),
            },
            config,
            scene,
            face,
            networks,
            truth,
            truth_blendshapes,
            motion,
            renderer: Some(renderer),
            rendered: Vec::new(),
            in_flight: false,
            tracking: None,
            remote_locator: None,
        })
    }

    /// Works until `budget` is spent or the GPU is awaited; `Some` once, at the end, with
    /// the demo session and the rate the clip was tracked at.
    pub fn step(
        &mut self,
        budget: web_time::Duration,
    ) -> Option<Result<(DemoSession, crate::stepped::TrackingRate)>> {
        let started = web_time::Instant::now();
        if let Some(tracking) = &mut self.tracking {
            let result = tracking.step(budget);
            self.progress = tracking.progress.clone();
            return result.map(|r| {
                r.map_err(|e| anyhow::anyhow!("the demo clip: {e}"))
                    .map(|tracked| self.finish(tracked))
            });
        }
        while started.elapsed() < budget {
            match self.render_step() {
                Ok(true) => {}
                Ok(false) => return None,
                Err(e) => return Some(Err(e)),
            }
            if self.rendered.len() == self.motion.weights.len() {
                return match self.start_tracking() {
                    Ok(()) => None,
                    Err(e) => Some(Err(e)),
                };
            }
        }
        None
    }

    /// Begins or collects one clip frame; `false` while the GPU is still on it.
    fn render_step(&mut self) -> Result<bool> {
        let Some(renderer) = self.renderer.as_mut() else {
            bail!("the demo renderer is gone");
        };
        if !self.in_flight {
            let k = self.rendered.len();
            let params = prepare_clip_frame(
                renderer,
                &self.scene,
                &self.truth,
                &self.motion,
                &self.config,
                k,
            )?;
            renderer.begin_image(self.config.width, self.config.height, &params)?;
            self.in_flight = true;
        }
        match renderer.poll_image() {
            None => Ok(false),
            Some(rgba) => {
                self.in_flight = false;
                self.rendered
                    .push(image::DynamicImage::ImageRgba8(rgba?).to_rgb8());
                self.progress.done = self.rendered.len();
                Ok(true)
            }
        }
    }

    fn start_tracking(&mut self) -> Result<()> {
        // The renderer's textures are the clip's only; the studio draws with its own.
        self.renderer = None;
        let config = TrackerConfig {
            threads: 1,
            fov_deg: Some(self.config.fov_deg),
            ..TrackerConfig::default()
        };
        let tracker = self
            .networks
            .tracker(self.face.clone(), config, true)
            .context("the demo tracks its clip like footage")?;
        let model_net = self.networks.model_net()?;
        let frames = std::mem::take(&mut self.rendered);
        let tracking = crate::stepped::SteppedTracking::new(
            self.face.clone(),
            tracker,
            model_net,
            crate::stepped::FrameFeed::clip(frames, self.config.fps),
            usize::MAX,
            self.config.personalize_frames,
        )
        .with_remote_locator(self.remote_locator.take());
        self.progress = tracking.progress.clone();
        self.tracking = Some(tracking);
        Ok(())
    }

    fn finish(
        &mut self,
        tracked: crate::stepped::Tracked,
    ) -> (DemoSession, crate::stepped::TrackingRate) {
        let selected_frames = tracked
            .selected_frames
            .iter()
            .map(|&i| tracked.outputs[i].record.index)
            .collect();
        let session = DemoSession {
            config: self.config.clone(),
            frames: tracked.frames,
            motion: self.motion.clone(),
            truth: self.truth.clone(),
            truth_blendshapes: self.truth_blendshapes.clone(),
            learned: tracked.corrections,
            learned_blendshapes: tracked.blendshapes,
            selected_frames,
            outputs: tracked.outputs,
            records: tracked.records,
            intrinsics: tracked.intrinsics,
        };
        (session, tracked.rate)
    }
}
