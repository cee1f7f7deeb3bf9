//! Golden-image comparison for tests (this crate's and any other crate's).
//!
//! Rendering is not bit-exact across drivers and Mesa versions (rasterisation rules, MSAA
//! resolve, float rounding), so images are compared with a [`Tolerance`] rather than for
//! equality. Set `LIKENESS_UPDATE_GOLDENS=1` to (re)write goldens from the current output;
//! without it a missing golden is a test failure that says how to create it.

use image::RgbaImage;
use std::path::{Path, PathBuf};

/// Environment variable that switches [`assert_matches_golden`] to writing goldens.
pub const UPDATE_ENV: &str = "LIKENESS_UPDATE_GOLDENS";

/// How different two images may be: at least `min_fraction_within` of the pixels must have
/// every channel within `max_channel_diff` (of 255).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    pub max_channel_diff: u8,
    pub min_fraction_within: f64,
}

impl Default for Tolerance {
    /// Per-channel |diff| <= 3 for >= 99.5 % of the pixels: absorbs rounding and a few edge
    /// pixels of rasterisation differences, but catches any visible change.
    fn default() -> Self {
        Self {
            max_channel_diff: 3,
            min_fraction_within: 0.995,
        }
    }
}

/// Result of [`compare`].
#[derive(Clone, Debug)]
pub struct Comparison {
    /// Pixels with some channel differing by more than the tolerance.
    pub pixels_outside: u64,
    pub total_pixels: u64,
    /// Largest per-channel difference anywhere.
    pub max_diff: u8,
    /// Red where a pixel is outside the tolerance, grey-scaled difference elsewhere.
    pub diff_image: RgbaImage,
}

impl Comparison {
    pub fn fraction_within(&self) -> f64 {
        if self.total_pixels == 0 {
            1.0
        } else {
            1.0 - self.pixels_outside as f64 / self.total_pixels as f64
        }
    }

    pub fn passes(&self, tolerance: Tolerance) -> bool {
        self.fraction_within() >= tolerance.min_fraction_within
    }
}

/// Compares two images of the same size; `None` if the sizes differ.
pub fn compare(
    expected: &RgbaImage,
    actual: &RgbaImage,
    tolerance: Tolerance,
) -> Option<Comparison> {
    if expected.dimensions() != actual.dimensions() {
        return None;
    }
    let (w, h) = actual.dimensions();
    let mut diff_image = RgbaImage::new(w, h);
    let mut pixels_outside = 0;
    let mut max_diff = 0;
    for ((e, a), d) in expected
        .pixels()
        .zip(actual.pixels())
        .zip(diff_image.pixels_mut())
    {
        let diff = (0..4).map(|c| e.0[c].abs_diff(a.0[c])).max().unwrap_or(0);
        max_diff = max_diff.max(diff);
        *d = if diff > tolerance.max_channel_diff {
            pixels_outside += 1;
            image::Rgba([255, 0, 0, 255])
        } else {
            let g = diff.saturating_mul(40);
            image::Rgba([g, g, g, 255])
        };
    }
    Some(Comparison {
        pixels_outside,
        total_pixels: w as u64 * h as u64,
        max_diff,
        diff_image,
    })
}

fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy())
        .unwrap_or_default();
    path.with_file_name(format!("{stem}{suffix}"))
}

