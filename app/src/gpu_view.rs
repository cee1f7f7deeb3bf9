//! A wgpu texture that a renderer draws into and egui shows as an image: the studio has
//! several 3D views (the face, the template and personalized blendshapes side by side,
//! the puppet), each needing its own target, re-created when the view is resized.

/// Colour format of every 3D view's texture (display-encoded, as the renderer expects).
pub const VIEW_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

struct Target {
    texture: wgpu::Texture,
    id: egui::TextureId,
    size: [u32; 2],
}

/// What the texture of a [`ViewTarget`] shows: the renderer's content stamp, the frame
/// parameters and the size.
#[derive(Clone, PartialEq)]
struct Shown {
    content_stamp: u64,
    params: renderer::FrameParams,
    size: [u32; 2],
}

/// One 3D view's render target, registered with egui.
#[derive(Default)]
pub struct ViewTarget {
    target: Option<Target>,
    shown: Option<Shown>,
    /// How many times [`ViewTarget::render`] drew (tests and the benchmark read it).
    pub renders: u64,
}

impl ViewTarget {
    /// The texture view to render into and the egui id to show, `size` pixels; the texture
    /// is re-created (keeping its egui id) when the size changes.
    pub fn prepare(
        &mut self,
        rs: &egui_wgpu::RenderState,
        size: [u32; 2],
        label: &str,
    ) -> (wgpu::TextureView, egui::TextureId) {
        let size = [size[0].max(1), size[1].max(1)];
        if let Some(t) = self.target.as_ref().filter(|t| t.size == size) {
            return (
                t.texture
                    .create_view(&wgpu::TextureViewDescriptor::default()),
                t.id,
            );
        }
        let texture = rs.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: wgpu::Extent3d {
                width: size[0],
                height: size[1],
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: VIEW_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::TEXTURE_BINDING,
            view_formats: &[],
        });
        let view = texture.create_view(&wgpu::TextureViewDescriptor::default());
        let mut egui_renderer = rs.renderer.write();
        let id = match self.target.take() {
            Some(old) => {
                egui_renderer.update_egui_texture_from_wgpu_texture(
                    &rs.device,
                    &view,
                    wgpu::FilterMode::Linear,
                    old.id,
                );
                old.id
            }
            None => {
                egui_renderer.register_native_texture(&rs.device, &view, wgpu::FilterMode::Linear)
            }
        };
        self.target = Some(Target { texture, id, size });
        (view, id)
    }
}

impl ViewTarget {
    /// Renders `face` with `params` into this target at `size` pixels (one submission) and
    /// returns the egui id to show. When nothing changed since the last call (the same
    /// renderer content, parameters and size) the texture still holds that picture and
    /// nothing is drawn: the studio repaints at the display's rate while a clip changes
    /// frame at its own, and on a software rasteriser a 3D view costs more than the rest
    /// of the window.
    pub fn render(
        &mut self,
        rs: &egui_wgpu::RenderState,
        face: &renderer::FaceRenderer,
        size: [u32; 2],
        params: &renderer::FrameParams,
        label: &str,
    ) -> egui::TextureId {
        let size = [size[0].max(1), size[1].max(1)];
        let shown = Shown {
            content_stamp: face.content_stamp(),
            params: params.clone(),
            size,
        };
        if let Some(t) = self.target.as_ref().filter(|t| t.size == size)
            && self.shown.as_ref() == Some(&shown)
        {
            return t.id;
        }
        let (view, id) = self.prepare(rs, size, label);
        let mut encoder = rs
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some(label) });
        face.render(
            &rs.device,
            &rs.queue,
            &mut encoder,
            &view,
            (size[0].max(1), size[1].max(1)),
            params,
        );
        rs.queue.submit([encoder.finish()]);
        self.shown = Some(shown);
        self.renders += 1;
        id
    }
}

impl ViewTarget {
    /// The size of the texture last prepared, in pixels.
    pub fn size(&self) -> Option<[u32; 2]> {
        self.target.as_ref().map(|t| t.size)
    }
}

/// The fraction of a 3D view's size it is rendered at: half width and height (a quarter of
/// the pixels) while a clip plays with `reduce` on, which a software rasteriser needs
/// since its cost grows with the pixels filled, and the full size when paused, so a still
/// picture is always sharp.
pub fn view_render_scale(playing: bool, reduce: bool) -> f32 {
    if playing && reduce { 0.5 } else { 1.0 }
}

