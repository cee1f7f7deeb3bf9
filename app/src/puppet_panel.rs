//! The puppet panel: the tracked performance retargeted live onto a glTF/VRM puppet (or onto
//! another person's personalized model), beside the input frame, with the mapping editor
//! (gain, offset, clamp, curve, invert, neutral calibration) and the exports (glTF
//! animation, Live Link Face CSV, the personalized rig).
//!
//! The mapping's meaning belongs to `retarget::mapping`; this module only edits a
//! [`MappingData`] and recompiles the [`Retargeter`] after every change, so the preview and
//! the exports always use the same response the CLI would.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Context, Result, bail};
use face::names::{ARKIT_NAMES, NUM_ARKIT, ict_to_arkit};
use face::{PersonalCorrections, PersonalizedBlendshapes};
use files::write_atomically;
use renderer::{FaceRenderer, FrameParams};
use retarget::export::{live_link_csv, retarget_clip, write_animation_glb};
use retarget::mapping::{ChannelMapping, Source, sidecar_path};
use retarget::rig::{PersonalizedRig, rig_glb_bytes};
use retarget::{MappingData, Puppet, PuppetPose, Retargeter};

use crate::gpu_view::{
    VIEW_FORMAT, ViewTarget, available_pixels, interactive_options, person_renderer,
    upload_person_albedo,
};
use crate::puppet_view::PuppetView;
use crate::scene::{Orbit, Scene, StudioView, frame_params};
use crate::studio_panels::{fit_rect, list_rows};
use crate::studio_session::StudioSession;

/// The project's demo puppet (made by `retarget::generator`, shipped in `assets/puppets`).
pub const DEMO_PUPPET: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/puppets/pip.glb");

/// A puppet with its mapping, compiled.
pub struct LoadedPuppet {
    pub path: PathBuf,
    pub puppet: Puppet,
    pub view: PuppetView,
    pub mapping: MappingData,
    pub retargeter: Retargeter,
    /// The file's bytes when it came without a path (the browser), for the animation
    /// export, which writes the puppet again with its animation.
    pub bytes: Option<Arc<[u8]>>,
}

impl LoadedPuppet {
    /// Reads a puppet and its mapping sidecar (`hero.mapping.json`, if any).
    pub fn load(path: &Path) -> Result<Self> {
        let puppet = Puppet::load(path)?;
        let mapping = MappingData::load_for_puppet(path)?;
        Self::with_mapping(path, puppet, mapping)
    }

    /// A puppet from a file's bytes (dropped in the browser), which cannot have an external
    /// buffer or a mapping sidecar beside it: the default mapping applies.
    pub fn from_bytes(name: &str, bytes: &[u8]) -> Result<Self> {
        let path = Path::new(name);
        let puppet = Puppet::from_slice(bytes, path, None)?;
        let mut loaded = Self::with_mapping(path, puppet, MappingData::default())?;
        loaded.bytes = Some(Arc::from(bytes));
        Ok(loaded)
    }

    fn with_mapping(path: &Path, puppet: Puppet, mapping: MappingData) -> Result<Self> {
        let view = PuppetView::new(&puppet)?;
        let retargeter = Retargeter::new(&puppet, &mapping);
        if !retargeter.report.drives_anything() && retargeter.head_node().is_none() {
            bail!(
                "{}: none of its {} morph targets matches an ARKit channel or a VRM expression, \
                 and it has no head node; write a mapping file ({}) naming the targets",
                path.display(),
                puppet.morph_target_count(),
                sidecar_path(path).display()
            );
        }
        Ok(Self {
            path: path.to_owned(),
            puppet,
            view,
            mapping,
            retargeter,
            bytes: None,
        })
    }

    /// Recompiles the retargeter after the mapping changed.
    pub fn mapping_changed(&mut self) {
        self.retargeter = Retargeter::new(&self.puppet, &self.mapping);
    }

    /// The index in `view`'s blendshapes of the morph target called `name` (any mesh).
    pub fn shape_index(&self, name: &str) -> Option<usize> {
        self.view.shapes.iter().position(|&(m, t)| {
            self.puppet.meshes[m]
                .target_names
                .get(t)
                .is_some_and(|n| n == name)
        })
    }

    /// The sidecar entry editing ARKit channel `a` changes: the first one for that source,
    /// created as the identity response when there is none.
    pub fn entry_mut(&mut self, a: usize) -> &mut ChannelMapping {
        let position = self
            .mapping
            .channels
            .iter()
            .position(|c| Source::parse(&c.source) == Some(Source::Arkit(a)));
        let k = match position {
            Some(k) => k,
            None => {
                self.mapping
                    .channels
                    .push(ChannelMapping::identity(ARKIT_NAMES[a]));
                self.mapping.channels.len() - 1
            }
        };
        &mut self.mapping.channels[k]
    }

