use crate::{
    BlendPath, FaceRenderer, FrameParams, MeshData, RenderError, RenderOptions, TextureLayers,
};

/// Format of the offscreen target: display-encoded, no sRGB conversion.
const FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8Unorm;

/// Target texture and readback buffer, kept between frames of the same size.
struct Target {
    size: (u32, u32),
    texture: wgpu::Texture,
    view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_bytes_per_row: u32,
}

/// Overrides of what [`OffscreenRenderer::new`] picks from the adapter; `None` keeps the
/// adapter's best ([`RenderOptions::for_adapter`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct OffscreenOptions {
    pub sample_count: Option<u32>,
    pub blend_path: Option<BlendPath>,
    /// [`RenderOptions::cull_back_faces`] (off by default).
    pub cull_back_faces: bool,
    /// The backends to choose an adapter from; `None` is wgpu's default and `WGPU_BACKEND`.
    /// Tests draw on OpenGL to check what WebGL2 browsers run.
    pub backends: Option<wgpu::Backends>,
}

/// Headless convenience: its own instance/adapter/device (lavapipe on a machine without a
/// GPU), rendering into an `Rgba8Unorm` texture that is read back into an image.
///
/// The adapter is chosen by wgpu's defaults and the usual environment variables
/// (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`, `WGPU_POWER_PREF`).
pub struct OffscreenRenderer {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub face: FaceRenderer,
    adapter: wgpu::Adapter,
    target: Option<Target>,
    /// A readback started by [`OffscreenRenderer::begin_image`]: its size and where the
    /// mapping callback puts its result.
    pending: Option<PendingReadback>,
}

/// What `map_async`'s callback reports, shared with the renderer that polls for it.
type MapResult = std::sync::Arc<std::sync::Mutex<Option<Result<(), wgpu::BufferAsyncError>>>>;

struct PendingReadback {
    width: u32,
    height: u32,
    mapped: MapResult,
}

impl OffscreenRenderer {
    pub fn new(mesh: &MeshData, albedo: &TextureLayers) -> Result<Self, RenderError> {
        Self::with_options(mesh, albedo, OffscreenOptions::default())
    }

