//! The project's own networks, TrackNet and ModelNet (exported by `training/` to
//! `assets/models/` with a `manifest.json`), and what their outputs mean.

use std::path::{Path, PathBuf};

use face::camera::{HeadPose, Intrinsics, focal_length_px};
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{ICT_NAMES, NUM_BLENDSHAPES, PersonalCorrections};
use glam::Vec3;
use serde::Deserialize;

use crate::backend::{BackendKind, InferenceBackend, Tensor, load_model};
use crate::error::{Result, TrackingError, io_error};
use crate::params::{FaceParams, crop_camera_rotation, pose_in_frame};
use crate::preprocess::{CropFraming, Normalisation};

/// Environment variable naming the folder of `manifest.json`, `track_net.onnx`, ...
pub const MODELS_ENV: &str = "LIKENESS_NETWORKS";

/// `assets/models` of this repository, or `$LIKENESS_NETWORKS`.
pub fn default_networks_dir() -> PathBuf {
    match std::env::var_os(MODELS_ENV).filter(|v| !v.is_empty()) {
        Some(dir) => PathBuf::from(dir),
        None => Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/models"),
    }
}

#[derive(Debug, Deserialize)]
struct RawManifest {
    input_size: usize,
    /// Absent from manifests written before TrackNet and ModelNet could differ.
    track_input_size: Option<usize>,
    /// Absent from manifests written before the browser had a TrackNet of its own.
    web_track_net: Option<WebTrackNet>,
    blendshape_names: Vec<String>,
    uv_size: usize,
    normalisation: RawNormalisation,
    camera: RawCamera,
    crop: Option<CropFraming>,
    mean_albedo: RawMeanAlbedo,
}

#[derive(Debug, Deserialize)]
struct RawNormalisation {
    mean: [f32; 3],
    std: [f32; 3],
}

#[derive(Debug, Deserialize)]
struct RawCamera {
    translation_reference_fov_deg: f32,
    nominal_fov_deg: f32,
}

#[derive(Debug, Deserialize)]
struct RawMeanAlbedo {
    file: String,
    tensor: String,
}

/// The TrackNet the browser runs (`manifest.json`'s `web_track_net`): tract in wasm on the
/// page's thread runs a 160 px TrackNet too slowly for live tracking, so the browser may
/// keep a smaller one beside the native `track_net.onnx`.
#[derive(Clone, Debug, PartialEq, Deserialize)]
pub struct WebTrackNet {
    /// Its file name in the models directory.
    pub file: String,
    /// Side of its square input in pixels.
    pub input_size: usize,
}

/// What the networks were trained with, read from `manifest.json`.
#[derive(Clone, Debug, PartialEq)]
pub struct Manifest {
    pub dir: PathBuf,
    /// Side of ModelNet's square input in pixels.
    pub input_size: usize,
    /// Side of TrackNet's square input in pixels. Both networks read the same crop
    /// rectangle, each sampled at its own size: TrackNet gains from more pixels on the face
    /// at a cost per frame, ModelNet runs once per person (issue 31).
    pub track_input_size: usize,
    /// The browser's TrackNet, where the export named one.
    pub web_track_net: Option<WebTrackNet>,
    pub normalisation: Normalisation,
    /// Field of view TrackNet's translation refers to (its z is for this focal length).
    pub reference_fov_deg: f32,
    /// The middle of the training cameras' fields of view, for crops of unknown cameras.
    pub nominal_fov_deg: f32,
    /// Where the crop goes around the landmarks (training framing).
    pub crop: CropFraming,
    pub mean_albedo_file: PathBuf,
    pub mean_albedo_tensor: String,
}

impl Manifest {
    pub fn load(dir: &Path) -> Result<Self> {
        let path = dir.join("manifest.json");
        if !path.is_file() {
            return Err(TrackingError::MissingModel {
                path,
                hint: format!(
                    "the trained networks are in the repository's assets/models (or set {MODELS_ENV}, or pass --networks DIR)"
                ),
            });
        }
        let text = std::fs::read_to_string(&path).map_err(io_error(&path))?;
        Self::from_json(dir, &text)
    }