    /// The entry for ARKit channel `a`, if the sidecar has one.
    pub fn entry(&self, a: usize) -> Option<&ChannelMapping> {
        self.mapping
            .channels
            .iter()
            .find(|c| Source::parse(&c.source) == Some(Source::Arkit(a)))
    }

    /// What ARKit channel `a` drives, as the mapping report names it.
    pub fn targets_of(&self, a: usize) -> Option<&[String]> {
        self.retargeter
            .report
            .mapped
            .iter()
            .find(|(source, _)| source == ARKIT_NAMES[a])
            .map(|(_, targets)| targets.as_slice())
    }

    /// The response of channel `a` to tracked ARKit weights: (calibrated input, output of
    /// its first link), `None` when it drives nothing.
    pub fn channel_response(&self, a: usize, arkit: &[f32; NUM_ARKIT]) -> (f32, Option<f32>) {
        let calibrated = self.retargeter.calibrated(arkit)[a];
        let output = self
            .retargeter
            .links
            .iter()
            .find(|l| l.source == Source::Arkit(a))
            .map(|l| l.response.respond(calibrated));
        (calibrated, output)
    }
}

/// What the tracked performance drives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DriveTarget {
    Puppet,
    /// Another person's personalized blendshapes and dynamic albedo (the paper's
    /// retargeting to a different user).
    Person,
}

/// Another person's personalized model.
pub struct PersonTarget {
    pub name: String,
    pub corrections: PersonalCorrections,
    pub blendshapes: Arc<PersonalizedBlendshapes>,
}

impl PersonTarget {
    /// A second synthetic person (another seed of the demo's generator): their true
    /// corrections, as a perfect ModelNet would learn them from their own footage.
    pub fn synthetic(scene: &Scene, seed: u64) -> Result<Self> {
        let corrections = crate::demo::synthetic_person(&scene.model, scene.albedo.face(), seed);
        let blendshapes = Arc::new(scene.model.personalize(&corrections)?);
        Ok(Self {
            name: format!("synthetic person B (seed {seed})"),
            corrections,
            blendshapes,
        })
    }

    /// The person of a studio session (what ModelNet learned from their footage).
    pub fn from_session(session: &StudioSession) -> Self {
        Self {
            name: session.source.clone(),
            corrections: session.corrections.clone(),
            blendshapes: session.blendshapes.clone(),
        }
    }
}

/// An export asked for by a button.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ExportRequest {
    pub kind: ExportKind,
    /// The button's label, which error messages start with.
    pub label: &'static str,
    pub dir: PathBuf,
}

/// The files the export buttons write.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportKind {
    /// The puppet with the clip as a glTF animation.
    Animation,
    /// Live Link Face CSV after the mapping's neutral calibration.
    LiveLinkCsv,
    /// The tracked person's personalized rig (blendshapes and dynamic albedo) as GLB.
    PersonalizedRig,
}

impl ExportKind {
    pub fn file_name(self, puppet: Option<&Path>) -> String {
        match self {
            ExportKind::Animation => {
                let stem = puppet
                    .and_then(|p| p.file_stem())
                    .map_or("puppet".into(), |s| s.to_string_lossy().into_owned());
                format!("{stem}_animation.glb")
            }
            ExportKind::LiveLinkCsv => "live_link_face.csv".into(),
            ExportKind::PersonalizedRig => "personalized_rig.glb".into(),
        }
    }
}

struct PuppetGpu {
    /// Which puppet it was built for (`PuppetPanel::generation`).
    generation: u64,
    face: FaceRenderer,
}

struct PersonGpu {
    /// The person's `Arc` address.
    person: usize,
    face: FaceRenderer,
    /// The frame whose blended albedo is uploaded (equation (3) is evaluated on the CPU).
    albedo_frame: Option<usize>,
}

pub struct PuppetPanel {
    pub puppet: Option<LoadedPuppet>,
    pub person: Option<Arc<PersonTarget>>,
    pub drive: DriveTarget,
    /// The ARKit channel the editor shows.
    pub selected_channel: usize,
    pub filter: String,
    /// Turns the preview around the puppet, degrees.
    pub orbit_yaw_deg: f32,
    /// Where the export buttons write.
    pub export_dir: String,
    /// The last success message (an export, a save).
    pub status: Option<String>,
    /// An export button was pressed this frame; the studio starts it in the background
    /// ([`Self::export_job`]) and reports its end in `status`.
    pub requested_export: Option<ExportRequest>,
    /// The puppet's renderer weights of the last frame shown (tests read them).
    pub shown_weights: Vec<f32>,
    pub shown_pose: Option<PuppetPose>,
    /// The fraction of the view's size the 3D view is rendered at (shown scaled to fill
    /// it); the studio sets it each frame from [`crate::gpu_view::view_render_scale`].
    pub render_scale: f32,
    generation: u64,
    tried_demo_puppet: bool,
    /// The demo puppet's bytes where there are no files (the browser fetches them).
    pub demo_puppet_bytes: Option<crate::web_host::PickedFile>,
    /// "Open puppet..." was clicked where the studio, not a native dialog, picks files.
    pub pick_requested: bool,
    dragging_point: Option<usize>,
    gpu: Option<PuppetGpu>,
    person_gpu: Option<PersonGpu>,
    pub(crate) target: ViewTarget,
}