/// `size` points scaled by `scale`, in whole pixels, at least 1 x 1.
pub fn scaled_pixels(size: [f32; 2], scale: f32) -> [u32; 2] {
    [
        (size[0] * scale).round().max(1.0) as u32,
        (size[1] * scale).round().max(1.0) as u32,
    ]
}

/// The size in whole pixels of the space `ui` has left, at least 16 x 16.
pub fn available_pixels(ui: &egui::Ui) -> [u32; 2] {
    let available = ui.available_size();
    [available.x.max(16.0) as u32, available.y.max(16.0) as u32]
}

/// Renderer options for interactive views: no MSAA, since on a software rasteriser 4x costs
/// about half the frame (renderer bench); screenshots written by the CLI keep 4x.
pub fn interactive_options(rs: &egui_wgpu::RenderState) -> renderer::RenderOptions {
    renderer::RenderOptions {
        sample_count: 1,
        ..renderer::RenderOptions::for_adapter(&rs.adapter, VIEW_FORMAT)
    }
}

/// [`interactive_options`] for the ICT template and a person's blendshapes on it, whose
/// triangles face outwards, so back faces are culled (tests/face_render.rs checks the
/// pictures are unchanged); not for puppets.
pub fn template_options(rs: &egui_wgpu::RenderState) -> renderer::RenderOptions {
    renderer::RenderOptions {
        cull_back_faces: true,
        ..interactive_options(rs)
    }
}

/// Dragging a view turns the head, scrolling over it moves the camera in and out.
pub fn orbit_input(ui: &egui::Ui, response: &egui::Response, orbit: &mut crate::scene::Orbit) {
    if response.dragged() {
        let delta = response.drag_delta();
        orbit.yaw_deg = (orbit.yaw_deg + delta.x * 0.4).clamp(-90.0, 90.0);
        orbit.pitch_deg = (orbit.pitch_deg + delta.y * 0.4).clamp(-60.0, 60.0);
    }
    if response.hovered() {
        let scroll = ui.input(|i| i.smooth_scroll_delta.y);
        orbit.distance_cm = (orbit.distance_cm - scroll * 0.1).clamp(30.0, 200.0);
    }
}

/// An interactive renderer of a person's own face: the template with their personalized
/// blendshapes (the mean albedo until [`upload_person_albedo`]). `what` names the view in
/// the error.
pub fn person_renderer(
    rs: &egui_wgpu::RenderState,
    scene: &crate::scene::Scene,
    blendshapes: &face::PersonalizedBlendshapes,
    what: &str,
) -> Result<renderer::FaceRenderer, String> {
    let mesh = crate::scene::mesh_data(&scene.model.template, blendshapes);
    renderer::FaceRenderer::with_options(
        &rs.device,
        &rs.queue,
        VIEW_FORMAT,
        template_options(rs),
        &mesh,
        &scene.textures,
    )
    .map_err(|e| format!("{what} unavailable: {e}"))
}

/// Shows the person's albedo under `weights` (equation 3): the mean albedo R_0^t stays on
/// the GPU and only the person's 128 x 128 correction dR_0 + sum_i w_i A_i dR_i is computed
/// and uploaded, added to the face layer by the renderer.
pub fn upload_person_albedo(
    rs: &egui_wgpu::RenderState,
    face: &mut renderer::FaceRenderer,
    scene: &crate::scene::Scene,
    corrections: &face::PersonalCorrections,
    weights: &face::BlendshapeWeights,
) -> Result<(), String> {
    let correction = scene
        .model
        .albedo_correction(corrections, weights)
        .map_err(|e| format!("albedo: {e}"))?;
    face.set_albedo_correction(&rs.queue, Some(face_layer_correction(&correction)))
        .map_err(|e| e.to_string())
}

/// A correction map of [`face::FaceModel::albedo_correction`] as the renderer takes it:
/// added to the template's face albedo layer.
pub fn face_layer_correction(correction: &face::uv::UvMap) -> renderer::AlbedoCorrection<'_> {
    renderer::AlbedoCorrection {
        rgb: &correction.data,
        width: correction.width as u32,
        height: correction.height as u32,
        layer: face::albedo::AlbedoLayer::Face.index() as u32,
    }
}
