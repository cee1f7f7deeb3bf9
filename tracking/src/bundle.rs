//! The networks as bytes in memory: what the browser build has after fetching them from
//! the served directory, where there is no file system to load them from. Everything runs
//! on tract (pure Rust); the trackers and ModelNets made here are the same as the ones
//! [`Tracker::new`] and [`ModelNet::load`] make from files.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use face::FaceModel;
use face::uv::UvMap;

use crate::BackendKind;
use crate::backend::TractModel;
use crate::error::{Result, TrackingError};
use crate::mediapipe::{
    CORRESPONDENCE_FILE, DETECTOR_FILE, Ibug68Points, IctCorrespondence, MESH_FILE, MediaPipe,
    MeshFollower,
};
use crate::networks::{Manifest, ModelNet, TrackNet};
use crate::openseeface::{FaceFollower, OpenSeeFace, model_files};
use crate::pipeline::{FootageLocator, LocatorChoice, Tracker, TrackerConfig};

/// A file's bytes with the name messages give it (its URL or path).
#[derive(Clone, Debug)]
pub struct NamedBytes {
    pub name: PathBuf,
    pub bytes: Arc<[u8]>,
}

impl NamedBytes {
    pub fn new(name: impl Into<PathBuf>, bytes: impl Into<Arc<[u8]>>) -> Self {
        Self {
            name: name.into(),
            bytes: bytes.into(),
        }
    }

    /// Reads `path` (native tests build bundles from the repository's files).
    pub fn read(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|source| match source.kind() {
            std::io::ErrorKind::NotFound => TrackingError::MissingModel {
                path: path.to_owned(),
                hint: "no such file".into(),
            },
            _ => TrackingError::Io {
                path: path.to_owned(),
                source,
            },
        })?;
        Ok(Self::new(path, bytes))
    }

    fn tract(&self) -> Result<TractModel> {
        let name = self.name.file_name().map_or_else(
            || self.name.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        TractModel::from_bytes(&name, &self.bytes)
    }
}

/// TrackNet, ModelNet, their manifest and mean albedo, and (for footage) the OpenSeeFace
/// detector and landmark network and MediaPipe's BlazeFace and Face Mesh, as bytes.
#[derive(Clone, Debug)]
pub struct NetworkBytes {
    pub manifest: Manifest,
    pub track_net: NamedBytes,
    pub model_net: NamedBytes,
    pub mean_albedo: NamedBytes,
    /// The OpenSeeFace `_plain_b1` detector and landmark network; without them only
    /// pre-cropped faces can be tracked.
    pub openseeface: Option<(NamedBytes, NamedBytes)>,
    /// MediaPipe's models and their ICT correspondence, for [`LocatorChoice::MediaPipe`].
    pub mediapipe: Option<MediaPipeBytes>,
}

impl NetworkBytes {
    /// The bundle of the files in `networks_dir` (as [`Manifest::load`] reads it) and, when
    /// given, the tract variants of the OpenSeeFace models in `models_dir`.
    pub fn read(networks_dir: &Path, models_dir: Option<&Path>) -> Result<Self> {
        let manifest = Manifest::load(networks_dir)?;
        let openseeface = match models_dir {
            Some(dir) => {
                let (detector, landmarks) = model_files(dir, BackendKind::Tract);
                Some((NamedBytes::read(&detector)?, NamedBytes::read(&landmarks)?))
            }
            None => None,
        };
        Ok(Self {
            track_net: NamedBytes::read(&networks_dir.join("track_net.onnx"))?,
            model_net: NamedBytes::read(&networks_dir.join("model_net.onnx"))?,
            mean_albedo: NamedBytes::read(&manifest.mean_albedo_file)?,
            manifest,
            openseeface,
            mediapipe: None,
        })
    }

