//! The project's own puppets, generated in code: stylized heads with the 52 ARKit morph
//! targets authored as displacement rules, written as GLB into `assets/puppets/`.
//!
//! A head is a superellipsoid (exponent 2 = ellipsoid, larger = boxier) with features as
//! decals lying on its surface: eye whites, pupils, brows, mouth, tongue, and a nose part.
//! A decal vertex has local coordinates (s, t) around its feature's centre, in radians of
//! longitude and latitude on the head; a morph target either remaps those coordinates
//! (a blink squashes the eye's t towards its centre line; a smile lifts the mouth corner)
//! and the delta is the difference of the two surface points, or moves skin with a smooth
//! 3D field (jaw, cheeks) that every part in the region follows. Nothing is random, so
//! regeneration gives the same bytes on the same platform.
//!
//! The two styles differ on purpose in shape, colour and file conventions: `pip` (round,
//! warm, ARKit camelCase names in `mesh.extras.targetNames`) and `bolt` (boxy robot, cool,
//! Live Link Face PascalCase names with an exporter prefix, given only as accessor names).

use std::f32::consts::PI;
use std::path::Path;

use face::names::{ARKIT_NAMES, NUM_ARKIT};
use glam::Vec3;
use serde_json::json;

use crate::error::{Result, RetargetError};
use crate::glb::{ARRAY_BUFFER, GlbBuilder};
use crate::names::live_link_name;

/// How a style names its morph targets in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TargetNaming {
    /// ARKit camelCase in `mesh.extras.targetNames`.
    ArkitExtras,
    /// `blendShape1.` + Live Link Face PascalCase, on the target accessors only.
    PrefixedPascalAccessors,
}

#[derive(Clone, Debug)]
pub struct PuppetStyle {
    pub name: &'static str,
    /// Head radii in metres (x, y, z) and the superellipsoid exponent.
    pub radii: Vec3,
    pub exponent: f32,
    pub skin: [f32; 4],
    pub eye_white: [f32; 4],
    pub pupil: [f32; 4],
    pub brow: [f32; 4],
    pub mouth: [f32; 4],
    pub tongue: [f32; 4],
    pub nose: [f32; 4],
    /// Eye half-size (s, t) and centre (u, v), in the normalised front-plane coordinates of
    /// `Head::front` (1 = the head's radius).
    pub eye_size: (f32, f32),
    pub eye_center: (f32, f32),
    pub pupil_size: f32,
    pub mouth_size: (f32, f32),
    pub mouth_latitude: f32,
    pub brow_size: (f32, f32),
    pub brow_latitude: f32,
    pub nose_size: Vec3,
    pub naming: TargetNaming,
    /// Node names: root, optional neck, head (the mesh).
    pub nodes: (&'static str, Option<&'static str>, &'static str),
}

/// The project's puppets.
pub fn styles() -> Vec<PuppetStyle> {
    vec![
        PuppetStyle {
            name: "pip",
            radii: Vec3::new(0.10, 0.115, 0.10),
            exponent: 2.0,
            skin: [0.96, 0.70, 0.36, 1.0],
            eye_white: [0.97, 0.97, 0.95, 1.0],
            pupil: [0.10, 0.16, 0.35, 1.0],
            brow: [0.36, 0.20, 0.10, 1.0],
            mouth: [0.35, 0.05, 0.08, 1.0],
            tongue: [0.92, 0.42, 0.48, 1.0],
            nose: [0.93, 0.50, 0.30, 1.0],
            eye_size: (0.20, 0.24),
            eye_center: (0.36, 0.16),
            pupil_size: 0.09,
            mouth_size: (0.34, 0.07),
            mouth_latitude: -0.38,
            brow_size: (0.20, 0.035),
            brow_latitude: 0.50,
            nose_size: Vec3::new(0.018, 0.015, 0.02),
            naming: TargetNaming::ArkitExtras,
            nodes: ("Pip", None, "Head"),
        },
        PuppetStyle {
            name: "bolt",
            radii: Vec3::new(0.11, 0.10, 0.09),
            exponent: 6.0,
            skin: [0.52, 0.58, 0.68, 1.0],
            eye_white: [0.30, 0.90, 1.00, 1.0],
            pupil: [0.03, 0.10, 0.20, 1.0],
            brow: [0.15, 0.17, 0.22, 1.0],
            mouth: [0.05, 0.06, 0.08, 1.0],
            tongue: [0.95, 0.35, 0.25, 1.0],
            nose: [0.85, 0.62, 0.15, 1.0],
            eye_size: (0.26, 0.13),
            eye_center: (0.40, 0.12),
            pupil_size: 0.07,
            mouth_size: (0.45, 0.06),
            mouth_latitude: -0.40,
            brow_size: (0.28, 0.03),
            brow_latitude: 0.40,
            nose_size: Vec3::new(0.012, 0.012, 0.012),
            naming: TargetNaming::PrefixedPascalAccessors,
            nodes: ("Bolt", Some("Neck"), "J_Head"),
        },
    ]
}

/// Which feature a part is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Feature {
    Skin,
    EyeWhite(Side),
    Pupil(Side),
    Brow(Side),
    Mouth,
    Tongue,
    Nose,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Left,
    Right,
}

