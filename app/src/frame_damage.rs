//! Which parts of a window changed between two egui frames, from their tessellated
//! primitives: the software window (`soft_window`) redraws only those, because on a CPU
//! adapter every shaded pixel costs (about 6.5 ns at 1280x720 on two cores) while most of
//! the studio (side panel, toolbar) stays the same from one frame of a playing clip to the
//! next. Pure logic, no GPU.
//!
//! A primitive is unchanged when its clip rectangle, texture and mesh hash the same as one of
//! the previous frame's, in the same relative order. The damage is the bounds of everything
//! else, new or gone, plus every primitive whose texture changed: a managed texture with a
//! delta this frame, and always a user texture (the studio's 3D views are drawn into them
//! outside egui) or a paint callback. Anything this cannot reason about (the font atlas
//! changed, the order of unchanged primitives changed, a new size) is a full redraw.

use std::collections::HashMap;
use std::hash::{Hash, Hasher};

use egui::epaint::Primitive;
use egui::{ClippedPrimitive, Rect, TextureId};

/// What must be redrawn this frame.
#[derive(Clone, Debug, PartialEq)]
pub enum Damage {
    /// Everything.
    Full,
    /// Only these rectangles, in physical pixels, disjoint enough to draw one by one.
    Rects(Vec<Rect>),
}

/// What a frame drew, as [`FrameDamage`] remembers it for the next.
#[derive(Default)]
pub struct FrameDamage {
    previous: Option<Summary>,
}

struct Summary {
    size: [u32; 2],
    pixels_per_point: f32,
    clear: [u32; 4],
    /// Each primitive's hash and its drawn bounds (physical pixels), in painting order.
    primitives: Vec<(u64, Rect)>,
}

/// More rectangles than this are merged into their bounding box: each one is a pass over
/// the primitives it touches, and draw calls cost too.
const MAX_RECTS: usize = 8;

impl FrameDamage {
    /// The damage of the frame about to be drawn, which then becomes the previous frame.
    /// `shapes` are in points; the damage is in physical pixels of a `size` target.
    pub fn next(
        &mut self,
        shapes: &[ClippedPrimitive],
        textures: &egui::TexturesDelta,
        pixels_per_point: f32,
        size: [u32; 2],
        clear: [f32; 4],
    ) -> Damage {
        let changed_textures: Vec<TextureId> = textures.set.keys().copied().collect();
        let summary = Summary {
            size,
            pixels_per_point,
            clear: clear.map(f32::to_bits),
            primitives: shapes
                .iter()
                .map(|p| (primitive_hash(p), drawn_bounds(p, pixels_per_point, size)))
                .collect(),
        };
        let previous = self.previous.replace(summary);
        let current = self
            .previous
            .as_ref()
            .map_or(&[][..], |s| &s.primitives[..]);
        let Some(previous) = previous else {
            return Damage::Full;
        };
        if previous.size != size
            || previous.pixels_per_point != pixels_per_point
            || previous.clear != clear.map(f32::to_bits)
            || changed_textures.contains(&TextureId::default())
        {
            return Damage::Full;
        }
        // Where each previous primitive was, by hash (a hash can repeat: identical shapes).
        let mut before: HashMap<u64, Vec<usize>> = HashMap::new();
        for (index, (hash, _)) in previous.primitives.iter().enumerate() {
            before.entry(*hash).or_default().push(index);
        }
        let mut matched = vec![false; previous.primitives.len()];
        let mut last_match = None;
        let mut damaged = Vec::new();
        for (primitive, (hash, bounds)) in shapes.iter().zip(current) {
            if bounds.is_negative() {
                continue;
            }
            let texture_changed = match &primitive.primitive {
                Primitive::Mesh(mesh) => match mesh.texture_id {
                    TextureId::User(_) => true,
                    id => changed_textures.contains(&id),
                },
                Primitive::Callback(_) => true,
            };
            let earlier = before
                .get_mut(hash)
                .and_then(|indices| (!indices.is_empty()).then(|| indices.remove(0)));
            match earlier {
                Some(index) => {
                    // Unchanged primitives painted in another order can cover each other
                    // differently: not worth reasoning about.
                    if last_match.is_some_and(|last| index < last) {
                        return Damage::Full;
                    }
                    last_match = Some(index);
                    matched[index] = true;
                    if texture_changed {
                        damaged.push(*bounds);
                    }
                }
                None => damaged.push(*bounds),
            }
        }
        for ((_, bounds), matched) in previous.primitives.iter().zip(matched) {
            if !matched && !bounds.is_negative() {
                damaged.push(*bounds);
            }
        }
        Damage::Rects(merge(damaged))
    }

    /// Forgets the previous frame: the next damage is full (after the target was lost).
    pub fn reset(&mut self) {
        self.previous = None;
    }
}

