//! Equations (2) and (3), masks and geometry on the real template, each against an
//! independent expectation (a literal transcription of the paper, an analytic value or a
//! finite difference).

// The checks index several parallel arrays by blendshape or coordinate on purpose.
#![allow(clippy::needless_range_loop)]

use std::sync::OnceLock;

use face::camera::{HeadPose, Intrinsics, project_with_jacobians};
use face::geometry::{Adjacency, blendshape_gradient_loss, deformation_gradients, vertex_normals};
use face::masks::{MASK_THRESHOLD_CM, vertex_attention};
use face::sampling::sample_sites;
use face::uv::{CORRECTION_SIZE, UvMap};
use face::{
    BlendshapeWeights, FaceModel, ICT_NAMES, NUM_BLENDSHAPES, PersonalCorrections, Template,
};
use glam::{Mat3, Vec2, Vec3};

fn model() -> &'static FaceModel {
    static MODEL: OnceLock<FaceModel> = OnceLock::new();
    MODEL.get_or_init(|| {
        let path = face::template::default_template_path();
        let template = Template::load_safetensors(&path)
            .unwrap_or_else(|e| panic!("the template is needed for these tests: {e}"));
        FaceModel::new(template)
    })
}

/// Deterministic pseudo-random numbers in [-1, 1] (no rand dependency for tests).
fn noise(seed: u32) -> f32 {
    let mut x = seed.wrapping_mul(0x9E37_79B9) ^ 0x85EB_CA6B;
    x ^= x >> 16;
    x = x.wrapping_mul(0x7FEB_352D);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846C_A68B);
    x ^= x >> 16;
    (x as f32 / u32::MAX as f32) * 2.0 - 1.0
}

fn smooth_map(seed: u32, amplitude: f32) -> UvMap {
    let (a, b, c) = (noise(seed), noise(seed + 1), noise(seed + 2));
    UvMap::from_fn(CORRECTION_SIZE, CORRECTION_SIZE, 3, |uv| {
        vec![
            amplitude * (a * (6.0 * uv.x).sin() + 0.3 * (9.0 * uv.y).cos()),
            amplitude * (b * (5.0 * uv.y).sin() + 0.2 * uv.x),
            amplitude * c * (4.0 * (uv.x + uv.y)).cos(),
        ]
    })
}

fn random_corrections() -> PersonalCorrections {
    PersonalCorrections {
        identity_shape: smooth_map(1, 0.3),
        expression_shapes: (0..NUM_BLENDSHAPES)
            .map(|i| smooth_map(100 + 7 * i as u32, 0.2))
            .collect(),
        static_albedo: smooth_map(5, 0.05),
        dynamic_albedo: (0..NUM_BLENDSHAPES)
            .map(|i| smooth_map(900 + 5 * i as u32, 0.1))
            .collect(),
    }
}

fn sparse_weights() -> BlendshapeWeights {
    let mut w = [0.0; NUM_BLENDSHAPES];
    for (i, name) in [
        "jawOpen",
        "mouthSmile_L",
        "eyeBlink_R",
        "browInnerUp_L",
        "cheekPuff_R",
    ]
    .iter()
    .enumerate()
    {
        w[face::names::ict_index(name).unwrap()] = 0.2 + 0.15 * i as f32;
    }
    BlendshapeWeights(w)
}

#[test]
fn equation_2_without_corrections_is_the_linear_blendshape_model() {
    let m = model();
    let t = &m.template;
    let person = m.personalize(&PersonalCorrections::zeros()).unwrap();
    let w = sparse_weights();
    let shape = person.shape(&w);
    // The linear model written with full blendshape meshes S_i = S_0 + delta_i and w_0.
    let w0 = 1.0 - w.0.iter().sum::<f32>();
    for v in (0..t.vertex_count()).step_by(7) {
        let mut expected = w0 * t.neutral[v];
        for i in 0..NUM_BLENDSHAPES {
            expected += w.0[i] * (t.neutral[v] + t.expression_delta(i)[v]);
        }
        assert!((shape[v] - expected).length() < 1e-4, "vertex {v}");
    }
}