impl Side {
    /// +1 for the puppet's left (+x), -1 for its right.
    fn sign(self) -> f32 {
        match self {
            Side::Left => 1.0,
            Side::Right => -1.0,
        }
    }
}

/// One drawn part: its rest vertices with their decal coordinates, and triangles.
struct Part {
    feature: Feature,
    color: [f32; 4],
    /// Decal coordinates (s, t) relative to the feature centre (skin: longitude, latitude).
    local: Vec<(f32, f32)>,
    /// How far above the head surface the part lies (decals stack without z-fighting).
    lift: f32,
    center: (f32, f32),
    triangles: Vec<[u32; 3]>,
}

struct Head<'a> {
    style: &'a PuppetStyle,
}

impl Head<'_> {
    /// The superellipsoid |x/a|^e + |y/b|^e + |z/c|^e = 1 at longitude `lon` (0 = front,
    /// +z; positive towards +x) and latitude `lat` (positive up): the skin's grid.
    fn surface(&self, lon: f32, lat: f32) -> Vec3 {
        let e = 2.0 / self.style.exponent;
        let f = |v: f32| v.signum() * v.abs().powf(e);
        let (cl, sl) = (lat.cos(), lat.sin());
        let (co, so) = (lon.cos(), lon.sin());
        let r = self.style.radii;
        Vec3::new(r.x * f(cl) * f(so), r.y * f(sl), r.z * f(cl) * f(co))
    }

    /// The point of the head's front half at normalised front-plane coordinates (u, v)
    /// (x = u * radius x, y = v * radius y), pushed out along the normal by `lift`. Features
    /// are laid out in this plane so that they keep their shape on boxy heads too (the
    /// longitude-latitude parameters crowd towards the centre of a superellipsoid's faces).
    fn front(&self, u: f32, v: f32, lift: f32) -> Vec3 {
        let e = self.style.exponent;
        let r = self.style.radii;
        let rest = (1.0 - u.abs().powf(e) - v.abs().powf(e)).max(0.0);
        let p = Vec3::new(r.x * u, r.y * v, r.z * rest.powf(1.0 / e));
        p + self.implicit_normal(p) * lift
    }

    /// The normal of |x/a|^e + |y/b|^e + |z/c|^e = 1 at a point on it.
    fn implicit_normal(&self, q: Vec3) -> Vec3 {
        let e = self.style.exponent;
        let r = self.style.radii;
        let g = |x: f32, a: f32| x.signum() * (x / a).abs().powf(e - 1.0) / a;
        let n = Vec3::new(g(q.x, r.x), g(q.y, r.y), g(q.z, r.z)).normalize_or_zero();
        if n == Vec3::ZERO { Vec3::Z } else { n }
    }
}