impl Default for PuppetPanel {
    fn default() -> Self {
        Self {
            puppet: None,
            person: None,
            drive: DriveTarget::Puppet,
            selected_channel: face::names::arkit_index("jawOpen").unwrap_or(0),
            filter: String::new(),
            orbit_yaw_deg: 0.0,
            export_dir: "likeness-export".into(),
            status: None,
            requested_export: None,
            shown_weights: Vec::new(),
            shown_pose: None,
            render_scale: 1.0,
            generation: 0,
            tried_demo_puppet: false,
            demo_puppet_bytes: None,
            pick_requested: false,
            dragging_point: None,
            gpu: None,
            person_gpu: None,
            target: ViewTarget::default(),
        }
    }
}

/// The tracked ARKit weights of frame `k`.
pub fn frame_arkit(session: &StudioSession, k: usize) -> [f32; NUM_ARKIT] {
    ict_to_arkit(&session.weights(k).0)
}

impl PuppetPanel {
    /// Loads a puppet (replacing the current one on success; on failure the current one
    /// stays).
    pub fn load(&mut self, path: &Path) -> Result<()> {
        self.show_loaded(LoadedPuppet::load(path)?, path);
        Ok(())
    }

    /// [`PuppetPanel::load`] from a file's bytes (the browser's drops and downloads).
    pub fn load_bytes(&mut self, name: &str, bytes: &[u8]) -> Result<()> {
        self.show_loaded(LoadedPuppet::from_bytes(name, bytes)?, Path::new(name));
        Ok(())
    }

    fn show_loaded(&mut self, loaded: LoadedPuppet, path: &Path) {
        self.puppet = Some(loaded);
        self.generation += 1;
        self.drive = DriveTarget::Puppet;
        // The file name only: the full path is in the header's hover text, and the panel
        // must look the same wherever the project is checked out.
        let name = path.file_name().unwrap_or(path.as_os_str());
        self.status = Some(format!("loaded {}", name.to_string_lossy()));
    }

    /// Drives person B: the one already chosen, else a second synthetic person (the demo
    /// generator's next seed).
    pub fn drive_person_b(&mut self, scene: &Scene) -> Result<()> {
        if self.person.is_none() {
            let seed = crate::demo::DemoConfig::default().seed + 1;
            self.person = Some(Arc::new(PersonTarget::synthetic(scene, seed)?));
        }
        self.drive = DriveTarget::Person;
        Ok(())
    }

    /// Loads the demo puppet the first time the panel is shown without one.
    pub fn ensure_demo_puppet(&mut self) -> Result<()> {
        if self.puppet.is_some() || self.tried_demo_puppet {
            return Ok(());
        }
        self.tried_demo_puppet = true;
        // The demo puppet arrives in the background: person B, if driven, stays driven.
        let drive = self.drive;
        let loaded = match self.demo_puppet_bytes.take() {
            // The browser fetched it from the served directory.
            Some(file) => self.load_bytes(&file.name, &file.bytes),
            None => self.load(Path::new(DEMO_PUPPET)),
        }
        .context(
            "the demo puppet (assets/puppets/pip.glb; `likeness generate-puppets` remakes it)",
        );
        self.drive = drive;
        loaded
    }