#[test]
fn equation_2_with_corrections_matches_the_papers_formula() {
    let m = model();
    let t = &m.template;
    let corrections = random_corrections();
    let person = m.personalize(&corrections).unwrap();
    let w = sparse_weights();
    let shape = person.shape(&w);
    let sites = sample_sites(t);
    // F written literally: weight * bilinear sample of the (masked) map at the site's UV.
    let f = |map: &UvMap, v: usize| -> Vec3 {
        sites[v].map_or(Vec3::ZERO, |s| {
            s.weight * Vec3::from_slice(&map.sample(s.uv))
        })
    };
    let masked: Vec<UvMap> = (0..NUM_BLENDSHAPES)
        .map(|i| {
            let mut p = corrections.expression_shapes[i].clone();
            for (k, px) in p.data.chunks_exact_mut(3).enumerate() {
                let a = m.masks.mask(i).data[k];
                px.iter_mut().for_each(|x| *x *= a);
            }
            p
        })
        .collect();
    let w0 = w.neutral_weight();
    let template_person = m.template_blendshapes();
    let mut checked_corrected = 0;
    for v in (0..t.vertex_count()).step_by(11) {
        let mut expected = w0 * t.neutral[v] + f(&corrections.identity_shape, v);
        for i in 0..NUM_BLENDSHAPES {
            let s_i = t.neutral[v] + t.expression_delta(i)[v];
            expected += w.0[i] * (s_i + f(&masked[i], v));
        }
        assert!(
            (shape[v] - expected).length() < 1e-4,
            "vertex {v}: {} vs {}",
            shape[v],
            expected
        );
        if (shape[v] - template_person.vertex(v, &w)).length() > 1e-3 {
            checked_corrected += 1;
        }
    }
    assert!(
        checked_corrected > 100,
        "the corrections must actually move vertices"
    );
}

#[test]
fn rigid_parts_get_no_correction_and_stitched_parts_follow_the_face() {
    let m = model();
    let t = &m.template;
    let person = m.personalize(&random_corrections()).unwrap();
    let teeth = t.part("teeth").unwrap().vertices.clone();
    for v in teeth.step_by(13) {
        assert_eq!(person.base[v as usize], t.neutral[v as usize]);
    }
    // Head vertices share triangles with face vertices; those close to the face must carry
    // exactly the correction of their nearest face vertex, or the shared triangles tear.
    let face = t.face_vertices();
    let correction = |v: usize| person.base[v] - t.neutral[v];
    let mut seams = 0;
    for tri in &t.triangles {
        let Some(&h) = tri
            .iter()
            .find(|&&v| t.vertex_part(v) == Some("head_and_neck"))
        else {
            continue;
        };
        if !tri.iter().any(|v| face.contains(v)) {
            continue;
        }
        let hp = t.neutral[h as usize];
        let (f, dist) = face
            .clone()
            .map(|f| (f, t.neutral[f as usize].distance(hp)))
            .fold((0, f32::MAX), |best, c| if c.1 < best.1 { c } else { best });
        if dist <= face::sampling::ATTACH_FULL_CM {
            seams += 1;
            assert!((correction(h as usize) - correction(f as usize)).length() < 1e-5);
        }
        if seams > 30 {
            break;
        }
    }
    assert!(seams > 30, "expected head vertices stitched to the face");
}

#[test]
fn a_vertex_on_a_uv_seam_samples_one_uv() {
    let t = &model().template;
    let mut uvs_of: Vec<Vec<u32>> = vec![Vec::new(); t.vertex_count()];
    for tri in t.face_triangles() {
        for k in 0..3 {
            uvs_of[t.triangles[tri][k] as usize].push(t.triangle_uvs[tri][k]);
        }
    }
    let chosen = t.face_vertex_uvs();
    let mut seam_vertices = 0;
    for (v, list) in uvs_of.iter().enumerate() {
        let mut distinct = list.clone();
        distinct.sort_unstable();
        distinct.dedup();
        if distinct.len() > 1 {
            seam_vertices += 1;
            assert_eq!(chosen[v], Some(t.uvs[distinct[0] as usize]));
        }
    }
    assert!(
        seam_vertices > 0,
        "the face part has UV seams (the ears and the mouth)"
    );
}