    /// Parses `manifest.json`'s text; `dir` is where the files it names are (and what
    /// messages name). The browser build fetches the text instead of reading a file.
    pub fn from_json(dir: &Path, text: &str) -> Result<Self> {
        let path = dir.join("manifest.json");
        let bad = |reason: String| TrackingError::Manifest {
            path: path.clone(),
            reason,
        };
        let raw: RawManifest = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
        if raw.blendshape_names.len() != NUM_BLENDSHAPES
            || raw
                .blendshape_names
                .iter()
                .zip(ICT_NAMES)
                .any(|(a, b)| a != b)
        {
            return Err(bad(
                "`blendshape_names` is not the 53 ICT names in the template's order".into(),
            ));
        }
        if raw.uv_size != CORRECTION_SIZE {
            return Err(bad(format!(
                "uv_size {} but the face model's corrections are {CORRECTION_SIZE}",
                raw.uv_size
            )));
        }
        let track_input_size = raw.track_input_size.unwrap_or(raw.input_size);
        let web_size = raw
            .web_track_net
            .as_ref()
            .map_or(track_input_size, |w| w.input_size);
        for (name, size) in [
            ("input_size", raw.input_size),
            ("track_input_size", track_input_size),
            ("web_track_net.input_size", web_size),
        ] {
            if !(16..=1024).contains(&size) {
                return Err(bad(format!("{name} {size} is implausible")));
            }
        }
        if let Some(web) = &raw.web_track_net {
            // A bare file name: the browser fetches it beside the manifest.
            if web.file.is_empty() || web.file.contains(['/', '\\']) || web.file.starts_with('.') {
                return Err(bad(format!(
                    "web_track_net.file {:?} is not a file name",
                    web.file
                )));
            }
        }
        let crop = raw.crop.ok_or_else(|| {
            bad("no `crop` framing (run `python -m likeness_train.preprocess --calibrate`)".into())
        })?;
        let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
        if !finite(&crop.centre_offset)
            || !crop.scale.is_finite()
            || crop.scale <= 0.0
            || !finite(&raw.normalisation.mean)
            || !finite(&raw.normalisation.std)
            || raw.normalisation.std.iter().any(|s| *s <= 0.0)
            || !(1.0..179.0).contains(&raw.camera.translation_reference_fov_deg)
            || !(1.0..179.0).contains(&raw.camera.nominal_fov_deg)
        {
            return Err(bad(
                "crop, normalisation or camera values out of range".into()
            ));
        }
        Ok(Self {
            dir: dir.to_owned(),
            input_size: raw.input_size,
            track_input_size,
            web_track_net: raw.web_track_net,
            normalisation: Normalisation {
                mean: raw.normalisation.mean,
                std: raw.normalisation.std,
            },
            reference_fov_deg: raw.camera.translation_reference_fov_deg,
            nominal_fov_deg: raw.camera.nominal_fov_deg,
            crop,
            mean_albedo_file: dir.join(raw.mean_albedo.file),
            mean_albedo_tensor: raw.mean_albedo.tensor,
        })
    }

    /// The manifest as the browser's TrackNet reads it (its input size in place of the
    /// native TrackNet's); the same manifest where the export named no web TrackNet.
    pub fn for_web(&self) -> Manifest {
        let mut manifest = self.clone();
        if let Some(web) = &self.web_track_net {
            manifest.track_input_size = web.input_size;
        }
        manifest
    }

    /// f_ref: the focal length in TrackNet's input pixels its translation is expressed for.
    pub fn reference_focal_px(&self) -> f32 {
        focal_length_px(self.track_input_size as u32, self.reference_fov_deg)
    }

    /// R_0^t, the trained mean albedo of equation (3) (a 512 x 512 RGB UV map).
    pub fn load_mean_albedo(&self) -> Result<UvMap> {
        let path = &self.mean_albedo_file;
        let bytes = std::fs::read(path).map_err(io_error(path))?;
        self.mean_albedo_from_bytes(&bytes)
    }

    /// [`Manifest::load_mean_albedo`] on the file's bytes (fetched in the browser).
    pub fn mean_albedo_from_bytes(&self, bytes: &[u8]) -> Result<UvMap> {
        let path = &self.mean_albedo_file;
        let bad = |reason: String| TrackingError::Manifest {
            path: path.clone(),
            reason,
        };
        let st = safetensors::SafeTensors::deserialize(bytes).map_err(|e| bad(e.to_string()))?;
        let view = st
            .tensor(&self.mean_albedo_tensor)
            .map_err(|e| bad(e.to_string()))?;
        let shape = view.shape().to_vec();
        if shape.len() != 3 || shape[0] != 3 {
            return Err(bad(format!(
                "mean albedo shape {shape:?}, expected [3, H, W]"
            )));
        }
        let values: Vec<f32> = match view.dtype() {
            safetensors::Dtype::F16 => view
                .data()
                .chunks_exact(2)
                .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect(),
            safetensors::Dtype::F32 => view
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            other => return Err(bad(format!("mean albedo dtype {other:?}"))),
        };
        let (h, w) = (shape[1], shape[2]);
        let map = chw_to_uv(&values, h, w);
        if !map.is_finite() {
            return Err(bad("mean albedo has NaN or infinite values".into()));
        }
        Ok(map)
    }
}

