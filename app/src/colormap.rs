//! Images of the model's UV maps for the studio's panels: albedo as colour, magnitudes
//! (masks, shape corrections in mm) through a sequential colour map, signed corrections
//! (dR_i) through a diverging one, and the colour bars that give them a scale.
//!
//! The colour maps come from `colorous` (matplotlib's viridis and ColorBrewer's RdBu); this
//! module only decides what value maps to which end.

use face::uv::UvMap;
use image::{Rgba, RgbaImage};

/// A UV map as an image, row 0 at v = 1 (the maps' own layout, so no flip).
fn image_from_fn(map: &UvMap, mut colour: impl FnMut(&[f32]) -> [u8; 3]) -> RgbaImage {
    let mut out = RgbaImage::new(map.width as u32, map.height as u32);
    for (i, px) in out.pixels_mut().enumerate() {
        let texel = &map.data[i * map.channels..(i + 1) * map.channels];
        let [r, g, b] = colour(texel);
        *px = Rgba([r, g, b, 255]);
    }
    out
}

fn quantize(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Display-encoded RGB values in [0, 1] as colour (values outside are clipped).
pub fn albedo_image(map: &UvMap) -> RgbaImage {
    image_from_fn(map, |t| match t {
        [r, g, b, ..] => [quantize(*r), quantize(*g), quantize(*b)],
        [v] => [quantize(*v); 3],
        _ => [0; 3],
    })
}

/// Viridis colour of `value / max`, clipped to [0, 1]; NaN shows as magenta so it is
/// never mistaken for a value.
pub fn sequential(value: f32, max: f32) -> [u8; 3] {
    if !value.is_finite() {
        return [255, 0, 255];
    }
    let t = if max > 0.0 { value / max } else { 0.0 };
    let c = colorous::VIRIDIS.eval_continuous(f64::from(t.clamp(0.0, 1.0)));
    [c.r, c.g, c.b]
}

/// Diverging colour of `value` in [-scale, scale]: blue below zero, white at zero, red
/// above (RdBu reversed, so that "more" reads as warm).
pub fn diverging(value: f32, scale: f32) -> [u8; 3] {
    if !value.is_finite() {
        return [255, 0, 255];
    }
    let t = if scale > 0.0 { value / scale } else { 0.0 };
    let c = colorous::RED_BLUE.eval_continuous(f64::from(0.5 - 0.5 * t.clamp(-1.0, 1.0)));
    [c.r, c.g, c.b]
}

/// The length of each texel's vector (one channel: its absolute value), `scale` times,
/// through [`sequential`] with `max` at the top: e.g. a shape correction in cm shown in mm
/// with `scale` 10.
pub fn magnitude_image(map: &UvMap, scale: f32, max: f32) -> RgbaImage {
    image_from_fn(map, |t| {
        let length = t.iter().map(|v| v * v).sum::<f32>().sqrt() * scale;
        sequential(length, max)
    })
}

/// The mean of each texel's channels (for dR_i: how much lighter or darker the skin gets)
/// through [`diverging`].
pub fn signed_mean_image(map: &UvMap, scale: f32) -> RgbaImage {
    image_from_fn(map, |t| {
        let mean = t.iter().sum::<f32>() / t.len().max(1) as f32;
        diverging(mean, scale)
    })
}

/// The largest texel vector length of a map, `scale` times (0 for an empty map).
pub fn max_magnitude(map: &UvMap, scale: f32) -> f32 {
    map.data
        .chunks_exact(map.channels.max(1))
        .map(|t| t.iter().map(|v| v * v).sum::<f32>().sqrt() * scale)
        .fold(0.0, f32::max)
}

/// The largest |mean of channels| of a map (the scale a diverging view needs).
pub fn max_abs_mean(map: &UvMap) -> f32 {
    map.data
        .chunks_exact(map.channels.max(1))
        .map(|t| (t.iter().sum::<f32>() / t.len() as f32).abs())
        .fold(0.0, f32::max)
}

/// A horizontal colour bar, `width` x `height`, low values on the left.
pub fn colour_bar(width: u32, height: u32, colour: impl Fn(f32) -> [u8; 3]) -> RgbaImage {
    let mut out = RgbaImage::new(width.max(1), height.max(1));
    for (x, _, px) in out.enumerate_pixels_mut() {
        let t = (x as f32 + 0.5) / width.max(1) as f32;
        let [r, g, b] = colour(t);
        *px = Rgba([r, g, b, 255]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sequential_ends_are_viridis_ends_and_clip() {
        // viridis: dark purple at 0, yellow at 1.
        assert_eq!(sequential(0.0, 2.0), sequential(-5.0, 2.0));
        assert_eq!(sequential(2.0, 2.0), sequential(9.0, 2.0));
        let [r0, g0, b0] = sequential(0.0, 1.0);
        let [r1, g1, b1] = sequential(1.0, 1.0);
        assert!(b0 > r0 && b0 > g0, "low end is purple-blue");
        assert!(r1 > b1 && g1 > b1, "high end is yellow");
        assert_eq!(sequential(f32::NAN, 1.0), [255, 0, 255]);
    }

    #[test]
    fn diverging_is_white_at_zero_red_above_blue_below() {
        // RdBu's centre is a near-white grey (ColorBrewer #f7f7f7, ~240 when interpolated).
        let [r, g, b] = diverging(0.0, 0.1);
        assert!(
            r.min(g).min(b) > 230 && r.max(g).max(b) - r.min(g).min(b) < 10,
            "{r} {g} {b}"
        );
        let [r, _, b] = diverging(0.1, 0.1);
        assert!(r > b);
        let [r, _, b] = diverging(-0.1, 0.1);
        assert!(b > r);
        assert_eq!(
            diverging(1.0, 0.1),
            diverging(0.1, 0.1),
            "clipped at the scale"
        );
    }

    #[test]
    fn images_keep_the_map_layout_and_values() {
        let mut map = UvMap::zeros(4, 2, 3);
        // Texel (x 3, y 1) = 3-4-0 triangle: length 5.
        let t = (4 + 3) * 3;
        map.data[t] = 3.0;
        map.data[t + 1] = 4.0;
        assert_eq!(max_magnitude(&map, 1.0), 5.0);
        assert_eq!(max_magnitude(&map, 10.0), 50.0);
        let image = magnitude_image(&map, 1.0, 5.0);
        assert_eq!(image.dimensions(), (4, 2));
        assert_eq!(image.get_pixel(3, 1).0[..3], sequential(1.0, 1.0));
        assert_eq!(image.get_pixel(0, 0).0[..3], sequential(0.0, 1.0));
        let mut albedo = UvMap::zeros(1, 1, 3);
        albedo.data.copy_from_slice(&[1.0, 0.5, -1.0]);
        assert_eq!(albedo_image(&albedo).get_pixel(0, 0).0, [255, 128, 0, 255]);
        let mut signed = UvMap::zeros(2, 1, 3);
        signed.data[..3].copy_from_slice(&[-0.1, -0.1, -0.1]);
        assert_eq!(max_abs_mean(&signed), 0.1);
        let image = signed_mean_image(&signed, 0.1);
        assert_eq!(image.get_pixel(0, 0).0[..3], diverging(-0.1, 0.1));
        assert_eq!(image.get_pixel(1, 0).0[..3], diverging(0.0, 0.1));
    }

    #[test]
    fn colour_bars_run_low_to_high() {
        let bar = colour_bar(100, 4, |t| sequential(t, 1.0));
        assert_eq!(bar.dimensions(), (100, 4));
        assert_eq!(bar.get_pixel(0, 0).0[..3], sequential(0.005, 1.0));
        assert_eq!(bar.get_pixel(99, 3).0[..3], sequential(0.995, 1.0));
    }
}