    /// The export of `kind` into `dir` as a job for a background thread: it owns a copy of
    /// the puppet and its mapping as they are now (later edits do not change it) and
    /// returns the file written.
    pub fn export_job(
        &self,
        kind: ExportKind,
        scene: Arc<Scene>,
        session: Arc<StudioSession>,
        dir: PathBuf,
    ) -> impl FnOnce() -> Result<PathBuf> + Send + 'static {
        let puppet = self
            .puppet
            .as_ref()
            .map(|p| (p.path.clone(), p.puppet.clone(), p.retargeter.clone()));
        move || export(kind, puppet, &scene, &session, &dir)
    }

    /// The channel list: each ARKit channel with its calibrated input and the puppet's
    /// response at the current frame; clicking selects it for the editor.
    pub fn channels_ui(&mut self, ui: &mut egui::Ui, session: &StudioSession, frame: usize) {
        ui.horizontal(|ui| {
            let label = ui.label("Search");
            ui.text_edit_singleline(&mut self.filter)
                .labelled_by(label.id);
        });
        ui.label("Channel: tracked input -> puppet");
        ui.separator();
        let arkit = frame_arkit(session, frame);
        let filter = self.filter.trim().to_ascii_lowercase();
        let listed: Vec<usize> = (0..NUM_ARKIT)
            .filter(|&a| filter.is_empty() || ARKIT_NAMES[a].to_ascii_lowercase().contains(&filter))
            .collect();
        list_rows(ui, listed.len(), |ui, row| {
            let a = listed[row];
            let name = ARKIT_NAMES[a];
            let (input, output) = match self.puppet.as_ref() {
                Some(p) => p.channel_response(a, &arkit),
                None => (arkit[a], None),
            };
            ui.horizontal(|ui| {
                value_bar(ui, input, egui::Color32::from_rgb(90, 160, 230));
                value_bar(
                    ui,
                    output.unwrap_or(0.0),
                    egui::Color32::from_rgb(230, 150, 60),
                );
                let text = match output {
                    Some(o) => format!("{name}  {input:.2} -> {o:.2}"),
                    None => format!("{name}  {input:.2} (drives nothing)"),
                };
                if ui
                    .selectable_label(self.selected_channel == a, text)
                    .clicked()
                {
                    self.selected_channel = a;
                }
            });
        });
    }

    /// The input frame beside the puppet (or person B), the mapping editor and exports.
    /// Returns an error message for the studio's notices (toasts).
    #[allow(clippy::too_many_arguments)]
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        rs: Option<&egui_wgpu::RenderState>,
        scene: &Scene,
        session: &Arc<StudioSession>,
        frame: usize,
        input: Option<(egui::TextureId, [u32; 2])>,
    ) -> Option<String> {
        let mut error = None;
        if let Err(e) = self.ensure_demo_puppet() {
            error = Some(format!("{e:#}"));
        }
        self.header_ui(ui, scene, &mut error);
        let editor_height = 250.0;
        let size = available_pixels(ui);
        let view_height = (size[1] as f32 - editor_height).max(64.0);
        let half = ((size[0] as f32 - ui.spacing().item_spacing.x) / 2.0).max(16.0);
        ui.horizontal(|ui| {
            // The input frame, fitted into the left half.
            let (rect, _) =
                ui.allocate_exact_size(egui::vec2(half, view_height), egui::Sense::hover());
            let picture = input.map(|(id, frame_size)| (id, fit_rect(rect, frame_size)));
            let shown = picture.map_or(egui::Rect::NOTHING, |(_, r)| r);
            for bar in crate::studio_panels::letterbox_bars(rect, shown) {
                ui.painter()
                    .rect_filled(bar, 0.0, ui.visuals().extreme_bg_color);
            }
            if let Some((id, picture_rect)) = picture {
                ui.painter().image(
                    id,
                    picture_rect,
                    egui::Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
                    egui::Color32::WHITE,
                );
            }
            let view_size = crate::gpu_view::scaled_pixels([half, view_height], self.render_scale);
            match rs.map(|rs| self.render(rs, scene, session, frame, view_size)) {
                Some(Ok(Some(id))) => {
                    let response = ui.add(
                        egui::Image::new((id, egui::vec2(half, view_height)))
                            .sense(egui::Sense::drag()),
                    );
                    if response.dragged() {
                        self.orbit_yaw_deg = (self.orbit_yaw_deg + response.drag_delta().x * 0.4)
                            .clamp(-180.0, 180.0);
                    }
                }
                Some(Ok(None)) => {
                    ui.label("No puppet loaded");
                }
                Some(Err(e)) => error = Some(e),
                None => {
                    ui.label("No 3D view: eframe is not running on wgpu");
                }
            }
        });
        ui.separator();
        ui.horizontal_top(|ui| {
            ui.vertical(|ui| {
                ui.set_width(ui.available_width() * 0.62);
                self.editor_ui(ui, session, frame, &mut error);
            });
            ui.separator();
            ui.vertical(|ui| self.export_ui(ui));
        });
        error
    }

    fn header_ui(&mut self, ui: &mut egui::Ui, scene: &Scene, error: &mut Option<String>) {
        ui.horizontal_wrapped(|ui| {
            ui.label("Drive");
            ui.selectable_value(&mut self.drive, DriveTarget::Puppet, "Puppet");
            if ui
                .selectable_label(self.drive == DriveTarget::Person, "Person B")
                .on_hover_text("Drive another person's own blendshapes and dynamic albedo")
                .clicked()
                && let Err(e) = self.drive_person_b(scene)
            {
                *error = Some(format!("person B: {e:#}"));
            }
            ui.separator();
            match (self.drive, self.puppet.as_ref(), self.person.as_ref()) {
                (DriveTarget::Person, _, Some(p)) => {
                    ui.label(&p.name);
                }
                (_, Some(p), _) => {
                    ui.label(p.path.file_name().map_or_else(
                        || p.path.display().to_string(),
                        |n| n.to_string_lossy().into_owned(),
                    ))
                    .on_hover_text(p.path.display().to_string());
                }
                _ => {
                    ui.label("no puppet");
                }
            }
            #[cfg(not(target_arch = "wasm32"))]
            if ui.button("Open puppet...").clicked()
                && let Some(path) = rfd::FileDialog::new()
                    .add_filter("glTF / VRM", &["glb", "gltf", "vrm"])
                    .pick_file()
                && let Err(e) = self.load(&path)
            {
                *error = Some(format!("{e:#}"));
            }
            #[cfg(target_arch = "wasm32")]
            if ui.button("Open puppet...").clicked() {
                // The studio's file picker: a chosen puppet comes back as picked bytes.
                self.pick_requested = true;
            }
            ui.separator();
            ui.add(egui::Slider::new(&mut self.orbit_yaw_deg, -180.0..=180.0).text("Turn"));
        });
    }

    /// Renders the driven character for frame `frame`; `None` when there is nothing to draw.
    fn render(
        &mut self,
        rs: &egui_wgpu::RenderState,
        scene: &Scene,
        session: &StudioSession,
        frame: usize,
        size: [u32; 2],
    ) -> Result<Option<egui::TextureId>, String> {
        let weights = session.weights(frame);
        let rotation = session.rotation_deg(frame);
        let id = match (self.drive, self.person.clone()) {
            (DriveTarget::Person, Some(person)) => {
                let key = Arc::as_ptr(&person) as usize;
                if self.person_gpu.as_ref().is_none_or(|g| g.person != key) {
                    let face = person_renderer(rs, scene, &person.blendshapes, "person B view")?;
                    self.person_gpu = Some(PersonGpu {
                        person: key,
                        face,
                        albedo_frame: None,
                    });
                }
                let Some(gpu) = self.person_gpu.as_mut() else {
                    return Ok(None);
                };
                gpu.face
                    .set_weights(&rs.queue, &weights.0)
                    .map_err(|e| e.to_string())?;
                if gpu.albedo_frame != Some(frame) {
                    // Person B's own dynamic albedo under person A's weights (equation 3).
                    upload_person_albedo(rs, &mut gpu.face, scene, &person.corrections, &weights)
                        .map_err(|e| format!("person B: {e}"))?;
                    gpu.albedo_frame = Some(frame);
                }
                let orbit = Orbit {
                    yaw_deg: self.orbit_yaw_deg,
                    ..Orbit::default()
                };
                let mut params: FrameParams =
                    frame_params(StudioView::Shaded, &orbit, size[0], size[1]);
                params.camera = orbit.camera_with_head(rotation, size[0], size[1]);
                self.shown_weights = weights.0.to_vec();
                self.shown_pose = None;
                self.target
                    .render(rs, &gpu.face, size, &params, "person B view")
            }
            _ => {
                let Some(p) = self.puppet.as_ref() else {
                    return Ok(None);
                };
                if self
                    .gpu
                    .as_ref()
                    .is_none_or(|g| g.generation != self.generation)
                {
                    let face = FaceRenderer::with_options(
                        &rs.device,
                        &rs.queue,
                        VIEW_FORMAT,
                        renderer::RenderOptions {
                            cull_back_faces: p.view.cull_back_faces,
                            ..interactive_options(rs)
                        },
                        &p.view.mesh,
                        &p.view.textures,
                    )
                    .map_err(|e| format!("puppet view unavailable: {e}"))?;
                    self.gpu = Some(PuppetGpu {
                        generation: self.generation,
                        face,
                    });
                }
                let Some(gpu) = self.gpu.as_mut() else {
                    return Ok(None);
                };
                let pose = p.retargeter.pose(&ict_to_arkit(&weights.0), Some(rotation));
                let shape_weights = p.view.weights(&pose);
                gpu.face
                    .set_weights(&rs.queue, &shape_weights)
                    .map_err(|e| e.to_string())?;
                let mut params =
                    FrameParams::new(p.view.camera(&pose, self.orbit_yaw_deg, size[0], size[1]));
                params.sh_coefficients = face::sh::studio_light();
                params.background = [0.11, 0.12, 0.14, 1.0];
                self.shown_weights = shape_weights;
                self.shown_pose = Some(pose);
                self.target
                    .render(rs, &gpu.face, size, &params, "puppet view")
            }
        };
        Ok(Some(id))
    }

    /// Gain, offset, clamp, invert and curve of the selected channel, neutral calibration
    /// and saving the sidecar.
    fn editor_ui(
        &mut self,
        ui: &mut egui::Ui,
        session: &StudioSession,
        frame: usize,
        error: &mut Option<String>,
    ) {
        let a = self.selected_channel.min(NUM_ARKIT - 1);
        let arkit = frame_arkit(session, frame);
        let Some(p) = self.puppet.as_mut() else {
            ui.label("Load a puppet to edit its mapping");
            return;
        };
        if self.drive == DriveTarget::Person {
            ui.label("Person B follows the tracked weights one to one; the mapping applies to the puppet");
        }
        ui.horizontal(|ui| {
            ui.strong(ARKIT_NAMES[a]);
            match p.targets_of(a) {
                Some(targets) => ui.label(format!("-> {}", targets.join(", "))),
                None => ui.label("drives nothing in this puppet"),
            };
        });
        let (input, output) = p.channel_response(a, &arkit);
        ui.label(format!(
            "this frame: tracked {:.3}, calibrated {input:.3}, puppet {}",
            arkit[a],
            output.map_or("-".into(), |o| format!("{o:.3}"))
        ));
        let mut changed = false;
        let mut entry = p
            .entry(a)
            .cloned()
            .unwrap_or_else(|| ChannelMapping::identity(ARKIT_NAMES[a]));
        ui.horizontal_top(|ui| {
            ui.vertical(|ui| {
                changed |= ui
                    .add(egui::Slider::new(&mut entry.gain, 0.0..=3.0).text("Gain"))
                    .changed();
                changed |= ui
                    .add(egui::Slider::new(&mut entry.offset, -1.0..=1.0).text("Offset"))
                    .changed();
                let [mut lo, mut hi] = entry.clamp;
                changed |= ui
                    .add(egui::Slider::new(&mut lo, -1.0..=1.0).text("Clamp low"))
                    .changed();
                changed |= ui
                    .add(egui::Slider::new(&mut hi, 0.0..=2.0).text("Clamp high"))
                    .changed();
                entry.clamp = [lo.min(hi), hi.max(lo)];
                changed |= ui.checkbox(&mut entry.invert, "Invert").changed();
                ui.horizontal(|ui| {
                    if ui
                        .button("Reset channel")
                        .on_hover_text("Back to the automatic identity response")
                        .clicked()
                    {
                        p.mapping
                            .channels
                            .retain(|c| Source::parse(&c.source) != Some(Source::Arkit(a)));
                        p.mapping_changed();
                    }
                    if ui.button("Reset curve").clicked() {
                        entry.curve.clear();
                        changed = true;
                    }
                });
            });
            changed |= curve_ui(ui, &mut entry, input, &mut self.dragging_point);
        });
        if changed {
            *p.entry_mut(a) = entry;
            p.mapping_changed();
        }
        ui.horizontal_wrapped(|ui| {
            if ui
                .button("Calibrate neutral")
                .on_hover_text("Record this frame's tracked weights as the performer's rest pose")
                .clicked()
            {
                p.mapping.calibrate_neutral(&arkit);
                p.mapping_changed();
            }
            if ui.button("Clear neutral").clicked() {
                p.mapping.neutral.clear();
                p.mapping_changed();
            }
            if ui
                .button("Save mapping")
                .on_hover_text(sidecar_path(&p.path).display().to_string())
                .clicked()
            {
                let path = sidecar_path(&p.path);
                match p.mapping.save(&path) {
                    Ok(()) => self.status = Some(format!("saved {}", path.display())),
                    Err(e) => *error = Some(e.to_string()),
                }
            }
            let calibrated = p.mapping.neutral.len();
            if calibrated > 0 {
                ui.label(format!("neutral: {calibrated} channel(s) calibrated"));
            }
        });
    }

    fn export_ui(&mut self, ui: &mut egui::Ui) {
        ui.strong("Export");
        // In a browser exports are downloads: there is no folder to choose.
        #[cfg(not(target_arch = "wasm32"))]
        ui.horizontal(|ui| {
            let label = ui.label("Folder");
            ui.add(egui::TextEdit::singleline(&mut self.export_dir).desired_width(110.0))
                .labelled_by(label.id);
            if ui.button("Choose...").clicked()
                && let Some(dir) = rfd::FileDialog::new().pick_folder()
            {
                self.export_dir = dir.display().to_string();
            }
        });
        for (kind, label) in [
            (ExportKind::Animation, "Export glTF animation"),
            (ExportKind::LiveLinkCsv, "Export Live Link CSV"),
            (ExportKind::PersonalizedRig, "Export personalized rig"),
        ] {
            if ui.button(label).clicked() {
                let dir = PathBuf::from(self.export_dir.trim());
                self.status = Some(format!("writing {}...", kind.file_name(None)));
                self.requested_export = Some(ExportRequest { kind, label, dir });
            }
        }
        if let Some(status) = &self.status {
            ui.label(status);
        }
    }
}