#[test]
fn mask_support_is_the_set_of_vertices_that_move() {
    let m = model();
    let t = &m.template;
    let face_uvs = t.face_vertex_uvs();
    for name in ["jawOpen", "eyeBlink_L", "browDown_R", "mouthSmile_L"] {
        let i = face::names::ict_index(name).unwrap();
        let attention = vertex_attention(t, i);
        let moving: Vec<bool> = t
            .expression_delta(i)
            .iter()
            .map(|d| d.length() > MASK_THRESHOLD_CM)
            .collect();
        for v in 0..t.vertex_count() {
            assert_eq!(attention[v] > 0.0, moving[v], "{name} vertex {v}");
            assert!((0.0..=1.0).contains(&attention[v]));
        }
        // In UV space: positive at every moving face vertex; zero at face vertices that
        // move less than the threshold and lie well away (> 10 texels) from any moving one.
        let mask = m.masks.mask(i);
        let moving_uvs: Vec<Vec2> = (0..t.vertex_count())
            .filter(|&v| moving[v])
            .filter_map(|v| face_uvs[v])
            .collect();
        // Blur radius 3 + padding 2 + bilinear 1 texels, plus one triangle of interpolation.
        let far = 10.0 / CORRECTION_SIZE as f32;
        let mut zeros_checked = 0;
        for v in (0..t.vertex_count()).step_by(3) {
            let Some(uv) = face_uvs[v] else { continue };
            let a = mask.sample(uv)[0];
            if moving[v] {
                assert!(a > 0.0, "{name}: moving vertex {v} has mask 0");
            } else if moving_uvs.iter().all(|m| m.distance(uv) > far) {
                assert!(
                    a < 1e-6,
                    "{name}: static vertex {v} far from the support has mask {a}"
                );
                zeros_checked += 1;
            }
        }
        assert!(zeros_checked > 100, "{name}: the mask must be local");
        let max = mask.data.iter().cloned().fold(0.0f32, f32::max);
        assert!(max > 0.5 && max <= 1.0, "{name}: max {max}");
    }
}

#[test]
fn equation_3_albedo() {
    let m = model();
    let r0 = UvMap::from_fn(64, 64, 3, |uv| vec![0.6 + 0.1 * uv.x, 0.4, 0.3 * uv.y]);
    let zero = PersonalCorrections::zeros();
    let w = sparse_weights();
    assert_eq!(m.albedo(&r0, &zero, &w).unwrap(), r0);

    let corrections = random_corrections();
    let albedo = m.albedo(&r0, &corrections, &w).unwrap();
    // Literal transcription at a few texels: R0 + dR0 + sum_i w_i A_i dR_i, each term
    // sampled at the texel centre (sampling is linear, so the order does not matter).
    for &(x, y) in &[(10usize, 20usize), (32, 40), (50, 33)] {
        let uv = face::uv::texel_center_uv(x, y, 64, 64);
        let mut expected = Vec3::from_slice(r0.texel(x, y))
            + Vec3::from_slice(&corrections.static_albedo.sample(uv));
        for i in 0..NUM_BLENDSHAPES {
            let mut product = corrections.dynamic_albedo[i].clone();
            for (k, px) in product.data.chunks_exact_mut(3).enumerate() {
                let a = m.masks.mask(i).data[k];
                px.iter_mut().for_each(|p| *p *= a);
            }
            expected += w.0[i] * Vec3::from_slice(&product.sample(uv));
        }
        let got = Vec3::from_slice(albedo.texel(x, y));
        assert!(
            (got - expected).length() < 1e-5,
            "texel {x},{y}: {got} vs {expected}"
        );
    }
}