/// Panics (it is a test assertion) unless `image` matches the PNG at `path` within
/// `tolerance`. On failure writes `<name>.actual.png` and `<name>.diff.png` next to the
/// golden. With `LIKENESS_UPDATE_GOLDENS=1` it writes `image` to `path` instead.
pub fn assert_matches_golden(path: &Path, image: &RgbaImage, tolerance: Tolerance) {
    let update = std::env::var(UPDATE_ENV).is_ok_and(|v| !v.is_empty() && v != "0");
    if update {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)
                .unwrap_or_else(|e| panic!("creating {}: {e}", dir.display()));
        }
        image
            .save(path)
            .unwrap_or_else(|e| panic!("writing golden {}: {e}", path.display()));
        eprintln!("golden updated: {}", path.display());
        return;
    }
    let actual_path = with_suffix(path, ".actual.png");
    let diff_path = with_suffix(path, ".diff.png");
    if !path.exists() {
        let _ = image.save(&actual_path);
        panic!(
            "golden image {} is missing (current output written to {}); \
             create it by running the test with {UPDATE_ENV}=1 and review it before committing",
            path.display(),
            actual_path.display()
        );
    }
    let expected = image::open(path)
        .unwrap_or_else(|e| panic!("reading golden {}: {e}", path.display()))
        .to_rgba8();
    let fail = |msg: String| -> ! {
        let _ = image.save(&actual_path);
        panic!(
            "{msg}\n  golden: {}\n  actual: {}\n  diff:   {}\n  (if the change is intended, rerun with {UPDATE_ENV}=1)",
            path.display(),
            actual_path.display(),
            diff_path.display()
        );
    };
    let Some(cmp) = compare(&expected, image, tolerance) else {
        fail(format!(
            "size differs: golden {:?}, actual {:?}",
            expected.dimensions(),
            image.dimensions()
        ));
    };
    if !cmp.passes(tolerance) {
        let _ = cmp.diff_image.save(&diff_path);
        fail(format!(
            "image differs from golden: {} of {} pixels ({:.3} %) have a channel off by more than {} \
             (max diff {}); allowed {:.3} %",
            cmp.pixels_outside,
            cmp.total_pixels,
            100.0 * (1.0 - cmp.fraction_within()),
            tolerance.max_channel_diff,
            cmp.max_diff,
            100.0 * (1.0 - tolerance.min_fraction_within)
        ));
    }
    // Stale failure artefacts from an earlier run would only confuse.
    let _ = std::fs::remove_file(&actual_path);
    let _ = std::fs::remove_file(&diff_path);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gradient(offset: u8) -> RgbaImage {
        RgbaImage::from_fn(20, 10, |x, y| {
            image::Rgba([(x * 10) as u8 + offset, (y * 20) as u8, 100, 255])
        })
    }

    #[test]
    fn compare_counts_pixels_outside_tolerance() {
        let a = gradient(0);
        let mut b = gradient(2);
        let tol = Tolerance::default();
        let c = compare(&a, &b, tol).unwrap();
        assert_eq!((c.pixels_outside, c.max_diff), (0, 2));
        assert!(c.passes(tol));
        // 1 of 200 pixels off = exactly the allowed 0.5 %; 2 is too many.
        b.put_pixel(3, 3, image::Rgba([0, 0, 0, 255]));
        assert!(compare(&a, &b, tol).unwrap().passes(tol));
        b.put_pixel(4, 3, image::Rgba([0, 0, 0, 255]));
        let c = compare(&a, &b, tol).unwrap();
        assert_eq!(c.pixels_outside, 2);
        assert!(!c.passes(tol));
        assert!(compare(&a, &RgbaImage::new(3, 3), tol).is_none());
    }

    #[test]
    fn failure_writes_actual_and_diff_next_to_the_golden() {
        if std::env::var(UPDATE_ENV).is_ok() {
            return; // update mode would (correctly) overwrite instead of failing
        }
        let dir = std::env::temp_dir().join(format!("renderer-golden-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("g.png");
        let missing = std::panic::catch_unwind(|| {
            assert_matches_golden(&path, &gradient(0), Tolerance::default())
        });
        assert!(missing.is_err() && !path.exists());
        gradient(0).save(&path).unwrap();
        assert_matches_golden(&path, &gradient(1), Tolerance::default());
        let differs = std::panic::catch_unwind(|| {
            assert_matches_golden(&path, &gradient(50), Tolerance::default())
        });
        assert!(differs.is_err());
        assert!(dir.join("g.actual.png").exists() && dir.join("g.diff.png").exists());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