/// Writes one export into `dir` (created if needed) and returns the file written; `puppet`
/// is the loaded puppet's file, model and retargeter, if one is loaded.
pub fn export(
    kind: ExportKind,
    puppet: Option<(PathBuf, Puppet, Retargeter)>,
    scene: &Scene,
    session: &StudioSession,
    dir: &Path,
) -> Result<PathBuf> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let out = dir.join(kind.file_name(puppet.as_ref().map(|p| p.0.as_path())));
    // Exporting into the puppet's folder must not overwrite the puppet or a file it names.
    if let Some((path, ..)) = &puppet {
        let inputs = std::iter::once(("the puppet".to_owned(), path.clone())).chain(
            retarget::puppet::external_files(path)
                .into_iter()
                .map(|(what, file)| (format!("the puppet's {what}"), file)),
        );
        for (what, input) in inputs {
            if files::same_file(&out, &input) {
                bail!(
                    "the export {} is the same file as {what} ({}): choose another folder",
                    out.display(),
                    input.display()
                );
            }
        }
    }
    let tracks = session.tracks();
    match kind {
        ExportKind::Animation => {
            let Some((_, puppet, retargeter)) = puppet.as_ref() else {
                bail!("load a puppet to export its animation");
            };
            let clip = retarget_clip(retargeter, &tracks);
            write_animation_glb(puppet, retargeter, &clip, &out)?;
        }
        ExportKind::LiveLinkCsv => {
            let text = live_link_text(puppet.as_ref().map(|(_, _, r)| r), &tracks);
            write_atomically(&out, text.as_bytes())?;
        }
        ExportKind::PersonalizedRig => {
            write_atomically(&out, &rig_bytes(scene, session, &out)?)?;
        }
    }
    Ok(out)
}

