"""Parity of the Python F and equations (2)/(3) with the Rust `face` crate (issue 3, item 1:
max abs difference <= 1e-5), through the reference evaluation in the Rust fixture."""

import json

import numpy as np
import pytest
import torch
from safetensors.numpy import save_file

from likeness_train.face import (
    CORRECTION_SIZE,
    NUM_BLENDSHAPES,
    FixtureError,
    load_fixture,
    resample_uv,
    texel_centers,
    uv_grid,
)

TOL = 1e-5


def _ref_inputs(fx):
    w = torch.from_numpy(fx.ref_weights)[None]
    shape_maps = torch.from_numpy(fx.ref_shape_corrections).permute(0, 3, 1, 2)  # [54, 3, H, W]
    albedo_maps = torch.from_numpy(fx.ref_albedo_corrections).permute(0, 3, 1, 2)
    return w, shape_maps[0][None], shape_maps[1:][None], albedo_maps[0][None], albedo_maps[1:][None]


def test_equation_2_matches_rust(face_model):
    fx = face_model.fixture
    w, dS0, dS, _, _ = _ref_inputs(fx)
    shape = face_model.shape(w, dS0, dS)[0]
    diff = (shape - torch.from_numpy(fx.ref_shape)).abs().max().item()
    print(f"equation (2) max abs difference vs Rust: {diff:.3e} cm over {shape.shape[0]} vertices")
    assert diff <= TOL
    # The per-blendshape path (sample each A_i dS_i, then weight) must agree too.
    per_shape = face_model.neutral + face_model.sample_uv(dS0)[0] + torch.einsum(
        "i,ivc->vc", w[0], face_model.blendshapes(dS)[0]
    )
    diff2 = (per_shape - torch.from_numpy(fx.ref_shape)).abs().max().item()
    print(f"equation (2) via blendshapes(): {diff2:.3e} cm")
    assert diff2 <= TOL
    # The corrections actually matter in the reference (otherwise parity proves nothing).
    assert (shape - face_model.shape(w)[0]).abs().max() > 0.05


def test_equation_3_matches_rust(face_model):
    fx = face_model.fixture
    w, _, _, dR0, dR = _ref_inputs(fx)
    albedo = face_model.albedo(w, dR0, dR)[0].permute(1, 2, 0)
    diff = (albedo - torch.from_numpy(fx.ref_albedo)).abs().max().item()
    print(f"equation (3) max abs difference vs Rust: {diff:.3e} on the {albedo.shape[0]}^2 face layer")
    assert diff <= TOL
    assert (albedo - torch.from_numpy(fx.mean_albedo[0])).abs().max() > 0.05


def test_face_region_equals_full_mesh_restricted(face_model, face_region_model):
    fx = face_model.fixture
    w, dS0, dS, _, _ = _ref_inputs(fx)
    region = face_model.face_region()
    full = region.select(face_model.shape(w, dS0, dS))
    small = face_region_model.shape(w, dS0, dS)
    assert small.shape[1] == len(region.vertices) == 9409
    assert torch.equal(full, small)
    # Re-indexed triangles and landmarks point at the same positions.
    tris_full = torch.from_numpy(face_model.template.triangles)[region.triangle_ids]
    assert torch.equal(region.vertices[region.triangles], tris_full)
    assert torch.equal(region.vertices[region.landmarks_68], face_model.landmarks_68)


def test_resample_matches_grid_sample_at_texel_centres():
    # Equation (3) upsamples with F.interpolate; it must equal sampling at the 512 texel
    # centres with the F convention (grid_sample, border), which is what Rust does.
    g = torch.Generator().manual_seed(0)
    maps = torch.randn(2, 3, CORRECTION_SIZE, CORRECTION_SIZE, generator=g)
    grid = uv_grid(texel_centers(512))[None].expand(2, -1, -1, -1)
    ref = torch.nn.functional.grid_sample(maps, grid, mode="bilinear", padding_mode="border", align_corners=False)
    assert (resample_uv(maps, 512) - ref).abs().max() < 1e-5


def test_sample_sites_of_face_vertices_are_their_template_uvs(face_model):
    # Rust-independent recomputation of F's sites on the face part: each face vertex samples
    # at its own UV (smallest uv index among face triangles, face/src/template.rs) with
    # weight 1; teeth, gums and eyeballs get weight 0.
    t, fx = face_model.template, face_model.fixture
    tris = t.triangles[fx.face_triangle_ids]
    tri_uvs = t.triangle_uvs[fx.face_triangle_ids]
    best = np.full(t.vertex_count, np.iinfo(np.int64).max)
    np.minimum.at(best, tris.ravel(), tri_uvs.ravel())
    face = np.arange(*t.parts["face"])
    assert (best[face] < np.iinfo(np.int64).max).all()
    np.testing.assert_array_equal(fx.sample_uv[face], t.uvs[best[face]])
    assert (fx.sample_weight[face] == 1.0).all()
    for part in ("teeth", "gums_and_tongue", "eyeball_left", "eyeball_right"):
        if part in t.parts:
            assert (fx.sample_weight[slice(*t.parts[part])] == 0.0).all(), part
    # F of a linear ramp reproduces the ramp at face vertices (bilinear is exact on linear
    # functions away from the clamped border half-texel).
    c = texel_centers(CORRECTION_SIZE)
    ramp = torch.stack([c[..., 0], c[..., 1], 2 * c[..., 0] - c[..., 1]])[None]
    got = face_model.sample_uv(ramp)[0, face].numpy()
    uv = fx.sample_uv[face]
    inner = ((uv > 0.5 / CORRECTION_SIZE) & (uv < 1 - 0.5 / CORRECTION_SIZE)).all(1)
    want = np.stack([uv[:, 0], uv[:, 1], 2 * uv[:, 0] - uv[:, 1]], 1)
    assert np.abs(got[inner] - want[inner]).max() < 1e-5