/// The per-frame part of equation (3) on the 128 x 128 grid: dR_0 + sum_i w_i A_i dR_i,
/// transcribed texel by texel; non-finite values it uses are errors, ones it does not use
/// (a dR_i whose weight is 0) are not its concern.
#[test]
fn equation_3_albedo_correction() {
    let m = model();
    let corrections = random_corrections();
    let w = sparse_weights();
    let correction = m.albedo_correction(&corrections, &w).unwrap();
    for t in [0usize, 5000, 8191, 12345, 16383] {
        for c in 0..3 {
            let mut expected = corrections.static_albedo.data[3 * t + c];
            for i in 0..NUM_BLENDSHAPES {
                expected += w.0[i]
                    * m.masks.mask(i).data[t]
                    * corrections.dynamic_albedo[i].data[3 * t + c];
            }
            let got = correction.data[3 * t + c];
            assert!(
                (got - expected).abs() < 1e-5,
                "texel {t}.{c}: {got} vs {expected}"
            );
        }
    }
    let used = w.0.iter().position(|&x| x != 0.0).unwrap();
    let unused = w.0.iter().position(|&x| x == 0.0).unwrap();
    let mut bad = corrections.clone();
    bad.dynamic_albedo[unused].data.fill(f32::NAN);
    assert!(m.albedo_correction(&bad, &w).is_ok());
    assert!(
        m.albedo(&UvMap::zeros(8, 8, 3), &bad, &w).is_err(),
        "albedo validates all"
    );
    // A NaN anywhere in a used map reaches the result (0 x NaN is NaN).
    bad.dynamic_albedo[used].data.fill(f32::NAN);
    assert!(m.albedo_correction(&bad, &w).is_err());
    let mut nan_weight = w;
    nan_weight.0[used] = f32::NAN;
    assert!(m.albedo_correction(&corrections, &nan_weight).is_err());
    let mut small = corrections.clone();
    small.static_albedo = UvMap::zeros(4, 4, 3);
    assert!(m.albedo_correction(&small, &w).is_err());
}

#[test]
fn weights_are_validated() {
    let mut values = vec![0.0f32; NUM_BLENDSHAPES];
    values[3] = 1.5;
    values[7] = -0.2;
    let (w, report) = BlendshapeWeights::from_slice_clamped(&values).unwrap();
    assert_eq!(w.0[3], 1.0);
    assert_eq!(w.0[7], 0.0);
    assert_eq!(
        report.clamped,
        vec![(ICT_NAMES[3], 1.5), (ICT_NAMES[7], -0.2)]
    );
    values[0] = f32::NAN;
    let err = BlendshapeWeights::from_slice_clamped(&values)
        .unwrap_err()
        .to_string();
    assert!(err.contains(ICT_NAMES[0]), "{err}");
    assert!(BlendshapeWeights::from_slice_clamped(&values[..10]).is_err());

    let mut bad = PersonalCorrections::zeros();
    bad.expression_shapes[2].data[5] = f32::INFINITY;
    let err = model().personalize(&bad).unwrap_err().to_string();
    assert!(err.contains(ICT_NAMES[2]), "{err}");
}

#[test]
fn equation_2_jacobian_matches_finite_differences() {
    let m = model();
    let person = m.personalize(&random_corrections()).unwrap();
    let w = sparse_weights();
    let v = m.template.landmarks_68[48] as usize;
    let jac = person.vertex_jacobian(v);
    let h = 1e-2;
    for i in [0usize, 26, 45] {
        let mut plus = w;
        plus.0[i] += h;
        let mut minus = w;
        minus.0[i] -= h;
        let fd = (person.vertex(v, &plus) - person.vertex(v, &minus)) / (2.0 * h);
        assert!((fd - jac[i]).length() < 1e-3, "{i}: {fd} vs {}", jac[i]);
    }
}