fn smoothstep(edge0: f32, edge1: f32, x: f32) -> f32 {
    let t = ((x - edge0) / (edge1 - edge0)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

fn ellipse_disc(
    rings: usize,
    segments: usize,
    size: (f32, f32),
) -> (Vec<(f32, f32)>, Vec<[u32; 3]>) {
    let mut local = vec![(0.0, 0.0)];
    for r in 1..=rings {
        let rr = r as f32 / rings as f32;
        for k in 0..segments {
            let a = 2.0 * PI * k as f32 / segments as f32;
            local.push((rr * size.0 * a.cos(), rr * size.1 * a.sin()));
        }
    }
    let mut tris = Vec::new();
    let ring = |r: usize, k: usize| (1 + (r - 1) * segments + k % segments) as u32;
    for k in 0..segments {
        tris.push([0, ring(1, k), ring(1, k + 1)]);
    }
    for r in 1..rings {
        for k in 0..segments {
            let (a, b, c, d) = (
                ring(r, k),
                ring(r, k + 1),
                ring(r + 1, k),
                ring(r + 1, k + 1),
            );
            tris.push([a, c, d]);
            tris.push([a, d, b]);
        }
    }
    (local, tris)
}

fn grid(nx: usize, ny: usize, size: (f32, f32)) -> (Vec<(f32, f32)>, Vec<[u32; 3]>) {
    let mut local = Vec::new();
    for j in 0..=ny {
        for i in 0..=nx {
            local.push((
                (i as f32 / nx as f32 * 2.0 - 1.0) * size.0,
                (j as f32 / ny as f32 * 2.0 - 1.0) * size.1,
            ));
        }
    }
    let mut tris = Vec::new();
    let at = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
    for j in 0..ny {
        for i in 0..nx {
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    (local, tris)
}

fn build_parts(style: &PuppetStyle) -> Vec<Part> {
    let mut parts = Vec::new();
    // Skin: a longitude-latitude grid, poles excluded by a hair to keep normals defined.
    let (nu, nv) = (64usize, 40usize);
    let mut local = Vec::new();
    for j in 0..=nv {
        let lat = -PI / 2.0 * 0.999 + PI * 0.999 * j as f32 / nv as f32;
        for i in 0..nu {
            local.push((-PI + 2.0 * PI * i as f32 / nu as f32, lat));
        }
    }
    let mut tris = Vec::new();
    for j in 0..nv {
        for i in 0..nu {
            let at = |i: usize, j: usize| (j * nu + i % nu) as u32;
            tris.push([at(i, j), at(i + 1, j), at(i + 1, j + 1)]);
            tris.push([at(i, j), at(i + 1, j + 1), at(i, j + 1)]);
        }
    }
    parts.push(Part {
        feature: Feature::Skin,
        color: style.skin,
        local,
        lift: 0.0,
        center: (0.0, 0.0),
        triangles: tris,
    });
    for side in [Side::Left, Side::Right] {
        let center = (side.sign() * style.eye_center.0, style.eye_center.1);
        let (l, t) = ellipse_disc(6, 32, style.eye_size);
        parts.push(Part {
            feature: Feature::EyeWhite(side),
            color: style.eye_white,
            local: l,
            lift: 0.0015,
            center,
            triangles: t,
        });
        let (l, t) = ellipse_disc(4, 24, (style.pupil_size, style.pupil_size));
        parts.push(Part {
            feature: Feature::Pupil(side),
            color: style.pupil,
            local: l,
            lift: 0.003,
            center,
            triangles: t,
        });
        let (l, t) = grid(10, 2, style.brow_size);
        let brow_center = (side.sign() * style.eye_center.0, style.brow_latitude);
        parts.push(Part {
            feature: Feature::Brow(side),
            color: style.brow,
            local: l,
            lift: 0.0015,
            center: brow_center,
            triangles: t,
        });
    }
    let (l, t) = ellipse_disc(6, 40, style.mouth_size);
    parts.push(Part {
        feature: Feature::Mouth,
        color: style.mouth,
        local: l,
        lift: 0.0015,
        center: (0.0, style.mouth_latitude),
        triangles: t,
    });
    // The tongue rests collapsed to a point inside the mouth; tongueOut unfolds it.
    let (l, t) = ellipse_disc(3, 20, (style.mouth_size.0 * 0.45, style.mouth_size.1 * 1.6));
    parts.push(Part {
        feature: Feature::Tongue,
        color: style.tongue,
        local: l,
        lift: 0.003,
        center: (0.0, style.mouth_latitude - style.mouth_size.1 * 0.3),
        triangles: t,
    });
    let (l, t) = ellipse_disc(5, 20, (1.0, 1.0));
    parts.push(Part {
        feature: Feature::Nose,
        color: style.nose,
        local: l,
        lift: 0.0,
        center: (0.0, (style.eye_center.1 + style.mouth_latitude) * 0.5),
        triangles: t,
    });
    parts
}

/// The rest position of a part's vertex.
fn rest_position(head: &Head, part: &Part, (s, t): (f32, f32)) -> Vec3 {
    match part.feature {
        Feature::Skin => head.surface(s, t),
        Feature::Tongue => head.front(part.center.0, part.center.1, part.lift),
        Feature::Nose => {
            // A half-ellipsoid bump: the disc's radius r becomes height sqrt(1 - r^2).
            let n = head.style.nose_size;
            let base = head.front(part.center.0, part.center.1, 0.0);
            let r2 = (s * s + t * t).min(1.0);
            base + Vec3::new(s * n.x, t * n.y, (1.0 - r2).sqrt() * n.z)
        }
        _ => head.front(part.center.0 + s, part.center.1 + t, part.lift),
    }
}

/// Where a decal vertex's (s, t) goes under `shape` at full weight (identity when the shape
/// does not touch the feature).
fn remap(style: &PuppetStyle, feature: Feature, shape: &str, (s, t): (f32, f32)) -> (f32, f32) {
    // `mouthLeft` / `mouthRight` (like `jawLeft` / `jawRight`) are directions, not one side
    // of a pair: they keep their whole name as the stem.
    let directional = matches!(shape, "mouthLeft" | "mouthRight" | "jawLeft" | "jawRight");
    let (stem, shape_side) = match (shape.strip_suffix("Left"), shape.strip_suffix("Right")) {
        (Some(stem), _) if !directional => (stem, Some(Side::Left)),
        (_, Some(stem)) if !directional => (stem, Some(Side::Right)),
        _ => (shape, None),
    };
    let (ms, mt) = style.mouth_size;
    let (es, et) = style.eye_size;
    match feature {
        Feature::EyeWhite(side) | Feature::Pupil(side) if shape_side == Some(side) => {
            let is_pupil = matches!(feature, Feature::Pupil(_));
            // Inward is towards the nose: -x for the left eye.
            let inward = -side.sign();
            match stem {
                "eyeBlink" => (s, t * 0.04 - 0.02 * et),
                "eyeWide" => (s * 1.08, t * 1.35),
                "eyeSquint" => (s, if t < 0.0 { t * 0.35 } else { t * 0.85 }),
                "eyeLookUp" if is_pupil => (s, t + 0.55 * et),
                "eyeLookDown" if is_pupil => (s, t - 0.55 * et),
                "eyeLookIn" if is_pupil => (s + inward * 0.6 * es, t),
                "eyeLookOut" if is_pupil => (s - inward * 0.6 * es, t),
                _ => (s, t),
            }
        }
        Feature::Brow(side) => {
            let outer = (s * side.sign() / style.brow_size.0).clamp(-1.0, 1.0); // +1 at the outer end
            let lift = 2.5 * style.brow_size.1;
            match shape {
                "browInnerUp" => (s, t + lift * (1.0 - outer) * 0.5),
                _ if shape_side == Some(side) && stem == "browDown" => (
                    s - side.sign() * 0.02,
                    t - lift * 0.6 - lift * 0.3 * (1.0 - outer),
                ),
                _ if shape_side == Some(side) && stem == "browOuterUp" => {
                    (s, t + lift * (1.0 + outer) * 0.5)
                }
                _ => (s, t),
            }
        }
        Feature::Mouth | Feature::Tongue => {
            let corner = |side: Side| ((s * side.sign()) / ms).clamp(0.0, 1.0).powi(2);
            let on_side = |side: Option<Side>| {
                side.map_or(1.0, |sd| if s * sd.sign() >= 0.0 { 1.0 } else { 0.0 })
            };
            let upper = if t > 0.0 { 1.0 } else { 0.0 };
            let lower = 1.0 - upper;
            match (stem, feature) {
                ("tongueOut", Feature::Tongue) => (s, t - 1.2 * mt),
                (_, Feature::Tongue) => (s, t),
                ("mouthClose", _) => (s, t * 0.25),
                ("mouthFunnel", _) => (s * 0.55, t * 1.6),
                ("mouthPucker", _) => (s * 0.45, t * 0.6),
                ("mouthLeft", _) => (s + 0.12 * ms, t),
                ("mouthRight", _) => (s - 0.12 * ms, t),
                ("mouthSmile", _) => {
                    let sd = shape_side.unwrap_or(Side::Left);
                    (
                        s + sd.sign() * 0.12 * ms * corner(sd),
                        t + 2.2 * mt * corner(sd),
                    )
                }
                ("mouthFrown", _) => {
                    let sd = shape_side.unwrap_or(Side::Left);
                    (s, t - 1.8 * mt * corner(sd))
                }
                ("mouthDimple", _) => {
                    let sd = shape_side.unwrap_or(Side::Left);
                    (s + sd.sign() * 0.15 * ms * corner(sd), t)
                }
                ("mouthStretch", _) => {
                    let sd = shape_side.unwrap_or(Side::Left);
                    (
                        s + sd.sign() * 0.2 * ms * corner(sd),
                        t - 0.8 * mt * corner(sd),
                    )
                }
                ("mouthRollLower", _) => (s, t * (1.0 - 0.6 * lower)),
                ("mouthRollUpper", _) => (s, t * (1.0 - 0.6 * upper)),
                ("mouthShrugLower", _) => (s, t + 0.8 * mt * lower),
                ("mouthShrugUpper", _) => (s, t + 0.8 * mt * upper),
                ("mouthPress", _) => (s, t * (1.0 - 0.7 * on_side(shape_side))),
                ("mouthLowerDown", _) => (s, t - 1.5 * mt * lower * on_side(shape_side)),
                ("mouthUpperUp", _) => (s, t + 1.5 * mt * upper * on_side(shape_side)),
                _ => (s, t),
            }
        }
        _ => (s, t),
    }
}

/// A smooth 3D field moving skin (and every part on it) for shapes that move the jaw,
/// cheeks or nose; zero elsewhere.
fn skin_field(style: &PuppetStyle, head: &Head, shape: &str, p: Vec3) -> Vec3 {
    let r = style.radii;
    let front = smoothstep(-0.2, 0.5, p.z / r.z);
    let mouth_y = head.front(0.0, style.mouth_latitude, 0.0).y;
    // 1 below the mouth line, fading out towards the ears and above it.
    let below = smoothstep(mouth_y + 0.15 * r.y, mouth_y - 0.25 * r.y, p.y) * front;
    let near = |lon: f32, lat: f32, radius: f32| {
        let c = head.front(lon, lat, 0.0);
        let d = (p - c).length() / (radius * r.x);
        (1.0 - d * d).max(0.0).powi(2)
    };
    let nose_lat = (style.eye_center.1 + style.mouth_latitude) * 0.5;
    match shape {
        "jawOpen" => Vec3::new(0.0, -0.28 * r.y, -0.06 * r.z) * below,
        "jawForward" => Vec3::new(0.0, 0.0, 0.12 * r.z) * below,
        "jawLeft" => Vec3::new(0.12 * r.x, 0.0, 0.0) * below,
        "jawRight" => Vec3::new(-0.12 * r.x, 0.0, 0.0) * below,
        "cheekPuff" => {
            let w = near(0.65, style.mouth_latitude * 0.6, 0.55)
                + near(-0.65, style.mouth_latitude * 0.6, 0.55);
            let n = head.implicit_normal(p);
            n * 0.12 * r.x * w
        }
        "cheekSquintLeft" => {
            Vec3::new(0.0, 0.06 * r.y, 0.02 * r.z)
                * near(style.eye_center.0, style.eye_center.1 - 0.3, 0.35)
        }
        "cheekSquintRight" => {
            Vec3::new(0.0, 0.06 * r.y, 0.02 * r.z)
                * near(-style.eye_center.0, style.eye_center.1 - 0.3, 0.35)
        }
        "noseSneerLeft" => Vec3::new(0.01 * r.x, 0.08 * r.y, 0.0) * near(0.12, nose_lat, 0.3),
        "noseSneerRight" => Vec3::new(-0.01 * r.x, 0.08 * r.y, 0.0) * near(-0.12, nose_lat, 0.3),
        "mouthPucker" | "mouthFunnel" => {
            Vec3::new(0.0, 0.0, 0.10 * r.z) * near(0.0, style.mouth_latitude, 0.45)
        }
        _ => Vec3::ZERO,
    }
}

/// A generated puppet: per part, rest positions, normals, triangles and 52 delta sets.
pub struct GeneratedPart {
    pub name: String,
    pub color: [f32; 4],
    pub positions: Vec<Vec3>,
    pub normals: Vec<Vec3>,
    pub triangles: Vec<[u32; 3]>,
    pub targets: Vec<Vec<Vec3>>,
}

pub fn generate(style: &PuppetStyle) -> Vec<GeneratedPart> {
    let head = Head { style };
    build_parts(style)
        .into_iter()
        .map(|part| {
            let positions: Vec<Vec3> = part
                .local
                .iter()
                .map(|&st| rest_position(&head, &part, st))
                .collect();
            let targets: Vec<Vec<Vec3>> = ARKIT_NAMES
                .iter()
                .map(|shape| {
                    part.local
                        .iter()
                        .zip(&positions)
                        .map(|(&st, &p)| {
                            let moved = match part.feature {
                                Feature::Skin | Feature::Nose => p,
                                Feature::Tongue if *shape == "tongueOut" => {
                                    let (s, t) = remap(style, part.feature, shape, st);
                                    head.front(part.center.0 + s, part.center.1 + t, part.lift)
                                        + Vec3::new(0.0, 0.0, 0.25 * style.radii.z)
                                }
                                Feature::Tongue => p,
                                _ => {
                                    let (s, t) = remap(style, part.feature, shape, st);
                                    head.front(part.center.0 + s, part.center.1 + t, part.lift)
                                }
                            };
                            moved - p + skin_field(style, &head, shape, p)
                        })
                        .collect()
                })
                .collect();
            let normals = face::geometry::vertex_normals(&positions, &part.triangles);
            let name = match part.feature {
                Feature::Skin => "skin".to_owned(),
                Feature::EyeWhite(s) => format!("eye_white_{s:?}").to_lowercase(),
                Feature::Pupil(s) => format!("pupil_{s:?}").to_lowercase(),
                Feature::Brow(s) => format!("brow_{s:?}").to_lowercase(),
                Feature::Mouth => "mouth".to_owned(),
                Feature::Tongue => "tongue".to_owned(),
                Feature::Nose => "nose".to_owned(),
            };
            GeneratedPart {
                name,
                color: part.color,
                positions,
                normals,
                triangles: part.triangles,
                targets,
            }
        })
        .collect()
}

/// The morph target names a style writes.
pub fn target_names(style: &PuppetStyle) -> Vec<String> {
    (0..NUM_ARKIT)
        .map(|a| match style.naming {
            TargetNaming::ArkitExtras => ARKIT_NAMES[a].to_owned(),
            TargetNaming::PrefixedPascalAccessors => format!("blendShape1.{}", live_link_name(a)),
        })
        .collect()
}

/// The GLB bytes of a style.
pub fn glb_bytes(style: &PuppetStyle) -> std::result::Result<Vec<u8>, String> {
    let parts = generate(style);
    let names = target_names(style);
    let mut doc = GlbBuilder::new(
        json!({"asset": {"version": "2.0", "generator": "Likeness puppet generator (retarget::generator)"}}),
        Vec::new(),
    );
    let mut primitives = Vec::new();
    for part in &parts {
        let flat = |v: &[Vec3]| -> Vec<f32> { v.iter().flat_map(|p| p.to_array()).collect() };
        let position = doc.float_accessor(&flat(&part.positions), "VEC3", Some(ARRAY_BUFFER), true);
        let normal = doc.float_accessor(&flat(&part.normals), "VEC3", Some(ARRAY_BUFFER), false);
        let indices: Vec<u32> = part.triangles.iter().flatten().copied().collect();
        let index = doc.index_accessor(&indices);
        let mut targets = Vec::new();
        for (a, deltas) in part.targets.iter().enumerate() {
            let accessor = doc.float_accessor(&flat(deltas), "VEC3", Some(ARRAY_BUFFER), true);
            if style.naming == TargetNaming::PrefixedPascalAccessors {
                doc.json["accessors"][accessor]["name"] = json!(names[a]);
            }
            targets.push(json!({"POSITION": accessor}));
        }
        let material = doc.push("materials", json!({"name": format!("{}_{}", style.name, part.name), "pbrMetallicRoughness": {"baseColorFactor": part.color, "metallicFactor": 0.0, "roughnessFactor": 0.55}}));
        primitives.push(json!({"attributes": {"POSITION": position, "NORMAL": normal}, "indices": index, "material": material, "targets": targets}));
    }
    let mut mesh = json!({"name": format!("{}_face", style.name), "primitives": primitives, "weights": vec![0.0; NUM_ARKIT]});
    if style.naming == TargetNaming::ArkitExtras {
        mesh["extras"] = json!({"targetNames": names});
    }
    let mesh = doc.push("meshes", mesh);
    let (root, neck, head) = style.nodes;
    let head_node = doc.push("nodes", json!({"name": head, "mesh": mesh, "translation": [0.0, if neck.is_some() { 0.08 } else { 0.0 }, 0.0]}));
    let mut top = head_node;
    if let Some(neck) = neck {
        top = doc.push(
            "nodes",
            json!({"name": neck, "children": [top], "translation": [0.0, 0.0, 0.0]}),
        );
    }
    let root = doc.push("nodes", json!({"name": root, "children": [top]}));
    doc.json["scenes"] = json!([{"name": style.name, "nodes": [root]}]);
    doc.json["scene"] = json!(0);
    doc.json["extras"] =
        json!({"likeness": {"generator": "retarget::generator", "style": style.name}});
    doc.finish()
}

/// Writes every style as `<dir>/<name>.glb`; returns the paths.
pub fn write_all(dir: &Path) -> Result<Vec<std::path::PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|e| RetargetError::Write {
        path: dir.to_owned(),
        reason: e.to_string(),
    })?;
    let mut written = Vec::new();
    for style in styles() {
        let path = dir.join(format!("{}.glb", style.name));
        let bytes = glb_bytes(&style).map_err(|reason| RetargetError::Write {
            path: path.clone(),
            reason,
        })?;
        files::write_atomically(&path, &bytes)?;
        written.push(path);
    }
    Ok(written)
}
