//! The UV face-parsing map T of the paper's parsing loss.
//!
//! The paper renders T with the personalised mesh and compares it with a face parser's
//! segmentation of the input frame, so that the mesh's lips, brows, eyes and nose land where
//! the image has them. T lives in the same UV layers as R_0 ([`AlbedoLayer`]) and is cut
//! along the same landmark contours ([`crate::albedo`]'s shared regions), so the albedo's
//! lips are exactly the parsing map's lips.

use glam::Vec2;

use crate::albedo::{ALBEDO_SIZE, AlbedoLayer, FaceRegions, LayerRaster, Surface, TemplateRegions};
use crate::template::Template;
use crate::uv::texel_center_uv;

/// A face-parsing class, in the order of the label maps' bytes.
#[repr(u8)]
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ParsingLabel {
    /// No surface: outside every chart, and the mouth and eye holes of the face tile.
    Background = 0,
    Skin,
    Brows,
    /// Eye openings with lid margins, eyeballs, eye sockets and eyelashes.
    Eyes,
    Nose,
    UpperLip,
    LowerLip,
    /// Mouth socket, gums, tongue and teeth.
    MouthInterior,
    /// Back of the head and the neck, outside the paper's face region.
    RestOfHead,
}

impl ParsingLabel {
    pub const ALL: [ParsingLabel; 9] = [
        ParsingLabel::Background,
        ParsingLabel::Skin,
        ParsingLabel::Brows,
        ParsingLabel::Eyes,
        ParsingLabel::Nose,
        ParsingLabel::UpperLip,
        ParsingLabel::LowerLip,
        ParsingLabel::MouthInterior,
        ParsingLabel::RestOfHead,
    ];

    pub fn name(self) -> &'static str {
        match self {
            ParsingLabel::Background => "background",
            ParsingLabel::Skin => "skin",
            ParsingLabel::Brows => "brows",
            ParsingLabel::Eyes => "eyes",
            ParsingLabel::Nose => "nose",
            ParsingLabel::UpperLip => "upper_lip",
            ParsingLabel::LowerLip => "lower_lip",
            ParsingLabel::MouthInterior => "mouth_interior",
            ParsingLabel::RestOfHead => "rest_of_head",
        }
    }

    /// A display colour, distinct for every label.
    pub fn color(self) -> [u8; 3] {
        match self {
            ParsingLabel::Background => [0, 0, 0],
            ParsingLabel::Skin => [236, 188, 150],
            ParsingLabel::Brows => [110, 60, 20],
            ParsingLabel::Eyes => [30, 120, 255],
            ParsingLabel::Nose => [255, 220, 0],
            ParsingLabel::UpperLip => [230, 20, 80],
            ParsingLabel::LowerLip => [150, 0, 190],
            ParsingLabel::MouthInterior => [0, 190, 110],
            ParsingLabel::RestOfHead => [128, 128, 128],
        }
    }

    /// The label stored as byte `b`, if it is one.
    pub fn from_u8(b: u8) -> Option<ParsingLabel> {
        ParsingLabel::ALL.get(usize::from(b)).copied()
    }
}

/// T: one `size` x `size` label map per [`AlbedoLayer`], bytes as [`ParsingLabel`], row 0
/// at v = 1 (the texel convention of [`crate::uv`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ParsingMap {
    pub size: usize,
    /// In [`AlbedoLayer::ALL`] order.
    pub layers: Vec<Vec<u8>>,
}

/// Texels a chart's labels are grown into empty space, so a nearest-texel lookup anywhere on
/// a triangle (including its edge, whose nearest texel centre may lie just outside) finds a
/// label; one texel keeps the mouth and eye holes open.
const LABEL_GROWTH_TEXELS: usize = 1;

impl ParsingMap {
    /// Labels every layer of the template at [`ALBEDO_SIZE`].
    pub fn generate(template: &Template) -> ParsingMap {
        let regions = TemplateRegions::new(template);
        let size = ALBEDO_SIZE;
        let layers = AlbedoLayer::ALL
            .iter()
            .map(|&layer| {
                let mut raster = LayerRaster::new(&regions, layer, size);
                raster.grow(LABEL_GROWTH_TEXELS);
                (0..size * size)
                    .map(|k| {
                        let uv = texel_center_uv(k % size, k / size, size, size);
                        let surface = raster
                            .at(k)
                            .and_then(|t| regions.surfaces[t])
                            .map(|(_, s)| s);
                        label_surface(surface, uv, regions.face.as_ref()) as u8
                    })
                    .collect()
            })
            .collect();
        ParsingMap { size, layers }
    }