/// The Live Link CSV: through the puppet's mapping calibration when one is loaded.
fn live_link_text(retargeter: Option<&Retargeter>, tracks: &retarget::Tracks) -> String {
    match retargeter {
        Some(retargeter) => live_link_csv(retargeter, tracks),
        None => retarget::export::live_link_csv_raw(tracks),
    }
}

/// The personalized rig's GLB; `out` names it in messages.
fn rig_bytes(scene: &Scene, session: &StudioSession, out: &Path) -> Result<Vec<u8>> {
    let rig = PersonalizedRig::new(
        &scene.model,
        &session.blendshapes,
        &session.corrections,
        &scene.albedo,
        scene.albedo.face(),
    )?;
    Ok(rig_glb_bytes(&rig, out)?)
}

/// An export's bytes and MIME type, as the browser offers it for download: the same files
/// [`export`] writes natively.
pub fn export_bytes(
    kind: ExportKind,
    puppet: Option<&LoadedPuppet>,
    scene: &Scene,
    session: &StudioSession,
    name: &str,
) -> anyhow::Result<(Vec<u8>, &'static str)> {
    let tracks = session.tracks();
    let out = std::path::Path::new(name);
    Ok(match kind {
        ExportKind::LiveLinkCsv => (
            live_link_text(puppet.map(|p| &p.retargeter), &tracks).into_bytes(),
            "text/csv",
        ),
        ExportKind::Animation => {
            let Some(p) = puppet else {
                anyhow::bail!("load a puppet to export its animation");
            };
            let Some(source) = &p.bytes else {
                anyhow::bail!("the puppet was loaded from a file: the native studio exports it");
            };
            let clip = retarget::export::retarget_clip(&p.retargeter, &tracks);
            let bytes = retarget::export::animation_glb_bytes(
                source,
                None,
                &p.puppet,
                &p.retargeter,
                &clip,
                out,
            )?;
            (bytes, "model/gltf-binary")
        }
        ExportKind::PersonalizedRig => (rig_bytes(scene, session, out)?, "model/gltf-binary"),
    })
}