#[test]
fn deformation_gradient_of_a_rigid_rotation_is_that_rotation() {
    let t = &model().template;
    let rotation = Mat3::from_axis_angle(Vec3::new(0.3, -0.5, 0.8).normalize(), 0.7);
    let rotated: Vec<Vec3> = t
        .neutral
        .iter()
        .map(|p| rotation * *p + Vec3::new(1.0, 2.0, 3.0))
        .collect();
    let tris: Vec<[u32; 3]> = t.face_triangles().map(|k| t.triangles[k]).collect();
    let g = deformation_gradients(&t.neutral, &rotated, &tris);
    for gi in g.iter().step_by(17) {
        assert!(
            (*gi - rotation).abs_diff_eq(Mat3::ZERO, 1e-3),
            "{gi} vs {rotation}"
        );
    }
    // Uniform scaling by s gives s I (the fourth vertex scales like the edges).
    let scaled: Vec<Vec3> = t.neutral.iter().map(|p| 1.7 * *p).collect();
    for gi in deformation_gradients(&t.neutral, &scaled, &tris)
        .iter()
        .step_by(17)
    {
        assert!((*gi - 1.7 * Mat3::IDENTITY).abs_diff_eq(Mat3::ZERO, 1e-3));
    }
}

#[test]
fn blendshape_gradient_loss_is_zero_for_the_template_and_grows_with_a_correction() {
    let m = model();
    let t = &m.template;
    let i = face::names::ict_index("jawOpen").unwrap();
    let tris: Vec<[u32; 3]> = t.face_triangles().map(|k| t.triangles[k]).collect();
    let s_i: Vec<Vec3> = t
        .neutral
        .iter()
        .zip(t.expression_delta(i))
        .map(|(a, d)| *a + *d)
        .collect();
    assert!(blendshape_gradient_loss(&t.neutral, &s_i, &s_i, &tris) < 1e-6);
    let mut last = 0.0;
    for scale in [0.05f32, 0.1, 0.2] {
        let bent: Vec<Vec3> = s_i
            .iter()
            .enumerate()
            .map(|(v, p)| {
                *p + scale * Vec3::new((v as f32 * 0.37).sin(), 0.0, (v as f32 * 0.11).cos())
            })
            .collect();
        let loss = blendshape_gradient_loss(&t.neutral, &s_i, &bent, &tris);
        assert!(loss > last, "{loss} must grow past {last}");
        last = loss;
    }
}

#[test]
fn laplacian_smoothness_and_its_gradient() {
    let t = &model().template;
    let face = t.face_vertices().end as usize;
    let tris: Vec<[u32; 3]> = t.face_triangles().map(|k| t.triangles[k]).collect();
    let adj = Adjacency::from_triangles(face, &tris);
    // A constant correction is perfectly smooth.
    let constant = vec![Vec3::new(0.3, -0.1, 0.2); face];
    assert_eq!(adj.smoothness_loss(&constant), 0.0);
    assert!(adj.laplacian(&constant).iter().all(|l| l.length() < 1e-6));
    // Gradient by central differences on a few coordinates.
    let x: Vec<Vec3> = (0..face)
        .map(|v| Vec3::new(noise(v as u32), noise(v as u32 + 9), 0.0) * 0.1)
        .collect();
    let grad = adj.smoothness_gradient(&x);
    let h = 1e-3;
    for v in [5usize, 400, 3000] {
        let mut plus = x.clone();
        plus[v].x += h;
        let mut minus = x.clone();
        minus[v].x -= h;
        let fd = (adj.smoothness_loss(&plus) as f64 - adj.smoothness_loss(&minus) as f64)
            / (2.0 * h as f64);
        assert!(
            (fd as f32 - grad[v].x).abs() < 2e-2 * (1.0 + grad[v].x.abs()),
            "{v}: {fd} vs {}",
            grad[v].x
        );
    }
}

#[test]
fn normals_point_out_of_the_face() {
    let t = &model().template;
    let normals = vertex_normals(&t.neutral, &t.triangles);
    // The nose tip (landmark 30) looks towards the viewer (+z).
    let nose = normals[t.landmarks_68[30] as usize];
    assert!(nose.z > 0.8, "{nose}");
    assert!(normals.iter().all(|n| (n.length() - 1.0).abs() < 1e-4));
}