    /// The label of the texel nearest to `uv`, given in `layer`'s tile (the template UV minus
    /// [`AlbedoLayer::uv_offset`]). Outside the tile the edge texel answers.
    pub fn label_at(&self, layer: AlbedoLayer, uv: Vec2) -> ParsingLabel {
        let Some(map) = self.layers.get(layer.index()) else {
            return ParsingLabel::Background;
        };
        let n = self.size;
        if n == 0 {
            return ParsingLabel::Background;
        }
        // Saturating float-to-int casts send NaN and negatives to 0.
        let x = ((uv.x * n as f32) as usize).min(n - 1);
        let y = (((1.0 - uv.y) * n as f32) as usize).min(n - 1);
        map.get(y * n + x)
            .and_then(|&b| ParsingLabel::from_u8(b))
            .unwrap_or(ParsingLabel::Background)
    }

    /// `layer` as RGB8 in each label's [`ParsingLabel::color`], row 0 at the top.
    pub fn to_rgb8(&self, layer: AlbedoLayer) -> Vec<u8> {
        let Some(map) = self.layers.get(layer.index()) else {
            return vec![0; self.size * self.size * 3];
        };
        map.iter()
            .flat_map(|&b| {
                ParsingLabel::from_u8(b)
                    .unwrap_or(ParsingLabel::Background)
                    .color()
            })
            .collect()
    }
}

/// The label of a texel of surface `surface` at `uv`; face-tile labels come from the
/// landmark regions shared with R_0.
fn label_surface(surface: Option<Surface>, uv: Vec2, face: Option<&FaceRegions>) -> ParsingLabel {
    match surface {
        None => ParsingLabel::Background,
        Some(Surface::FaceSkin) => face.map_or(ParsingLabel::Skin, |f| face_label(f, uv)),
        Some(Surface::HeadSkin) => ParsingLabel::RestOfHead,
        Some(Surface::MouthSocket | Surface::Gums | Surface::Tongue | Surface::Teeth) => {
            ParsingLabel::MouthInterior
        }
        Some(Surface::EyeSocket | Surface::Eyeball | Surface::Eyelashes) => ParsingLabel::Eyes,
    }
}