/// Where `primitive` can change pixels: its mesh's bounds within its clip rectangle, in
/// physical pixels, rounded out to whole pixels and kept inside the target.
fn drawn_bounds(primitive: &ClippedPrimitive, pixels_per_point: f32, size: [u32; 2]) -> Rect {
    let extent = match &primitive.primitive {
        Primitive::Mesh(mesh) => mesh.calc_bounds(),
        Primitive::Callback(callback) => callback.rect,
    };
    let target = Rect::from_min_size(egui::Pos2::ZERO, egui::vec2(size[0] as f32, size[1] as f32));
    let shown = extent.intersect(primitive.clip_rect) * pixels_per_point;
    let rounded = Rect::from_min_max(shown.min.floor(), shown.max.ceil());
    if rounded.is_positive() {
        rounded.intersect(target)
    } else {
        Rect::NOTHING
    }
}

fn primitive_hash(primitive: &ClippedPrimitive) -> u64 {
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    let rect_bits = |r: Rect| [r.min.x, r.min.y, r.max.x, r.max.y].map(f32::to_bits);
    rect_bits(primitive.clip_rect).hash(&mut hasher);
    match &primitive.primitive {
        Primitive::Mesh(mesh) => {
            mesh.texture_id.hash(&mut hasher);
            mesh.indices.hash(&mut hasher);
            for v in &mesh.vertices {
                [v.pos.x, v.pos.y, v.uv.x, v.uv.y]
                    .map(f32::to_bits)
                    .hash(&mut hasher);
                v.color.to_array().hash(&mut hasher);
            }
        }
        Primitive::Callback(callback) => {
            // A callback draws what it wants: never the same twice.
            rect_bits(callback.rect).hash(&mut hasher);
            std::ptr::from_ref(callback).hash(&mut hasher);
            u64::MAX.hash(&mut hasher);
        }
    }
    hasher.finish()
}

/// Merges overlapping or touching rectangles, then everything into one bounding box if
/// more than [`MAX_RECTS`] remain.
fn merge(mut rects: Vec<Rect>) -> Vec<Rect> {
    rects.retain(|r| r.is_positive());
    let mut merged: Vec<Rect> = Vec::with_capacity(rects.len());
    for rect in rects {
        let mut rect = rect;
        // Absorb every merged rectangle this one touches, until none does.
        while let Some(i) = merged.iter().position(|m| m.expand(1.0).intersects(rect)) {
            rect = rect.union(merged.swap_remove(i));
        }
        merged.push(rect);
    }
    if merged.len() > MAX_RECTS {
        let all = merged.iter().fold(Rect::NOTHING, |a, r| a.union(*r));
        return vec![all];
    }
    merged
}