/// [3, H, W] planes (row 0 at v = 1, the training code's layout) to an interleaved UvMap.
pub fn chw_to_uv(planes: &[f32], h: usize, w: usize) -> UvMap {
    let mut map = UvMap::zeros(w, h, 3);
    for c in 0..3 {
        for (t, v) in planes[c * h * w..(c + 1) * h * w].iter().enumerate() {
            map.data[t * 3 + c] = *v;
        }
    }
    map
}

/// One image's TrackNet output, in the network's own units: w after the sigmoid, Euler
/// angles in radians, translation in cm for the reference camera, 27 SH coefficients.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackNetOutput {
    pub weights: [f32; NUM_BLENDSHAPES],
    pub euler_rad: Vec3,
    pub translation_ref: Vec3,
    pub gamma: [f32; 27],
}

impl TrackNetOutput {
    pub fn is_finite(&self) -> bool {
        self.weights.iter().all(|v| v.is_finite())
            && self.euler_rad.is_finite()
            && self.translation_ref.is_finite()
            && self.gamma.iter().all(|v| v.is_finite())
    }

    /// The parameters in the frame camera, for an input cropped from `crop` (frame pixels)
    /// of a frame seen by `frame` intrinsics.
    pub fn to_frame(
        &self,
        manifest: &Manifest,
        crop: &crate::preprocess::Rect,
        frame: &Intrinsics,
    ) -> FaceParams {
        // The crop camera is the frame camera turned towards the crop centre; in input
        // pixels its focal length is f_frame * input / side, and TrackNet's z is for f_ref.
        let focal_input = frame.focal_px * manifest.track_input_size as f32 / crop.width;
        let mut t = self.translation_ref;
        t.z *= focal_input / manifest.reference_focal_px();
        let in_crop = HeadPose {
            euler_rad: self.euler_rad,
            translation: t,
        };
        let rotation = crop_camera_rotation(frame, crop.centre());
        FaceParams {
            weights: self.weights.map(|w| w.clamp(0.0, 1.0)),
            pose: pose_in_frame(&in_crop, rotation),
            gamma: self.gamma,
        }
    }
}

/// TrackNet: per-image tracking parameters.
pub struct TrackNet {
    model: Box<dyn InferenceBackend>,
    pub manifest: Manifest,
}

fn check_shape(model: &str, t: &Tensor, expect: &[usize]) -> Result<()> {
    if t.shape != expect {
        return Err(TrackingError::BadOutput {
            model: model.into(),
            reason: format!("shape {:?}, expected {expect:?}", t.shape),
        });
    }
    Ok(())
}

impl TrackNet {
    pub fn load(manifest: &Manifest, kind: BackendKind, threads: usize) -> Result<Self> {
        let path = manifest.dir.join("track_net.onnx");
        Ok(Self {
            model: load_model(&path, kind, threads)?,
            manifest: manifest.clone(),
        })
    }

    /// TrackNet on any backend (tests inject failing ones).
    pub fn from_backend(model: Box<dyn InferenceBackend>, manifest: &Manifest) -> Self {
        Self {
            model,
            manifest: manifest.clone(),
        }
    }

    pub fn kind(&self) -> BackendKind {
        self.model.kind()
    }

