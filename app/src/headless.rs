//! Rendering studio views to PNG files without a window.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use face::BlendshapeWeights;
use renderer::OffscreenRenderer;

use crate::scene::{Orbit, Scene, StudioView, frame_params};

/// A headless renderer for the scene, on whatever adapter wgpu finds (lavapipe here).
pub fn offscreen(scene: &Scene) -> Result<OffscreenRenderer> {
    OffscreenRenderer::new(&scene.mesh, &scene.textures).context(
        "no GPU adapter for headless rendering (on Debian install mesa-vulkan-drivers for lavapipe)",
    )
}

/// Renders one view with the given weights and orbit.
pub fn render_view(
    scene: &Scene,
    renderer: &mut OffscreenRenderer,
    view: StudioView,
    weights: &BlendshapeWeights,
    orbit: &Orbit,
    size: (u32, u32),
) -> Result<image::RgbaImage> {
    renderer.face.set_weights(&renderer.queue, &weights.0)?;
    let mask = match view {
        StudioView::Mask(i) => Some(scene.mask(i)),
        _ => None,
    };
    renderer.face.set_uv_mask(&renderer.queue, mask)?;
    let params = frame_params(view, orbit, size.0, size.1);
    Ok(renderer.render_image(size.0, size.1, &params)?)
}

/// Checks that the folder of `path` exists, before any expensive work is done for it.
pub fn ensure_output_folder(path: &Path) -> Result<&Path> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    if !dir.is_dir() {
        anyhow::bail!(
            "cannot write {}: folder {} does not exist",
            path.display(),
            dir.display()
        );
    }
    Ok(dir)
}

/// Writes a PNG atomically (a temporary file beside it, then a rename), so a failed write
/// never leaves a truncated image under the requested name.
pub fn save_png(image: &image::RgbaImage, path: &Path) -> Result<()> {
    ensure_output_folder(path)?;
    files::write_atomically_with(path, |file| {
        let mut out = std::io::BufWriter::new(file);
        image
            .write_to(&mut out, image::ImageFormat::Png)
            .map_err(std::io::Error::other)?;
        std::io::Write::flush(&mut out)
    })?;
    Ok(())
}

/// The demo's views as files: the studio's 3D view in each mode and a few expressions.
pub fn write_demo_views(scene: &Scene, out_dir: &Path, size: (u32, u32)) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let mut renderer = offscreen(scene)?;
    let neutral = BlendshapeWeights::default();
    let (expression, _) =
        crate::scene::parse_weights("jawOpen=0.6,mouthSmile_L=0.8,mouthSmile_R=0.8")?;
    let jaw = face::names::ict_index("jawOpen").unwrap_or(0);
    let front = Orbit::default();
    let three_quarter = Orbit {
        yaw_deg: 35.0,
        pitch_deg: -8.0,
        ..Orbit::default()
    };
    let shots: [(&str, StudioView, &BlendshapeWeights, &Orbit); 7] = [
        ("shaded_neutral", StudioView::Shaded, &neutral, &front),
        ("shaded_expression", StudioView::Shaded, &expression, &front),
        (
            "shaded_three_quarter",
            StudioView::Shaded,
            &expression,
            &three_quarter,
        ),
        ("albedo", StudioView::Albedo, &neutral, &front),
        ("wireframe", StudioView::Wireframe, &neutral, &three_quarter),
        ("landmarks", StudioView::Landmarks, &neutral, &front),
        ("mask_jawOpen", StudioView::Mask(jaw), &neutral, &front),
    ];
    let mut written = Vec::new();
    for (name, view, weights, orbit) in shots {
        let image = render_view(scene, &mut renderer, view, weights, orbit, size)?;
        let path = out_dir.join(format!("{name}.png"));
        save_png(&image, &path)?;
        written.push(path);
    }
    Ok(written)
}

/// The session's input as files: the first frame, the middle one (mid-performance) and the
/// frames ModelNet saw, as `input_NNNN.png`.
pub fn write_session_views(
    session: &crate::studio_session::StudioSession,
    out_dir: &Path,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out_dir)
        .with_context(|| format!("cannot create {}", out_dir.display()))?;
    let mut picked = vec![0, session.frame_count() / 2];
    picked.extend(&session.selected_frames);
    picked.sort_unstable();
    picked.dedup();
    let mut written = Vec::new();
    for k in picked {
        let Some(frame) = session.frames.get(k) else {
            continue;
        };
        let path = out_dir.join(format!("input_{k:04}.png"));
        save_png(
            &image::DynamicImage::ImageRgb8(frame.clone()).to_rgba8(),
            &path,
        )?;
        written.push(path);
    }
    Ok(written)
}