    /// Like [`Self::new`], with the sample count and/or blend path forced (benchmarks, and
    /// tests that compare the paths). Forcing [`BlendPath::PrePass`] on an adapter without
    /// `Rgba32Float` render targets is an error.
    pub fn with_options(
        mesh: &MeshData,
        albedo: &TextureLayers,
        overrides: OffscreenOptions,
    ) -> Result<Self, RenderError> {
        // Validate before touching the GPU: cheaper, and the error is about the input.
        mesh.validate()?;
        let mut descriptor = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
        if let Some(backends) = overrides.backends {
            descriptor.backends = backends;
        }
        let instance = wgpu::Instance::new(descriptor);
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::from_env().unwrap_or_default(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::NoAdapter(e.to_string()))?;
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("likeness offscreen renderer"),
            required_features: wgpu::Features::empty(),
            // The adapter's own limits: offscreen rendering may want large textures.
            required_limits: adapter.limits(),
            ..Default::default()
        }))
        .map_err(|e| RenderError::RequestDevice(e.to_string()))?;
        let info = adapter.get_info();
        tracing::info!(adapter = %info.name, backend = ?info.backend, "offscreen renderer");
        let best = RenderOptions::for_adapter(&adapter, FORMAT);
        let options = RenderOptions {
            sample_count: overrides.sample_count.unwrap_or(best.sample_count),
            blend_path: overrides.blend_path.unwrap_or(best.blend_path),
            cull_back_faces: overrides.cull_back_faces,
        };
        if options.blend_path == BlendPath::PrePass && !crate::blend_prepass_supported(&adapter) {
            return Err(RenderError::InvalidInput(format!(
                "{}: Rgba32Float is not renderable, the blend pre-pass is unavailable",
                info.name
            )));
        }
        Self::on_device(adapter, device, queue, options, mesh, albedo)
    }

    /// An offscreen renderer on a device that already exists (the browser studio's, which
    /// cannot make a second one cheaply), with `options` as given.
    pub fn on_device(
        adapter: wgpu::Adapter,
        device: wgpu::Device,
        queue: wgpu::Queue,
        options: RenderOptions,
        mesh: &MeshData,
        albedo: &TextureLayers,
    ) -> Result<Self, RenderError> {
        mesh.validate()?;
        let face = FaceRenderer::with_options(&device, &queue, FORMAT, options, mesh, albedo)?;
        Ok(Self {
            device,
            queue,
            face,
            adapter,
            target: None,
            pending: None,
        })
    }

    pub fn adapter_info(&self) -> wgpu::AdapterInfo {
        self.adapter.get_info()
    }

    fn target(&mut self, width: u32, height: u32) -> Result<&Target, RenderError> {
        if width == 0 || height == 0 {
            return Err(RenderError::InvalidInput(format!(
                "render size {width}x{height} is empty"
            )));
        }
        let max = self.device.limits().max_texture_dimension_2d;
        if width > max || height > max {
            return Err(RenderError::TextureTooLarge {
                what: "render target",
                width,
                height,
                layers: 1,
                max_dim: max,
                max_layers: 1,
            });
        }
        if self
            .target
            .as_ref()
            .is_none_or(|t| t.size != (width, height))
        {
            let texture = self.device.create_texture(&wgpu::TextureDescriptor {
                label: Some("offscreen target"),
                size: wgpu::Extent3d {
                    width,
                    height,
                    depth_or_array_layers: 1,
                },
                mip_level_count: 1,
                sample_count: 1,
                dimension: wgpu::TextureDimension::D2,
                format: FORMAT,
                usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
                view_formats: &[],
            });
            let view = texture.create_view(&Default::default());
            // Texture-to-buffer copies need rows aligned to 256 bytes.
            let padded_bytes_per_row =
                (width * 4).next_multiple_of(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT);
            let readback = self.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("offscreen readback"),
                size: padded_bytes_per_row as u64 * height as u64,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            self.target = Some(Target {
                size: (width, height),
                texture,
                view,
                readback,
                padded_bytes_per_row,
            });
        }
        self.target
            .as_ref()
            .ok_or_else(|| RenderError::InvalidInput("no render target".into()))
    }

    fn record(
        &mut self,
        width: u32,
        height: u32,
        params: &FrameParams,
        readback: bool,
    ) -> Result<(), RenderError> {
        self.target(width, height)?;
        let Some(target) = self.target.as_ref() else {
            return Err(RenderError::InvalidInput("no render target".into()));
        };
        let mut encoder = self
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("offscreen frame"),
            });
        self.face.render(
            &self.device,
            &self.queue,
            &mut encoder,
            &target.view,
            (width, height),
            params,
        );
        if readback {
            encoder.copy_texture_to_buffer(
                target.texture.as_image_copy(),
                wgpu::TexelCopyBufferInfo {
                    buffer: &target.readback,
                    layout: wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(target.padded_bytes_per_row),
                        rows_per_image: Some(height),
                    },
                },
                target.texture.size(),
            );
        }
        self.queue.submit([encoder.finish()]);
        Ok(())
    }

    /// Renders one frame and waits for the GPU to finish it, without reading it back
    /// (for timing, or when only the side effects matter).
    pub fn render_and_wait(
        &mut self,
        width: u32,
        height: u32,
        params: &FrameParams,
    ) -> Result<(), RenderError> {
        self.record(width, height, params, false)?;
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        Ok(())
    }

    /// Renders one frame and returns it as an image (rows top-first, display-encoded RGBA).
    /// Blocks until the GPU is done, which a browser cannot do: there use
    /// [`OffscreenRenderer::begin_image`] and [`OffscreenRenderer::poll_image`].
    pub fn render_image(
        &mut self,
        width: u32,
        height: u32,
        params: &FrameParams,
    ) -> Result<image::RgbaImage, RenderError> {
        self.begin_image(width, height, params)?;
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| RenderError::Readback(e.to_string()))?;
        match self.poll_image() {
            Some(result) => result,
            None => Err(RenderError::Readback(
                "the GPU finished but the readback was not mapped".into(),
            )),
        }
    }

    /// Starts rendering one frame and reading it back, without waiting; the image comes
    /// from [`OffscreenRenderer::poll_image`]. A frame begun before is abandoned.
    pub fn begin_image(
        &mut self,
        width: u32,
        height: u32,
        params: &FrameParams,
    ) -> Result<(), RenderError> {
        if let Some(old) = self.pending.take()
            && let Some(target) = self.target.as_ref()
            && old.mapped.lock().is_ok_and(|m| m.is_some())
        {
            target.readback.unmap();
        }
        self.record(width, height, params, true)?;
        let Some(target) = self.target.as_ref() else {
            return Err(RenderError::InvalidInput("no render target".into()));
        };
        let mapped: MapResult = Default::default();
        let slot = mapped.clone();
        target
            .readback
            .slice(..)
            .map_async(wgpu::MapMode::Read, move |r| {
                if let Ok(mut slot) = slot.lock() {
                    *slot = Some(r);
                }
            });
        self.pending = Some(PendingReadback {
            width,
            height,
            mapped,
        });
        Ok(())
    }

    /// The frame [`OffscreenRenderer::begin_image`] started, once the GPU has finished it
    /// (`None` until then; the browser maps buffers between its event-loop turns).
    pub fn poll_image(&mut self) -> Option<Result<image::RgbaImage, RenderError>> {
        // Native backends deliver the mapping from `poll`; the browser's WebGPU from its
        // event loop (this call is then a no-op).
        if let Err(e) = self.device.poll(wgpu::PollType::Poll) {
            self.pending = None;
            return Some(Err(RenderError::Readback(e.to_string())));
        }
        let pending = self.pending.as_ref()?;
        let result = pending.mapped.lock().ok()?.take()?;
        let (width, height) = (pending.width, pending.height);
        self.pending = None;
        Some(
            result
                .map_err(|e| RenderError::Readback(e.to_string()))
                .and_then(|()| self.read_mapped(width, height)),
        )
    }

    fn read_mapped(&self, width: u32, height: u32) -> Result<image::RgbaImage, RenderError> {
        let Some(target) = self.target.as_ref() else {
            return Err(RenderError::InvalidInput("no render target".into()));
        };
        let slice = target.readback.slice(..);
        let row_bytes = (width * 4) as usize;
        let mut pixels = Vec::with_capacity(row_bytes * height as usize);
        {
            let mapped = slice
                .get_mapped_range()
                .map_err(|e| RenderError::Readback(e.to_string()))?;
            for row in mapped.chunks(target.padded_bytes_per_row as usize) {
                pixels.extend_from_slice(&row[..row_bytes]);
            }
        }
        target.readback.unmap();
        image::RgbaImage::from_raw(width, height, pixels)
            .ok_or_else(|| RenderError::Readback("readback size mismatch".into()))
    }
}
