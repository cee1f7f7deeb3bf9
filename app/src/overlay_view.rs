//! The Input panel's overlay: the reconstructed face (the person's personalized blendshapes
//! and dynamic albedo under the frame's tracked pose, weights and SH lighting) rendered in
//! the frame's own camera and composited over the frame with an opacity.
//!
//! Where the reconstruction lines up with the footage is the quickest check of a track, so
//! this is drawn by the same renderer and camera model the tracker fits against, not as a
//! separate approximation.

use std::sync::Arc;

use face::camera::HeadPose;
use glam::Vec3;
use renderer::{Camera, FaceRenderer, FrameParams, ViewMode};

use crate::gpu_view::{ViewTarget, person_renderer, upload_person_albedo};
use crate::scene::Scene;
use crate::studio_session::StudioSession;

struct OverlayGpu {
    /// The session's `Arc` address: the mesh holds that person's blendshapes.
    session: usize,
    face: FaceRenderer,
    /// The frame whose albedo (equation 3) and image are uploaded, and at which opacity.
    uploaded: Option<(usize, u32)>,
}

/// The reconstructed face over the input frame.
pub struct OverlayView {
    /// 0 shows the plain frame, 1 the reconstruction alone where the face is.
    pub opacity: f32,
    /// Where the Input panel last drew the frame, in points (tests map pixels through it).
    pub frame_rect: Option<egui::Rect>,
    gpu: Option<OverlayGpu>,
    pub(crate) target: ViewTarget,
}

impl Default for OverlayView {
    fn default() -> Self {
        Self {
            opacity: 0.6,
            frame_rect: None,
            gpu: None,
            target: ViewTarget::default(),
        }
    }
}

/// The tracked camera of frame `k`: the head pose in the session's intrinsics.
pub fn frame_camera(session: &StudioSession, k: usize) -> Option<(Camera, [f32; 27])> {
    let track = session.records.get(k)?.track.as_ref()?;
    let [yaw, pitch, roll] = track.rotation_deg;
    let pose = HeadPose::from_degrees(yaw, pitch, roll, Vec3::from(track.translation));
    let sh: [f32; 27] = track.sh.as_slice().try_into().ok()?;
    if !sh.iter().all(|c| c.is_finite()) || !pose.view_from_model().is_finite() {
        return None;
    }
    Some((
        Camera {
            view_from_model: pose.view_from_model(),
            clip_from_view: session.intrinsics.clip_from_view(1.0, 1000.0),
        },
        sh,
    ))
}

impl OverlayView {
    /// Forgets the GPU state of the previous session.
    pub fn clear(&mut self) {
        self.gpu = None;
    }

    /// Renders frame `k` with the reconstruction over it at `size` pixels (the frame's
    /// aspect ratio). `Ok(None)` when there is nothing to composite (no face tracked in the
    /// frame, or opacity 0): the caller shows the plain frame.
    pub fn render(
        &mut self,
        rs: &egui_wgpu::RenderState,
        scene: &Scene,
        session: &Arc<StudioSession>,
        k: usize,
        size: [u32; 2],
    ) -> Result<Option<egui::TextureId>, String> {
        if self.opacity <= 0.0 {
            return Ok(None);
        }
        let (Some((camera, sh)), Some(frame)) = (frame_camera(session, k), session.frames.get(k))
        else {
            return Ok(None);
        };
        let key = Arc::as_ptr(session) as usize;
        if self.gpu.as_ref().is_none_or(|g| g.session != key) {
            let face = person_renderer(rs, scene, &session.blendshapes, "face overlay")?;
            self.gpu = Some(OverlayGpu {
                session: key,
                face,
                uploaded: None,
            });
        }
        let Some(gpu) = self.gpu.as_mut() else {
            return Ok(None);
        };
        let weights = session.weights(k);
        gpu.face
            .set_weights(&rs.queue, &weights.0)
            .map_err(|e| e.to_string())?;
        let opacity = self.opacity.clamp(0.0, 1.0);
        let uploaded = (k, opacity.to_bits());
        if gpu.uploaded != Some(uploaded) {
            if gpu.uploaded.is_none_or(|(shown, _)| shown != k) {
                upload_person_albedo(rs, &mut gpu.face, scene, &session.corrections, &weights)
                    .map_err(|e| format!("overlay: {e}"))?;
            }
            let rgba = image::DynamicImage::ImageRgb8(frame.clone()).to_rgba8();
            gpu.face
                .set_overlay_image(&rs.device, &rs.queue, Some(&rgba), opacity)
                .map_err(|e| e.to_string())?;
            gpu.uploaded = Some(uploaded);
        }
        let mut params = FrameParams::new(camera);
        params.view = ViewMode::Shaded;
        params.sh_coefficients = sh;
        Ok(Some(self.target.render(
            rs,
            &gpu.face,
            size,
            &params,
            "input overlay",
        )))
    }
}