#[test]
fn projection_jacobians_match_finite_differences() {
    let k = Intrinsics::from_fov(640, 480, 40.0);
    let pose = HeadPose::from_degrees(20.0, -10.0, 5.0, Vec3::new(1.0, -2.0, -55.0));
    let p = Vec3::new(3.0, 2.0, 9.0);
    let (pixel, d_pose, d_point) = project_with_jacobians(&k, &pose, p).unwrap();
    let proj = |pose: &HeadPose, p: Vec3| k.project(pose.transform(p)).unwrap();
    assert!((pixel - proj(&pose, p)).length() < 1e-4);
    let h = 1e-3;
    for j in 0..6 {
        let mut a = pose;
        let mut b = pose;
        if j < 3 {
            a.euler_rad[j] += h;
            b.euler_rad[j] -= h;
        } else {
            a.translation[j - 3] += h;
            b.translation[j - 3] -= h;
        }
        let fd = (proj(&a, p) - proj(&b, p)) / (2.0 * h);
        assert!(
            (fd - d_pose[j]).length() < 1e-2 * (1.0 + fd.length()),
            "pose {j}: {fd} vs {}",
            d_pose[j]
        );
    }
    for j in 0..3 {
        let mut e = Vec3::ZERO;
        e[j] = h;
        let fd = (proj(&pose, p + e) - proj(&pose, p - e)) / (2.0 * h);
        assert!(
            (fd - d_point[j]).length() < 1e-2 * (1.0 + fd.length()),
            "point {j}"
        );
    }
}

#[test]
fn clip_matrix_agrees_with_pixel_projection() {
    let mut k = Intrinsics::from_fov(800, 600, 35.0);
    k.cx = 390.0;
    k.cy = 310.0;
    let clip = k.clip_from_view(1.0, 500.0);
    for p in [Vec3::new(3.0, 2.0, -50.0), Vec3::new(-8.0, 5.0, -70.0)] {
        let c = clip * p.extend(1.0);
        let ndc = c.truncate() / c.w;
        let px = Vec2::new((ndc.x + 1.0) * 0.5 * 800.0, (1.0 - ndc.y) * 0.5 * 600.0);
        assert!((px - k.project(p).unwrap()).length() < 1e-2, "{px}");
        assert!((0.0..=1.0).contains(&ndc.z));
    }
}

#[test]
fn constant_sh_light_shades_every_normal_alike_and_gradients_match() {
    let gamma = face::sh::constant_light(0.9);
    for k in 0..50 {
        let n = Vec3::new(noise(k), noise(k + 100), noise(k + 200)).normalize();
        let c = face::sh::shade(Vec3::new(0.5, 0.4, 0.3), n, &gamma);
        assert!((c - Vec3::new(0.45, 0.36, 0.27)).length() < 1e-5, "{c}");
    }
    let n = Vec3::new(0.3, -0.4, 0.8).normalize();
    let grad = face::sh::sh_basis_gradient(n);
    let h = 1e-3;
    for j in 0..3 {
        let mut e = Vec3::ZERO;
        e[j] = h;
        let (a, b) = (face::sh::sh_basis(n + e), face::sh::sh_basis(n - e));
        for k in 0..9 {
            let fd = (a[k] - b[k]) / (2.0 * h);
            assert!(
                (fd - grad[k][j]).abs() < 1e-3,
                "Y{k} d{j}: {fd} vs {}",
                grad[k][j]
            );
        }
    }
    // The studio light is brighter on a surface facing its key light than facing away.
    let studio = face::sh::studio_light();
    let key = face::sh::KEY_LIGHT_DIRECTION.normalize();
    let lit = face::sh::irradiance(key, &studio);
    let dark = face::sh::irradiance(Vec3::new(-key.x, -key.y, key.z), &studio);
    assert!(lit.x > dark.x + 0.2);
}
