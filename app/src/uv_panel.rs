//! The studio's UV-space panel: what the model learned about a person, as maps on the face
//! tile (row 0 at v = 1), with zoom and pan (egui's `Scene`) and a colour bar:
//! the static albedo R_0^t + dR_0, each dynamic albedo A_i dR_i (diverging, one scale for
//! all i so they compare), the blended albedo of the current frame (equation 3), the
//! attention masks A_i, and the shape corrections |A_i dS_i| in mm.

use std::collections::HashMap;

use face::uv::UvMap;
use face::{BlendshapeWeights, FaceModel, NUM_BLENDSHAPES, PersonalCorrections};
use image::RgbaImage;

use crate::colormap::{
    albedo_image, colour_bar, diverging, magnitude_image, max_abs_mean, max_magnitude, sequential,
    signed_mean_image,
};

/// Which map the panel shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum UvLayer {
    /// R_0^t + dR_0.
    StaticAlbedo,
    /// A_i dR_i of the selected blendshape.
    DynamicAlbedo,
    /// Equation (3) with the current frame's weights.
    FrameAlbedo,
    /// A_i of the selected blendshape.
    Mask,
    /// |A_i dS_i| of the selected blendshape, in mm.
    ShapeCorrection,
}

impl UvLayer {
    pub const ALL: [UvLayer; 5] = [
        UvLayer::StaticAlbedo,
        UvLayer::DynamicAlbedo,
        UvLayer::FrameAlbedo,
        UvLayer::Mask,
        UvLayer::ShapeCorrection,
    ];

    pub fn label(self) -> &'static str {
        match self {
            UvLayer::StaticAlbedo => "Static albedo",
            UvLayer::DynamicAlbedo => "Dynamic albedo",
            UvLayer::FrameAlbedo => "Frame albedo",
            UvLayer::Mask => "Attention mask",
            UvLayer::ShapeCorrection => "Shape correction",
        }
    }
}

/// How a map's colours read.
#[derive(Clone, Debug, PartialEq)]
pub enum Legend {
    /// Colours are the albedo itself.
    Colour,
    /// Viridis from 0 to `max` (in `unit`).
    Sequential { max: f32, unit: &'static str },
    /// RdBu from -scale to +scale.
    Diverging { scale: f32 },
}

/// Scales shared by all blendshapes of one person, computed once.
#[derive(Clone, Debug, PartialEq)]
pub struct UvScales {
    /// Largest |mean of A_i dR_i| over all i (at least 0.01).
    pub dynamic_albedo: f32,
    /// Largest |A_i dS_i| over all i, in mm (at least 0.1).
    pub shape_mm: f32,
}

/// A_i times a 3-channel map (what equations 2 and 3 apply).
pub fn masked(mask: &UvMap, map: &UvMap) -> UvMap {
    let mut out = map.clone();
    for (t, texel) in out.data.chunks_exact_mut(map.channels.max(1)).enumerate() {
        let a = mask.data.get(t).copied().unwrap_or(0.0);
        texel.iter_mut().for_each(|v| *v *= a);
    }
    out
}

impl UvScales {
    /// The scales shared by every blendshape, so maps compare across blendshapes.
    pub fn new(model: &FaceModel, corrections: &PersonalCorrections) -> Self {
        Self::over(model, corrections, 0..NUM_BLENDSHAPES)
    }

    /// The scales of blendshape `i` alone, so a small correction fills the colour range.
    pub fn for_blendshape(model: &FaceModel, corrections: &PersonalCorrections, i: usize) -> Self {
        let i = i.min(NUM_BLENDSHAPES - 1);
        Self::over(model, corrections, i..i + 1)
    }