    /// Runs a batch [B, 3, S, S]. An image whose outputs are not finite is an `Err` in its
    /// slot (the rest of the batch is still usable).
    pub fn run(&mut self, images: &Tensor) -> Result<Vec<Result<TrackNetOutput>>> {
        let s = self.manifest.track_input_size;
        if images.shape.len() != 4 || images.shape[1..] != [3, s, s] {
            return Err(TrackingError::InvalidInput(format!(
                "TrackNet takes [B, 3, {s}, {s}], got {:?}",
                images.shape
            )));
        }
        let b = images.shape[0];
        let out = self.model.run(images)?;
        if out.len() != 4 {
            return Err(TrackingError::BadOutput {
                model: "track_net".into(),
                reason: format!(
                    "{} outputs, expected 4 (w, euler, translation, gamma)",
                    out.len()
                ),
            });
        }
        check_shape("track_net", &out[0], &[b, NUM_BLENDSHAPES])?;
        check_shape("track_net", &out[1], &[b, 3])?;
        check_shape("track_net", &out[2], &[b, 3])?;
        check_shape("track_net", &out[3], &[b, 27])?;
        Ok((0..b)
            .map(|i| {
                let o = TrackNetOutput {
                    weights: std::array::from_fn(|k| out[0].data[i * NUM_BLENDSHAPES + k]),
                    euler_rad: Vec3::from_slice(&out[1].data[i * 3..i * 3 + 3]),
                    translation_ref: Vec3::from_slice(&out[2].data[i * 3..i * 3 + 3]),
                    gamma: std::array::from_fn(|k| out[3].data[i * 27 + k]),
                };
                if o.is_finite() {
                    Ok(o)
                } else {
                    Err(TrackingError::NonFinite {
                        model: "track_net".into(),
                        output: format!("image {i}"),
                    })
                }
            })
            .collect())
    }
}

/// ModelNet: a person's corrections dS_0, dS_i, dR_0, dR_i from N images of them.
pub struct ModelNet {
    model: Box<dyn InferenceBackend>,
    pub manifest: Manifest,
}

impl ModelNet {
    pub fn load(manifest: &Manifest, kind: BackendKind, threads: usize) -> Result<Self> {
        let path = manifest.dir.join("model_net.onnx");
        Ok(Self {
            model: load_model(&path, kind, threads)?,
            manifest: manifest.clone(),
        })
    }

    /// ModelNet on any backend (the browser's tract model read from fetched bytes).
    pub fn from_backend(model: Box<dyn InferenceBackend>, manifest: &Manifest) -> Self {
        Self {
            model,
            manifest: manifest.clone(),
        }
    }

    pub fn kind(&self) -> BackendKind {
        self.model.kind()
    }

    /// Runs N >= 1 crops [N, 3, S, S] of one person; the paper's feature averaging makes
    /// any N valid.
    pub fn run(&mut self, images: &Tensor) -> Result<PersonalCorrections> {
        let s = self.manifest.input_size;
        if images.shape.len() != 4 || images.shape[0] == 0 || images.shape[1..] != [3, s, s] {
            return Err(TrackingError::InvalidInput(format!(
                "ModelNet takes [N >= 1, 3, {s}, {s}], got {:?}",
                images.shape
            )));
        }
        let out = self.model.run(images)?;
        corrections_from_outputs(&out)
    }
}

/// ModelNet's four outputs (dS0, dS, dR0, dR, channel-first) as `PersonalCorrections`.
pub fn corrections_from_outputs(out: &[Tensor]) -> Result<PersonalCorrections> {
    let n = CORRECTION_SIZE;
    if out.len() != 4 {
        return Err(TrackingError::BadOutput {
            model: "model_net".into(),
            reason: format!("{} outputs, expected 4 (dS0, dS, dR0, dR)", out.len()),
        });
    }
    check_shape("model_net", &out[0], &[1, 3, n, n])?;
    check_shape("model_net", &out[1], &[1, NUM_BLENDSHAPES, 3, n, n])?;
    check_shape("model_net", &out[2], &[1, 3, n, n])?;
    check_shape("model_net", &out[3], &[1, NUM_BLENDSHAPES, 3, n, n])?;
    for (t, name) in out.iter().zip(["dS0", "dS", "dR0", "dR"]) {
        if !t.is_finite() {
            return Err(TrackingError::NonFinite {
                model: "model_net".into(),
                output: name.into(),
            });
        }
    }
    let plane = 3 * n * n;
    let per_shape = |t: &Tensor| {
        (0..NUM_BLENDSHAPES)
            .map(|i| chw_to_uv(&t.data[i * plane..(i + 1) * plane], n, n))
            .collect::<Vec<_>>()
    };
    Ok(PersonalCorrections {
        identity_shape: chw_to_uv(&out[0].data, n, n),
        expression_shapes: per_shape(&out[1]),
        static_albedo: chw_to_uv(&out[2].data, n, n),
        dynamic_albedo: per_shape(&out[3]),
    })
}