    /// A tracker on tract, its face found as `config.locator` says: MediaPipe's models for
    /// [`LocatorChoice::MediaPipe`], none for [`LocatorChoice::PreCropped`], else
    /// OpenSeeFace's. `footage` says the input is real footage, which needs a locator's
    /// models to find the face.
    pub fn tracker(
        &self,
        face: Arc<FaceModel>,
        config: TrackerConfig,
        footage: bool,
    ) -> Result<Tracker> {
        let track_net = TrackNet::from_backend(Box::new(self.track_net.tract()?), &self.manifest);
        let locator = match config.locator {
            LocatorChoice::PreCropped => None,
            LocatorChoice::MediaPipe => {
                let mediapipe = self.mediapipe.as_ref().ok_or_else(|| {
                    TrackingError::InvalidInput(format!(
                        "the MediaPipe face locator needs MediaPipe's models ({DETECTOR_FILE}, \
                         {MESH_FILE}) and {CORRESPONDENCE_FILE}, which were not loaded"
                    ))
                })?;
                let points = mediapipe.correspondence.ibug68_points(&face.template)?;
                Some(FootageLocator::MediaPipe {
                    follower: Box::new(mediapipe.mesh_follower(points)?),
                    dense: config
                        .dense_fit
                        .then(|| mediapipe.correspondence.fit_points()),
                })
            }
            LocatorChoice::Landmarks | LocatorChoice::Auto => match self.face_follower()? {
                Some(follower) => Some(FootageLocator::OpenSeeFace(Box::new(follower))),
                None if footage => {
                    return Err(TrackingError::InvalidInput(
                        "real footage needs face detection: the OpenSeeFace models \
                         (mnv3_detection_plain_b1.onnx, lm_model0_plain_b1.onnx) were not loaded"
                            .into(),
                    ));
                }
                None => None,
            },
        };
        Tracker::from_parts(face, config, self.manifest.clone(), track_net, locator)
    }

    /// The OpenSeeFace models on tract, following a face through a video; `None` without
    /// them. The browser's face-locating worker runs one beside the tracker's own.
    pub fn face_follower(&self) -> Result<Option<FaceFollower>> {
        let Some((detector, landmarks)) = &self.openseeface else {
            return Ok(None);
        };
        face_follower(detector, landmarks).map(Some)
    }

    /// ModelNet on tract.
    pub fn model_net(&self) -> Result<ModelNet> {
        Ok(ModelNet::from_backend(
            Box::new(self.model_net.tract()?),
            &self.manifest,
        ))
    }

    /// R_0^t, the trained mean albedo.
    pub fn load_mean_albedo(&self) -> Result<UvMap> {
        self.manifest
            .mean_albedo_from_bytes(&self.mean_albedo.bytes)
    }
}

/// OpenSeeFace's detector and landmark network (the `_plain_b1` files) on tract, following
/// a face through a video.
pub fn face_follower(detector: &NamedBytes, landmarks: &NamedBytes) -> Result<FaceFollower> {
    Ok(FaceFollower::new(OpenSeeFace::from_backends(
        (Box::new(detector.tract()?), &detector.name),
        (Box::new(landmarks.tract()?), &landmarks.name),
    )?))
}

/// MediaPipe's BlazeFace (short range) and Face Mesh, and the ICT vertex under each Face
/// Mesh point, as bytes.
#[derive(Clone, Debug)]
pub struct MediaPipeBytes {
    pub detector: NamedBytes,
    pub mesh: NamedBytes,
    pub correspondence: IctCorrespondence,
}

impl MediaPipeBytes {
    /// The three files of a MediaPipe model folder (as [`MediaPipe::load`] and
    /// [`IctCorrespondence::load`] read it).
    pub fn read(dir: &Path) -> Result<Self> {
        Ok(Self {
            detector: NamedBytes::read(&dir.join(DETECTOR_FILE))?,
            mesh: NamedBytes::read(&dir.join(MESH_FILE))?,
            correspondence: IctCorrespondence::load(dir)?,
        })
    }

    /// From fetched bytes; `correspondence` is `ict_correspondence.json`'s.
    pub fn from_bytes(
        detector: NamedBytes,
        mesh: NamedBytes,
        correspondence: &NamedBytes,
    ) -> Result<Self> {
        Ok(Self {
            correspondence: IctCorrespondence::from_json(
                &correspondence.bytes,
                &correspondence.name,
            )?,
            detector,
            mesh,
        })
    }

    /// BlazeFace and Face Mesh on tract, following a face through a video and handing on
    /// `ibug68`'s points as its 68 landmarks.
    pub fn mesh_follower(&self, ibug68: Ibug68Points) -> Result<MeshFollower> {
        mesh_follower(&self.detector, &self.mesh, ibug68)
    }
}

/// BlazeFace and Face Mesh on tract (the browser's worker has no correspondence or template,
/// only the networks and the points the page worked out).
pub fn mesh_follower(
    detector: &NamedBytes,
    mesh: &NamedBytes,
    ibug68: Ibug68Points,
) -> Result<MeshFollower> {
    let located = MediaPipe::from_backends(
        (Box::new(detector.tract()?), &detector.name),
        (Box::new(mesh.tract()?), &mesh.name),
    )?;
    Ok(MeshFollower::new(located, ibug68))
}