/// Face-tile label: eyes over brows over lips over nose over skin, so that where grown
/// regions meet, the smaller, more distinctive feature wins.
fn face_label(f: &FaceRegions, uv: Vec2) -> ParsingLabel {
    if f.eye_sd(uv) <= FaceRegions::EYE_GROWTH * f.scale {
        ParsingLabel::Eyes
    } else if f.brow_sd(uv).0 <= 0.0 {
        ParsingLabel::Brows
    } else if f.upper_lip_sd(uv) <= 0.0 {
        ParsingLabel::UpperLip
    } else if f.lower_lip_sd(uv) <= 0.0 {
        ParsingLabel::LowerLip
    } else if f.nose_sd(uv) <= 0.0 {
        ParsingLabel::Nose
    } else {
        ParsingLabel::Skin
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::albedo::{landmark_uvs, triangle_layer};

    fn template() -> Template {
        crate::template::test_template()
    }

    /// UV (in its layer's tile) of some corner of a triangle whose vertices all lie in
    /// `part`, and that triangle.
    fn triangle_in_part(template: &Template, part: &str) -> (usize, AlbedoLayer) {
        let range = match template.part(part) {
            Some(p) => p.vertices.clone(),
            None => panic!("template has no part {part}"),
        };
        (0..template.triangles.len())
            .find_map(|t| {
                let inside = template.triangles[t].iter().all(|v| range.contains(v));
                let layer = triangle_layer(template, t)?;
                inside.then_some((t, layer))
            })
            .unwrap_or_else(|| panic!("no drawn triangle in part {part}"))
    }

    fn centroid_uv(template: &Template, t: usize, layer: AlbedoLayer) -> Vec2 {
        let sum: Vec2 = template.triangle_uvs[t]
            .iter()
            .map(|&k| template.uvs[k as usize])
            .sum();
        sum / 3.0 - Vec2::new(layer.uv_offset(), 0.0)
    }

    #[test]
    fn parsing_labels_at_independent_points() {
        let template = template();
        let map = ParsingMap::generate(&template);
        assert_eq!(map.size, ALBEDO_SIZE);
        assert_eq!(map.layers.len(), AlbedoLayer::ALL.len());
        let lm = landmark_uvs(&template).expect("every landmark has a face-tile UV");
        let face = |uv: Vec2| map.label_at(AlbedoLayer::Face, uv);
        let mid = |a: usize, b: usize| 0.5 * (lm[a] + lm[b]);

        assert_eq!(face(mid(51, 62)), ParsingLabel::UpperLip);
        assert_eq!(face(mid(57, 66)), ParsingLabel::LowerLip);
        assert_eq!(face(lm[19]), ParsingLabel::Brows);
        assert_eq!(face(lm[24]), ParsingLabel::Brows);
        assert_eq!(face(lm[30]), ParsingLabel::Nose);
        assert_eq!(face(mid(2, 31)), ParsingLabel::Skin);
        assert_eq!(face(mid(14, 35)), ParsingLabel::Skin);
        for eye in [[37, 38, 40, 41], [43, 44, 46, 47]] {
            let centre = eye.iter().map(|&i| lm[i]).sum::<Vec2>() / 4.0;
            // The eye slit itself has no triangles; just above and below it is the lid margin.
            let lid = 0.5 * (centre + lm[eye[0]]);
            assert_eq!(face(lid), ParsingLabel::Eyes, "eye {eye:?}");
        }
        let mouth_hole = (60..68).map(|i| lm[i]).sum::<Vec2>() / 8.0;
        assert_eq!(face(mouth_hole), ParsingLabel::Background);
        // Forehead centre and a face-tile corner.
        assert_eq!(face(lm[27] + 1.2 * (lm[27] - lm[30])), ParsingLabel::Skin);
        assert_eq!(face(Vec2::new(0.0, 0.0)), ParsingLabel::Background);

        // Eyeball: the shell's UV nearest to the layout centre is the front of the iris.
        let eyeball = template.part("eyeball_left").map(|p| p.vertices.clone());
        let eyeball = eyeball.unwrap_or_else(|| panic!("no eyeball_left part"));
        let iris_centre = (0..template.triangles.len())
            .filter(|&t| triangle_layer(&template, t) == Some(AlbedoLayer::Eyeball))
            .filter(|&t| eyeball.contains(&template.triangles[t][0]))
            .flat_map(|t| template.triangle_uvs[t])
            .map(|k| template.uvs[k as usize])
            .min_by(|a, b| {
                let c = Vec2::splat(0.5);
                a.distance(c).total_cmp(&b.distance(c))
            })
            .unwrap_or_else(|| panic!("no eyeball UVs"));
        assert!(iris_centre.distance(Vec2::splat(0.5)) < 0.02);
        assert_eq!(
            map.label_at(AlbedoLayer::Eyeball, iris_centre),
            ParsingLabel::Eyes
        );

        let (t, layer) = triangle_in_part(&template, "teeth");
        assert_eq!(layer, AlbedoLayer::Teeth);
        let k = template.triangle_uvs[t][0] as usize;
        let teeth_uv = template.uvs[k] - Vec2::new(layer.uv_offset(), 0.0);
        assert_eq!(map.label_at(layer, teeth_uv), ParsingLabel::MouthInterior);

        let (t, layer) = triangle_in_part(&template, "mouth_socket");
        assert_eq!(layer, AlbedoLayer::Head);
        let uv = centroid_uv(&template, t, layer);
        assert_eq!(map.label_at(layer, uv), ParsingLabel::MouthInterior);

        let (t, layer) = triangle_in_part(&template, "head_and_neck");
        let uv = centroid_uv(&template, t, layer);
        assert_eq!(map.label_at(layer, uv), ParsingLabel::RestOfHead);

        let (t, layer) = triangle_in_part(&template, "gums_and_tongue");
        let uv = centroid_uv(&template, t, layer);
        assert_eq!(map.label_at(layer, uv), ParsingLabel::MouthInterior);

        let (t, layer) = triangle_in_part(&template, "eyelashes_left");
        let uv = centroid_uv(&template, t, layer);
        assert_eq!(map.label_at(layer, uv), ParsingLabel::Eyes);
    }

    #[test]
    fn every_face_triangle_corner_has_a_face_label() {
        let template = template();
        let map = ParsingMap::generate(&template);
        for t in template.face_triangles() {
            for &k in &template.triangle_uvs[t] {
                let label = map.label_at(AlbedoLayer::Face, template.uvs[k as usize]);
                assert_ne!(label, ParsingLabel::Background, "triangle {t} corner {k}");
            }
        }
    }

    #[test]
    fn parsing_labels_round_trip_and_have_distinct_colours() {
        for (i, label) in ParsingLabel::ALL.iter().enumerate() {
            assert_eq!(*label as usize, i);
            assert_eq!(ParsingLabel::from_u8(i as u8), Some(*label));
            for other in &ParsingLabel::ALL[i + 1..] {
                assert_ne!(label.color(), other.color());
                assert_ne!(label.name(), other.name());
            }
        }
        assert_eq!(ParsingLabel::from_u8(9), None);
    }

    #[test]
    fn parsing_map_is_deterministic_and_displayable() {
        let template = template();
        let a = ParsingMap::generate(&template);
        assert_eq!(a, ParsingMap::generate(&template));
        for layer in AlbedoLayer::ALL {
            let rgb = a.to_rgb8(layer);
            assert_eq!(rgb.len(), a.size * a.size * 3);
        }
    }

    /// Writes the label maps as binary PPMs to /tmp for looking at T by eye:
    /// `cargo test -p face dump_parsing -- --ignored`.
    #[test]
    #[ignore]
    fn dump_parsing_layers_to_tmp() {
        let template = template();
        let map = ParsingMap::generate(&template);
        for layer in AlbedoLayer::ALL {
            let mut bytes = format!("P6\n{} {}\n255\n", map.size, map.size).into_bytes();
            bytes.extend(map.to_rgb8(layer));
            let path = std::env::temp_dir().join(format!("parsing_{}.ppm", layer.name()));
            if let Err(e) = std::fs::write(&path, bytes) {
                panic!("cannot write {path:?}: {e}");
            }
        }
    }
}