/// A 0..1 value as a small horizontal bar.
fn value_bar(ui: &mut egui::Ui, value: f32, colour: egui::Color32) {
    let (rect, _) = ui.allocate_exact_size(egui::vec2(28.0, 10.0), egui::Sense::hover());
    ui.painter()
        .rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let filled = rect.width() * value.clamp(0.0, 1.0);
    ui.painter().rect_filled(
        egui::Rect::from_min_size(rect.min, egui::vec2(filled, rect.height())),
        2.0,
        colour,
    );
}

/// Pixel radius within which a click or drag picks a curve point.
const PICK_RADIUS: f32 = 8.0;
/// Smallest x gap kept between neighbouring curve points (x must increase strictly).
const MIN_GAP: f32 = 0.01;

/// The response curve: the whole response (thick) and the curve's points (step 3 of the
/// mapping), with the current input as a vertical line. Drag a point to move it,
/// double-click to add one, right-click a point to remove it. Returns whether it changed.
///
/// Written by hand because egui_plot's interaction covers panning, not editing points.
pub fn curve_ui(
    ui: &mut egui::Ui,
    entry: &mut ChannelMapping,
    input: f32,
    dragging: &mut Option<usize>,
) -> bool {
    let side = 150.0;
    let (rect, response) =
        ui.allocate_exact_size(egui::vec2(side, side), egui::Sense::click_and_drag());
    let to_screen = |x: f32, y: f32| {
        egui::pos2(
            rect.left() + x * rect.width(),
            rect.bottom() - y.clamp(-0.05, 1.05) * rect.height(),
        )
    };
    let from_screen = |p: egui::Pos2| {
        (
            ((p.x - rect.left()) / rect.width()).clamp(0.0, 1.0),
            ((rect.bottom() - p.y) / rect.height()).clamp(0.0, 1.0),
        )
    };
    let painter = ui.painter_at(rect.expand(4.0));
    painter.rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    let grid = egui::Stroke::new(1.0, ui.visuals().weak_text_color().gamma_multiply(0.4));
    for k in 1..4 {
        let t = k as f32 / 4.0;
        painter.line_segment([to_screen(t, 0.0), to_screen(t, 1.0)], grid);
        painter.line_segment([to_screen(0.0, t), to_screen(1.0, t)], grid);
    }
    let mut changed = false;
    let point_at = |curve: &[[f32; 2]], pos: egui::Pos2| {
        curve
            .iter()
            .position(|q| to_screen(q[0], q[1]).distance(pos) <= PICK_RADIUS)
    };
    if response.drag_started()
        && let Some(pos) = response.interact_pointer_pos()
    {
        *dragging = point_at(&entry.curve, pos);
    }
    if response.dragged()
        && let (Some(k), Some(pos)) = (*dragging, response.interact_pointer_pos())
        && k < entry.curve.len()
    {
        let (x, y) = from_screen(pos);
        let lo = if k == 0 {
            0.0
        } else {
            entry.curve[k - 1][0] + MIN_GAP
        };
        let hi = entry.curve.get(k + 1).map_or(1.0, |q| q[0] - MIN_GAP);
        entry.curve[k] = [x.clamp(lo, hi.max(lo)), y];
        changed = true;
    }
    if response.drag_stopped() {
        *dragging = None;
    }
    if response.double_clicked()
        && let Some(pos) = response.interact_pointer_pos()
        && point_at(&entry.curve, pos).is_none()
    {
        let (x, y) = from_screen(pos);
        if entry.curve.is_empty() {
            // An empty curve is the identity: make its ends explicit so the new point bends it.
            entry.curve = vec![[0.0, 0.0], [1.0, 1.0]];
        }
        let at = entry.curve.partition_point(|q| q[0] < x);
        let too_close = entry.curve.iter().any(|q| (q[0] - x).abs() < MIN_GAP);
        if !too_close {
            entry.curve.insert(at, [x, y]);
            changed = true;
        }
    }
    if response.secondary_clicked()
        && let Some(pos) = response.interact_pointer_pos()
        && let Some(k) = point_at(&entry.curve, pos)
    {
        entry.curve.remove(k);
        changed = true;
    }
    // The whole response (curve, gain, offset, clamp) as the puppet receives it.
    let samples: Vec<egui::Pos2> = (0..=64)
        .map(|s| {
            let x = s as f32 / 64.0;
            to_screen(x, entry.respond(x))
        })
        .collect();
    painter.add(egui::Shape::line(
        samples,
        egui::Stroke::new(2.0, egui::Color32::from_rgb(230, 150, 60)),
    ));
    for q in &entry.curve {
        painter.circle_filled(
            to_screen(q[0], q[1]),
            4.0,
            egui::Color32::from_rgb(90, 160, 230),
        );
    }
    let x = input.clamp(0.0, 1.0);
    painter.line_segment(
        [to_screen(x, 0.0), to_screen(x, 1.0)],
        egui::Stroke::new(1.0, egui::Color32::WHITE),
    );
    response.on_hover_text(
        "Response: input (x) to puppet weight (y). Drag a point to move it, double-click to add one, right-click to remove it",
    );
    changed
}