def test_masks_are_in_unit_range_and_cover_the_moving_vertices(face_model):
    fx, t = face_model.fixture, face_model.template
    a = fx.attention_masks
    assert a.shape == (NUM_BLENDSHAPES, CORRECTION_SIZE, CORRECTION_SIZE)
    assert a.min() >= 0.0 and a.max() <= 1.0
    face = slice(*t.parts["face"])
    fa = face_model.sample_uv(torch.from_numpy(a)[None])[0, face].T  # [53, Vf] F(A_i)
    dist = np.linalg.norm(t.expression_deltas[:, face], axis=2)
    thr = fx.metadata["mask_threshold_cm"]
    for i in range(NUM_BLENDSHAPES):
        moving = dist[i] > 2 * thr
        # Where the blendshape moves, its mask lets a correction through...
        assert (fa[i][moving] > 0).float().mean() > 0.99, t.expression_names[i]
        # ...and the mask follows the motion: strongest where the template moves most.
        assert fa[i][dist[i].argmax()] > 0.5, t.expression_names[i]
    # Masks are local: a blendshape's mask covers far less than the whole face tile.
    assert (a > 0).mean() < 0.3


def test_fixture_of_another_version_is_refused(tmp_path):
    path = tmp_path / "face_fixture.safetensors"
    save_file({"x": np.zeros(1, np.float32)}, str(path), metadata={"likeness_fixture": json.dumps({"version": 2})})
    with pytest.raises(FixtureError, match="export-fixture"):
        load_fixture(path)
    with pytest.raises(FixtureError, match="export-fixture"):
        load_fixture(tmp_path / "missing.safetensors")


def test_gradients_reach_the_maps_only_inside_the_masks(face_region_model):
    m = face_region_model
    g = torch.Generator().manual_seed(3)
    w = torch.rand(2, NUM_BLENDSHAPES, generator=g)
    dS0 = torch.zeros(2, 3, CORRECTION_SIZE, CORRECTION_SIZE, requires_grad=True)
    dS = torch.zeros(2, NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE, requires_grad=True)
    dR = torch.zeros(2, NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE, requires_grad=True)
    target = torch.randn(2, m.vertex_count, 3, generator=g)
    loss = (m.shape(w, dS0, dS) * target).sum() + m.albedo(w, None, dR).pow(2).sum()
    loss.backward()
    outside = (m.masks == 0)[None, :, None].expand_as(dS)
    assert dS.grad[outside].abs().max() == 0 and dR.grad[outside].abs().max() == 0
    assert dS.grad[~outside].abs().max() > 0 and dR.grad[~outside].abs().max() > 0
    assert dS0.grad.abs().max() > 0
    # Equation (2) is linear in the maps: a directional derivative is exact.
    e = torch.randn(2, NUM_BLENDSHAPES, 3, CORRECTION_SIZE, CORRECTION_SIZE, generator=g) * 0.1
    with torch.no_grad():
        fd = m.shape(w, None, e) - m.shape(w)
    assert abs((fd * target).sum() - (dS.grad * e).sum()) < 1e-2 * (fd * target).abs().sum()


def test_per_person_corrections_equal_per_image_ones(face_region_model):
    """Equations (2) and (3) with per-person maps equal the same maps repeated per image."""
    g = torch.Generator().manual_seed(3)
    region = face_region_model
    w = torch.rand(6, 53, generator=g) * (torch.rand(6, 53, generator=g) < 0.2)
    dS0 = 0.1 * torch.randn(2, 3, 128, 128, generator=g)
    dS = 0.1 * torch.randn(2, 53, 3, 128, 128, generator=g)
    per_image = lambda t: t.repeat_interleave(3, dim=0)  # noqa: E731
    a = region.shape(w, dS0, dS)
    b = region.shape(w, per_image(dS0), per_image(dS))
    assert torch.allclose(a, b, atol=1e-5)
    ra = region.albedo(w, dS0, dS)
    rb = region.albedo(w, per_image(dS0), per_image(dS))
    assert torch.allclose(ra, rb, atol=1e-5)