/// The share of a `size` target that `damage` redraws (0..1).
pub fn damaged_fraction(damage: &Damage, size: [u32; 2]) -> f64 {
    match damage {
        Damage::Full => 1.0,
        Damage::Rects(rects) => {
            let area: f64 = rects.iter().map(|r| f64::from(r.area())).sum();
            area / (f64::from(size[0]) * f64::from(size[1])).max(1.0)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use egui::epaint::{Color32, Mesh};

    fn quad(rect: Rect, colour: Color32, texture: TextureId) -> ClippedPrimitive {
        let mut mesh = Mesh::with_texture(texture);
        mesh.add_rect_with_uv(
            rect,
            Rect::from_min_max(egui::pos2(0.0, 0.0), egui::pos2(1.0, 1.0)),
            colour,
        );
        ClippedPrimitive {
            clip_rect: Rect::EVERYTHING,
            primitive: Primitive::Mesh(mesh),
        }
    }

    fn r(x0: f32, y0: f32, x1: f32, y1: f32) -> Rect {
        Rect::from_min_max(egui::pos2(x0, y0), egui::pos2(x1, y1))
    }

    const SIZE: [u32; 2] = [200, 100];
    const CLEAR: [f32; 4] = [0.1, 0.1, 0.1, 1.0];
    const FONT: TextureId = TextureId::Managed(0);

    fn damage(state: &mut FrameDamage, shapes: &[ClippedPrimitive], ppp: f32) -> Damage {
        state.next(shapes, &egui::TexturesDelta::default(), ppp, SIZE, CLEAR)
    }

    /// The rectangles of `damage`, left to right.
    fn sorted_rects(damage: Damage) -> Vec<Rect> {
        let Damage::Rects(mut rects) = damage else {
            panic!("expected rectangles, got {damage:?}");
        };
        rects.sort_by(|a, b| a.min.x.total_cmp(&b.min.x));
        rects
    }

    #[test]
    fn first_frame_and_a_new_size_are_full_and_a_repeat_is_empty() {
        let mut state = FrameDamage::default();
        let shapes = vec![quad(r(10.0, 10.0, 20.0, 20.0), Color32::RED, FONT)];
        assert_eq!(damage(&mut state, &shapes, 1.0), Damage::Full);
        assert_eq!(damage(&mut state, &shapes, 1.0), Damage::Rects(vec![]));
        assert_eq!(damage(&mut state, &shapes, 2.0), Damage::Full);
        assert_eq!(
            state.next(
                &shapes,
                &egui::TexturesDelta::default(),
                2.0,
                [201, 100],
                CLEAR
            ),
            Damage::Full
        );
    }

    #[test]
    fn a_moved_shape_damages_where_it_was_and_where_it_is() {
        let mut state = FrameDamage::default();
        let still = quad(r(0.0, 0.0, 50.0, 50.0), Color32::GRAY, FONT);
        damage(
            &mut state,
            &[
                still.clone(),
                quad(r(100.0, 10.0, 110.0, 20.0), Color32::RED, FONT),
            ],
            1.0,
        );
        let d = damage(
            &mut state,
            &[still, quad(r(150.0, 60.0, 160.0, 70.0), Color32::RED, FONT)],
            1.0,
        );
        let rects = sorted_rects(d);
        assert_eq!(
            rects,
            vec![r(100.0, 10.0, 110.0, 20.0), r(150.0, 60.0, 160.0, 70.0)]
        );
        assert!(
            (damaged_fraction(&Damage::Rects(rects.clone()), SIZE) - 200.0 / 20_000.0).abs()
                < 1e-12
        );
    }

    #[test]
    fn damage_is_in_physical_pixels_clipped_and_rounded_out() {
        let mut state = FrameDamage::default();
        damage(&mut state, &[], 2.0);
        let mut clipped = quad(r(10.2, 10.2, 90.0, 20.7), Color32::RED, FONT);
        clipped.clip_rect = r(0.0, 0.0, 60.0, 100.0);
        assert_eq!(
            damage(&mut state, &[clipped], 2.0),
            Damage::Rects(vec![r(20.0, 20.0, 120.0, 42.0)])
        );
    }

    #[test]
    fn texture_changes_damage_their_users_and_the_font_atlas_everything() {
        let mut state = FrameDamage::default();
        let picture = quad(
            r(0.0, 0.0, 40.0, 40.0),
            Color32::WHITE,
            TextureId::Managed(3),
        );
        let view = quad(r(50.0, 0.0, 90.0, 40.0), Color32::WHITE, TextureId::User(1));
        let text = quad(r(100.0, 0.0, 140.0, 40.0), Color32::WHITE, FONT);
        let shapes = vec![picture, view, text];
        damage(&mut state, &shapes, 1.0);
        // A user texture (a 3D view) may change any frame.
        assert_eq!(
            damage(&mut state, &shapes, 1.0),
            Damage::Rects(vec![r(50.0, 0.0, 90.0, 40.0)])
        );
        let delta = |id| {
            let mut delta = egui::TexturesDelta::default();
            let image = egui::ColorImage::new([1, 1], vec![Color32::RED; 1]);
            delta.set.insert(
                id,
                [egui::epaint::ImageDelta::full(
                    image,
                    egui::TextureOptions::LINEAR,
                )]
                .into(),
            );
            delta
        };
        let mut picture_changed = delta(TextureId::Managed(3));
        let d = state.next(&shapes, &picture_changed, 1.0, SIZE, CLEAR);
        // egui asserts (debug builds) that a delta is applied or cleared before it drops.
        picture_changed.clear();
        let rects = sorted_rects(d);
        assert_eq!(
            rects,
            vec![r(0.0, 0.0, 40.0, 40.0), r(50.0, 0.0, 90.0, 40.0)]
        );
        let mut atlas_changed = delta(FONT);
        let d = state.next(&shapes, &atlas_changed, 1.0, SIZE, CLEAR);
        atlas_changed.clear();
        assert_eq!(d, Damage::Full);
    }

    #[test]
    fn unchanged_shapes_in_another_order_are_a_full_redraw() {
        let mut state = FrameDamage::default();
        let a = quad(r(0.0, 0.0, 50.0, 50.0), Color32::RED, FONT);
        let b = quad(r(25.0, 25.0, 75.0, 75.0), Color32::BLUE, FONT);
        damage(&mut state, &[a.clone(), b.clone()], 1.0);
        assert_eq!(damage(&mut state, &[b, a], 1.0), Damage::Full);
    }

    #[test]
    fn touching_rectangles_merge_and_many_become_one_box() {
        assert_eq!(
            merge(vec![
                r(0.0, 0.0, 10.0, 10.0),
                r(10.0, 0.0, 20.0, 10.0),
                r(50.0, 50.0, 60.0, 60.0)
            ])
            .len(),
            2
        );
        let many: Vec<Rect> = (0..20)
            .map(|i| r(i as f32 * 10.0, 0.0, i as f32 * 10.0 + 5.0, 5.0))
            .collect();
        assert_eq!(merge(many), vec![r(0.0, 0.0, 195.0, 5.0)]);
    }
}