    fn over(
        model: &FaceModel,
        corrections: &PersonalCorrections,
        blendshapes: std::ops::Range<usize>,
    ) -> Self {
        let mut dynamic_albedo = 0.0f32;
        let mut shape_mm = 0.0f32;
        for i in blendshapes {
            let mask = model.masks.mask(i);
            dynamic_albedo =
                dynamic_albedo.max(max_abs_mean(&masked(mask, &corrections.dynamic_albedo[i])));
            shape_mm = shape_mm.max(max_magnitude(
                &masked(mask, &corrections.expression_shapes[i]),
                10.0,
            ));
        }
        Self {
            dynamic_albedo: dynamic_albedo.max(0.01),
            shape_mm: shape_mm.max(0.1),
        }
    }
}

/// The image and legend of one map.
pub fn layer_image(
    model: &FaceModel,
    mean_albedo: &UvMap,
    corrections: &PersonalCorrections,
    scales: &UvScales,
    layer: UvLayer,
    blendshape: usize,
    frame_weights: &BlendshapeWeights,
) -> face::Result<(RgbaImage, Legend)> {
    let i = blendshape.min(NUM_BLENDSHAPES - 1);
    let mask = model.masks.mask(i);
    Ok(match layer {
        UvLayer::StaticAlbedo => (
            albedo_image(&model.albedo(mean_albedo, corrections, &BlendshapeWeights::default())?),
            Legend::Colour,
        ),
        UvLayer::FrameAlbedo => (
            albedo_image(&model.albedo(mean_albedo, corrections, frame_weights)?),
            Legend::Colour,
        ),
        UvLayer::DynamicAlbedo => (
            signed_mean_image(
                &masked(mask, &corrections.dynamic_albedo[i]),
                scales.dynamic_albedo,
            ),
            Legend::Diverging {
                scale: scales.dynamic_albedo,
            },
        ),
        UvLayer::Mask => (
            magnitude_image(mask, 1.0, 1.0),
            Legend::Sequential { max: 1.0, unit: "" },
        ),
        UvLayer::ShapeCorrection => (
            magnitude_image(
                &masked(mask, &corrections.expression_shapes[i]),
                10.0,
                scales.shape_mm,
            ),
            Legend::Sequential {
                max: scales.shape_mm,
                unit: "mm",
            },
        ),
    })
}

/// What the panel keeps between frames.
pub struct UvPanel {
    pub layer: Option<UvLayer>,
    /// The part of the map in view (egui `Scene` coordinates: the map spans 0..512).
    pub scene_rect: egui::Rect,
    textures: HashMap<(UvLayer, usize), (egui::TextureHandle, Legend)>,
    bars: HashMap<&'static str, egui::TextureHandle>,
    scales: Option<UvScales>,
    /// Colour scales fitted to the shown blendshape's map instead of shared by all.
    pub scale_per_map: bool,
}

impl Default for UvPanel {
    fn default() -> Self {
        Self {
            layer: None,
            // Not positive: the first frame frames the whole map.
            scene_rect: egui::Rect::NOTHING,
            textures: HashMap::new(),
            bars: HashMap::new(),
            scales: None,
            scale_per_map: false,
        }
    }
}

/// A colour bar: its cache name, its two end labels and its colour function.
type BarSpec = (&'static str, String, String, fn(f32) -> [u8; 3]);

/// Side of the map in scene units.
const MAP_SIDE: f32 = 512.0;

impl UvPanel {
    /// Forgets cached images (a new session).
    pub fn clear(&mut self) {
        self.textures.clear();
        self.scales = None;
    }

    pub fn layer(&self) -> UvLayer {
        self.layer.unwrap_or(UvLayer::StaticAlbedo)
    }

    #[allow(clippy::too_many_arguments)]
    pub fn ui(
        &mut self,
        ui: &mut egui::Ui,
        model: &FaceModel,
        mean_albedo: &UvMap,
        corrections: &PersonalCorrections,
        blendshape: usize,
        frame: usize,
        frame_weights: &BlendshapeWeights,
    ) -> Option<String> {
        let mut layer = self.layer();
        ui.horizontal(|ui| {
            for l in UvLayer::ALL {
                if ui.selectable_label(layer == l, l.label()).clicked() {
                    layer = l;
                }
            }
            if ui.button("Reset view").clicked() {
                self.scene_rect = egui::Rect::NOTHING;
            }
            ui.separator();
            if ui
                .checkbox(&mut self.scale_per_map, "Fit the scale to this map")
                .on_hover_text(
                    "Off: one scale for all 53 blendshapes, so their maps compare. On: the selected map fills the colour range.",
                )
                .changed()
            {
                self.textures
                    .retain(|k, _| !matches!(k.0, UvLayer::DynamicAlbedo | UvLayer::ShapeCorrection));
            }
        });
        self.layer = Some(layer);

        // Per-blendshape maps are keyed by the blendshape, the frame's albedo by the frame.
        let key = match layer {
            UvLayer::StaticAlbedo => (layer, 0),
            UvLayer::FrameAlbedo => (layer, frame),
            _ => (layer, blendshape),
        };
        if layer == UvLayer::FrameAlbedo {
            // Only the current frame's map is worth keeping.
            self.textures
                .retain(|k, _| k.0 != UvLayer::FrameAlbedo || k.1 == frame);
        }
        if let std::collections::hash_map::Entry::Vacant(slot) = self.textures.entry(key) {
            // Scales are worked out only when a map is drawn, not every frame.
            let scales = if self.scale_per_map {
                UvScales::for_blendshape(model, corrections, blendshape)
            } else {
                self.scales
                    .get_or_insert_with(|| UvScales::new(model, corrections))
                    .clone()
            };
            match layer_image(
                model,
                mean_albedo,
                corrections,
                &scales,
                layer,
                blendshape,
                frame_weights,
            ) {
                Ok((image, legend)) => {
                    let size = [image.width() as usize, image.height() as usize];
                    let color = egui::ColorImage::from_rgba_unmultiplied(size, image.as_raw());
                    let texture = ui.ctx().load_texture(
                        format!("uv {key:?}"),
                        color,
                        egui::TextureOptions::LINEAR,
                    );
                    slot.insert((texture, legend));
                }
                Err(e) => return Some(format!("cannot show the {}: {e}", layer.label())),
            }
        }
        let (texture, legend) = self.textures.get(&key)?.clone();
        self.legend_ui(ui, &legend, layer, blendshape);
        if !self.scene_rect.is_positive() {
            self.scene_rect =
                egui::Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(MAP_SIDE, MAP_SIDE));
        }
        egui::Scene::new()
            .zoom_range(0.25..=16.0)
            .show(ui, &mut self.scene_rect, |ui| {
                ui.add(
                    egui::Image::new((texture.id(), egui::vec2(MAP_SIDE, MAP_SIDE)))
                        .texture_options(egui::TextureOptions::NEAREST),
                );
            });
        None
    }

    fn legend_ui(&mut self, ui: &mut egui::Ui, legend: &Legend, layer: UvLayer, i: usize) {
        ui.horizontal(|ui| {
            let what = match layer {
                UvLayer::StaticAlbedo | UvLayer::FrameAlbedo => "the person's albedo".to_owned(),
                _ => face::ICT_NAMES[i.min(NUM_BLENDSHAPES - 1)].to_owned(),
            };
            ui.label(format!("{}: {what}", layer.label()));
            let (name, low, high, colour): BarSpec = match legend {
                Legend::Colour => return,
                Legend::Sequential { max, unit } => (
                    "sequential",
                    "0".to_owned(),
                    format!("{max:.2} {unit}"),
                    |t| sequential(t, 1.0),
                ),
                Legend::Diverging { scale } => (
                    "diverging",
                    format!("-{scale:.3}"),
                    format!("+{scale:.3}"),
                    |t| diverging(2.0 * t - 1.0, 1.0),
                ),
            };
            let bar = self.bars.entry(name).or_insert_with(|| {
                let image = colour_bar(256, 12, colour);
                ui.ctx().load_texture(
                    format!("colour bar {name}"),
                    egui::ColorImage::from_rgba_unmultiplied([256, 12], image.as_raw()),
                    egui::TextureOptions::LINEAR,
                )
            });
            ui.separator();
            ui.label(low);
            ui.add(egui::Image::new((bar.id(), egui::vec2(160.0, 12.0))));
            ui.label(high);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masking_scales_each_texel_by_its_mask_value() {
        let mut mask = UvMap::zeros(2, 1, 1);
        mask.data = vec![0.5, 0.0];
        let mut map = UvMap::zeros(2, 1, 3);
        map.data = vec![2.0, -4.0, 6.0, 1.0, 1.0, 1.0];
        assert_eq!(
            masked(&mask, &map).data,
            vec![1.0, -2.0, 3.0, 0.0, 0.0, 0.0]
        );
    }
}
