//! The crop and input tensor every network sees, identical to the training code's
//! (`training/likeness_train/preprocess.py`; a parity test compares the two on fixtures the
//! training code exports).
//!
//! Written by hand rather than with `image::imageops::resize`: the crop must be a square at
//! sub-pixel position and size, may reach outside the frame, and has to match the Python
//! implementation bit for bit in its sampling rule, which no resizing crate promises.
//!
//! Sampling rule: pixel (row i, column j) covers [j, j+1) x [i, i+1), so its centre is at
//! (j + 0.5, i + 0.5). Output pixel (r, c) of an `out_w` x `out_h` tensor taken from the
//! rectangle (x0, y0, w, h) averages k_x x k_y bilinear samples at
//! x = x0 + (c + (a + 0.5) / k_x) * w / out_w, y = y0 + (r + (b + 0.5) / k_y) * h / out_h,
//! with k = ceil(source extent / output extent) per axis (a box prefilter, so a large face
//! is not aliased). Bilinear taps outside the frame repeat the nearest edge pixel. Values
//! are RGB / 255, then (v - mean) / std per channel; the layout is NCHW.

use glam::Vec2;
use image::RgbImage;

use crate::backend::Tensor;
use crate::error::{Result, TrackingError};

/// Per-channel input normalisation: (v / 255 - mean) / std.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Normalisation {
    pub mean: [f32; 3],
    pub std: [f32; 3],
}

impl Normalisation {
    /// TrackNet and ModelNet (the manifest's `normalisation`).
    pub const HALF: Self = Self {
        mean: [0.5; 3],
        std: [0.5; 3],
    };
    /// The OpenSeeFace detector and landmark models.
    pub const IMAGENET: Self = Self {
        mean: [0.485, 0.456, 0.406],
        std: [0.229, 0.224, 0.225],
    };
}

/// An axis-aligned rectangle in image pixels (x right, y down).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rect {
    pub x: f32,
    pub y: f32,
    pub width: f32,
    pub height: f32,
}

impl Rect {
    /// The square of side `side` centred at `centre`.
    pub fn square(centre: Vec2, side: f32) -> Self {
        Self {
            x: centre.x - 0.5 * side,
            y: centre.y - 0.5 * side,
            width: side,
            height: side,
        }
    }

    pub fn centre(&self) -> Vec2 {
        Vec2::new(self.x + 0.5 * self.width, self.y + 0.5 * self.height)
    }

    /// The bounding box of `points`; `None` if empty or not finite.
    pub fn bounding(points: impl IntoIterator<Item = Vec2>) -> Option<Self> {
        let mut lo = Vec2::splat(f32::INFINITY);
        let mut hi = Vec2::splat(f32::NEG_INFINITY);
        let mut any = false;
        for p in points {
            if !p.is_finite() {
                return None;
            }
            lo = lo.min(p);
            hi = hi.max(p);
            any = true;
        }
        any.then_some(Self {
            x: lo.x,
            y: lo.y,
            width: hi.x - lo.x,
            height: hi.y - lo.y,
        })
    }

    pub fn is_valid(&self) -> bool {
        [self.x, self.y, self.width, self.height]
            .iter()
            .all(|v| v.is_finite())
            && self.width > 0.0
            && self.height > 0.0
    }

    /// Maps a point in this rectangle's `size` x `size` resampled image back to the frame.
    pub fn to_frame(&self, p: Vec2, out_w: f32, out_h: f32) -> Vec2 {
        Vec2::new(
            self.x + p.x * self.width / out_w,
            self.y + p.y * self.height / out_h,
        )
    }

    pub fn to_array(&self) -> [f32; 4] {
        [self.x, self.y, self.width, self.height]
    }
}

/// How the TrackNet crop is placed around a face's landmarks. The training images framed
/// the face in a particular way (face height ~0.85 of the image); these constants, measured
/// on the synthetic training frames by the training code and stored in the manifest, put
/// the same framing around landmarks found in any image.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CropFraming {
    /// Crop centre minus landmark-box centre, in units of the landmark-box size.
    pub centre_offset: [f32; 2],
    /// Crop side / landmark-box size.
    pub scale: f32,
}

/// The landmarks that define the crop: the first 60 of the iBUG 68-point layout (jaw,
/// brows, nose, eyes, outer lips). OpenSeeFace's 66 points cover all of them, in another
/// order for the mouth (`openseeface::Landmarks66::to_ibug68`).
pub const CROP_LANDMARKS: usize = 60;

impl CropFraming {
    /// The square crop for `landmarks` (at least [`CROP_LANDMARKS`] points in the iBUG
    /// order, image pixels). The box size is max(width, height) of their bounding box.
    pub fn crop_for_landmarks(&self, landmarks: &[Vec2]) -> Result<Rect> {
        if landmarks.len() < CROP_LANDMARKS {
            return Err(TrackingError::InvalidInput(format!(
                "a crop needs {CROP_LANDMARKS} landmarks, got {}",
                landmarks.len()
            )));
        }
        let bbox = Rect::bounding(landmarks[..CROP_LANDMARKS].iter().copied())
            .filter(Rect::is_valid)
            .ok_or_else(|| {
                TrackingError::InvalidInput("landmarks are degenerate or not finite".into())
            })?;
        let size = bbox.width.max(bbox.height);
        let centre = bbox.centre() + Vec2::from(self.centre_offset) * size;
        Ok(Rect::square(centre, size * self.scale))
    }
}

/// Resamples `rect` of `image` to an `out_w` x `out_h` NCHW tensor (batch 1) by the rule in
/// the module documentation.
pub fn sample_rect(
    image: &RgbImage,
    rect: Rect,
    out_w: usize,
    out_h: usize,
    norm: Normalisation,
) -> Result<Tensor> {
    let mut tensor = Tensor::zeros(vec![1, 3, out_h, out_w]);
    sample_rect_into(image, rect, out_w, out_h, norm, &mut tensor.data)?;
    Ok(tensor)
}

/// [`sample_rect`] into a caller's buffer of 3 * out_h * out_w values (one image of a
/// batch).
pub fn sample_rect_into(
    image: &RgbImage,
    rect: Rect,
    out_w: usize,
    out_h: usize,
    norm: Normalisation,
    out: &mut [f32],
) -> Result<()> {
    let (iw, ih) = (image.width() as usize, image.height() as usize);
    if iw == 0 || ih == 0 {
        return Err(TrackingError::InvalidInput("the image is empty".into()));
    }
    if !rect.is_valid() {
        return Err(TrackingError::InvalidInput(format!(
            "crop rectangle {rect:?} is empty or not finite"
        )));
    }
    if out_w == 0 || out_h == 0 || out.len() != 3 * out_w * out_h {
        return Err(TrackingError::InvalidInput(format!(
            "output buffer of {} values for a {out_w}x{out_h} crop",
            out.len()
        )));
    }
    let step_x = f64::from(rect.width) / out_w as f64;
    let step_y = f64::from(rect.height) / out_h as f64;
    let kx = step_x.ceil().max(1.0) as usize;
    let ky = step_y.ceil().max(1.0) as usize;
    let raw = image.as_raw();
    let plane = out_w * out_h;
    let inv = 1.0 / (kx * ky) as f64;
    // Taps depend only on the column (row): computed once per column (row) and sample.
    let x_taps = axis_taps(f64::from(rect.x), step_x, kx, out_w, iw);
    let y_taps = axis_taps(f64::from(rect.y), step_y, ky, out_h, ih);
    // Bilinear sampling is separable: each source row that any sample touches is first
    // resampled horizontally (summing its kx taps per output column), then rows are
    // blended vertically. Same arithmetic as sampling point by point, up to the order of
    // the f64 additions, at a fraction of the cost.
    let mut used = vec![false; ih];
    for &(y0, y1, _) in &y_taps {
        used[y0] = true;
        used[y1] = true;
    }
    let mut rows: Vec<Option<Vec<f64>>> = vec![None; ih];
    for (y, row) in rows.iter_mut().enumerate().filter(|(y, _)| used[*y]) {
        let src = &raw[y * iw * 3..(y + 1) * iw * 3];
        let mut h = vec![0.0f64; out_w * 3];
        for (c, out3) in h.chunks_exact_mut(3).enumerate() {
            for &(x0, x1, fx) in &x_taps[c * kx..(c + 1) * kx] {
                let (p0, p1) = (&src[x0 * 3..x0 * 3 + 3], &src[x1 * 3..x1 * 3 + 3]);
                for ch in 0..3 {
                    let (a, b) = (f64::from(p0[ch]), f64::from(p1[ch]));
                    out3[ch] += a + (b - a) * fx;
                }
            }
        }
        *row = Some(h);
    }
    let scale: [f64; 3] = std::array::from_fn(|ch| inv / 255.0 / f64::from(norm.std[ch]));
    let offset: [f64; 3] =
        std::array::from_fn(|ch| f64::from(norm.mean[ch]) / f64::from(norm.std[ch]));
    let mut acc = vec![0.0f64; out_w * 3];
    for r in 0..out_h {
        acc.iter_mut().for_each(|v| *v = 0.0);
        for &(y0, y1, fy) in &y_taps[r * ky..(r + 1) * ky] {
            let (Some(top), Some(bottom)) = (rows[y0].as_deref(), rows[y1].as_deref()) else {
                continue; // every tapped row was resampled above
            };
            for ((a, t), b) in acc.iter_mut().zip(top).zip(bottom) {
                *a += t + (b - t) * fy;
            }
        }
        for c in 0..out_w {
            for ch in 0..3 {
                out[ch * plane + r * out_w + c] = (acc[c * 3 + ch] * scale[ch] - offset[ch]) as f32;
            }
        }
    }
    Ok(())
}

/// The bilinear taps of the `k` samples of each of `out_n` output pixels along one axis:
/// sample a of pixel c sits at origin + (c + (a + 0.5) / k) * step.
fn axis_taps(
    origin: f64,
    step: f64,
    k: usize,
    out_n: usize,
    in_n: usize,
) -> Vec<(usize, usize, f64)> {
    (0..out_n)
        .flat_map(|c| {
            (0..k).map(move |a| {
                taps(
                    origin + (c as f64 + (a as f64 + 0.5) / k as f64) * step - 0.5,
                    in_n,
                )
            })
        })
        .collect()
}

/// Bilinear taps of continuous index `t` on an axis of `n` pixels, edges repeated.
fn taps(t: f64, n: usize) -> (usize, usize, f64) {
    let last = (n - 1) as f64;
    let t = t.clamp(0.0, last);
    let i0 = t.floor();
    let f = t - i0;
    let i0 = i0 as usize;
    (i0, (i0 + 1).min(n - 1), f)
}
