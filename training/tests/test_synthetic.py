"""Synthetic people (issue 3, deliverable 2): deterministic, corrections confined to A_i,
magnitudes, weights, poses and lighting within the stated ranges, image composition."""

import math

import numpy as np
import pytest
import torch

from likeness_train.face import NUM_BLENDSHAPES
from likeness_train.synthetic import (
    ComposeConfig,
    SyntheticPeople,
    compose_image,
    constant_light,
    directional_light,
    euler_to_matrix,
    irradiance,
    stack_frames,
)

PEOPLE = 4
FRAMES = 64


@pytest.fixture(scope="module")
def people(face_model):
    return SyntheticPeople(face_model, seed=1234)


@pytest.fixture(scope="module")
def persons(people):
    return [people.person(k) for k in range(PEOPLE)]


@pytest.fixture(scope="module")
def frames(people):
    return [f for g in range(FRAMES // 4) for f in people.group(g % PEOPLE, g, 4)]


def test_same_seed_same_people_and_frames(face_model, people, persons):
    again = SyntheticPeople(face_model, seed=1234)
    p, q = persons[1], again.person(1)
    for name in ("identity_coeffs", "dS0", "dS", "dR0", "dR"):
        assert torch.equal(getattr(p, name), getattr(q, name)), name
    a, b = stack_frames(people.group(2, 7, 4)), stack_frames(again.group(2, 7, 4))
    for k in a:
        assert torch.equal(a[k], b[k]), k
    # Other seeds and indices give other people and frames.
    other = SyntheticPeople(face_model, seed=99).person(1)
    assert not torch.equal(p.identity_coeffs, other.identity_coeffs)
    assert not torch.equal(p.dS, persons[2].dS)
    assert not torch.equal(a["weights"], stack_frames(people.group(2, 8, 4))["weights"])


def test_corrections_are_zero_outside_the_attention_masks(people, persons):
    outside = people.masks == 0  # [53, 128, 128]
    assert outside.any(1).any(1).all()  # every mask leaves something outside
    for p in persons:
        for maps in (p.dS, p.dR):
            assert maps.abs().amax(1)[outside].max().item() == 0.0
        # ...and they are not trivially zero inside.
        assert (p.dS.norm(dim=1).amax((1, 2)) > 0).all()
        assert (p.dR.abs().amax((1, 2, 3)) > 0).sum() >= 20


def test_expression_corrections_have_plausible_size(people, persons):
    c = people.config
    mouth = torch.tensor([n.startswith(("jaw", "mouth", "cheekPuff")) for n in people.names])
    for p in persons:
        peak = p.dS.norm(dim=1).amax((1, 2))  # cm per blendshape
        assert peak[~mouth].max() <= c.max_correction_cm + 1e-6
        assert peak[mouth].max() <= c.max_correction_mouth_cm + 1e-6
        # A few millimetres typically, not negligible.
        assert 0.05 < peak.median() < 0.5
        assert np.abs(p.motion_scale).max() <= c.motion_scale_clip
        assert p.dR.abs().max() <= c.max_dynamic_albedo + 1e-6


def test_identity_is_realistic_and_its_uv_projection_round_trips(face_model, persons):
    face = slice(*face_model.template.parts["face"])
    for p in persons:
        assert p.identity_coeffs.abs().max() <= 2.5
        offset = p.identity_offset(face_model)[face]
        rms = offset.norm(dim=-1).pow(2).mean().sqrt().item()
        assert 0.1 < rms < 1.5, rms  # a few mm RMS: people differ, but stay human
        # F(dS0^true) recovers the per-vertex identity to well under a millimetre on average.
        err = (face_model.sample_uv(p.dS0[None])[0, face] - offset).norm(dim=-1)
        assert err.mean() < 0.03 and err.max() < 0.4, (err.mean(), err.max())


def test_albedo_stays_in_range(face_model, persons, frames):
    tones = []
    for k, p in enumerate(persons):
        assert p.dR0.abs().max() < 0.6
        # Static albedo (w = 0) is a valid colour everywhere on the 512 face layer...
        r = p.albedo(face_model, torch.zeros(1, NUM_BLENDSHAPES))
        assert r.min() >= 0.02 - 1e-5 and r.max() <= 0.98 + 1e-5, (r.min(), r.max())
        # ...and the drawn expressions darken it only moderately.
        w = torch.from_numpy(np.stack([f.weights for f in frames[4 * k : 4 * k + 4]]))
        r = p.albedo(face_model, w)
        assert r.min() > -0.05 and r.max() < 1.05
        tones.append(p.skin_tone)
    assert max(tones) - min(tones) > 0.1  # skin tone varies between people


def test_weights_are_sparse_and_in_unit_range(frames):
    w = np.stack([f.weights for f in frames])
    assert w.min() >= 0.0 and w.max() <= 1.0
    active = (w > 0).sum(1)
    assert active.max() <= 20 and active.mean() >= 2 and active.mean() <= 12, active.mean()
    assert (w == 0).mean() > 0.75
    assert (active >= 3).mean() > 0.5  # several shapes at once, usually


def test_expressions_are_dense_enough_to_learn(people):
    """SyntheticConfig says why: each non-gaze shape is active in a tenth of the frames or
    more on average, the jaw open (> 0.3) in about a third (talking_probability 0.4 times
    P(beta(1.5, 2) > 0.3) ~ 0.71, plus groups)."""
    w = np.stack([f.weights for k in range(150) for f in people.group(k, 0, 4)])
    names = people.names
    jaw = names.index("jawOpen")
    assert 0.25 < (w[:, jaw] > 0.3).mean() < 0.45
    expression = [i for i, n in enumerate(names) if not n.startswith(("eyeLook", "eyeBlink"))]
    assert (w[:, expression] > 0.05).mean() > 0.08


def test_mouth_close_is_a_corrective_of_an_open_jaw(people):
    """Version 3: mouthClose only with jawOpen and at most jawOpen (in ICT and ARKit it
    closes the lips of an open jaw; alone it pushes the lower lip through the upper)."""
    w = np.stack([f.weights for k in range(150) for f in people.group(k, 0, 4)])
    close, jaw = w[:, people.names.index("mouthClose")], w[:, people.names.index("jawOpen")]
    assert (close <= jaw + 1e-7).all()
    assert (close[jaw == 0] == 0).all()
    assert 0.05 < (close > 0).mean() < 0.2  # 0.25 of the ~40 % of frames with the jaw open


def test_the_principal_point_is_the_image_centre(frames):
    """What the inference crop assumes (tracking/src/params.rs): the image cannot show it."""
    for f in frames:
        assert np.array_equal(f.principal, [0.5 * f.image_size, 0.5 * f.image_size])


def test_the_eyeballs_turn_by_the_documented_angles_and_nothing_else_moves(face_model):
    from likeness_train.face import EYEBALL_PARTS, GAZE_PITCH_DEG_PER_UNIT, GAZE_YAW_DEG_PER_UNIT

    names = face_model.expression_names
    w = torch.zeros(3, 53)
    w[1, names.index("eyeLookOut_L")] = 0.5  # left eye 15 degrees towards +x
    w[1, names.index("eyeLookIn_R")] = 0.5  # right eye 15 degrees towards +x
    w[2, names.index("eyeLookDown_L")] = 1.0  # left eye 25 degrees down
    w[2, names.index("eyeLookDown_R")] = 0.4  # right eye 10 degrees down
    shaped = face_model.shape(w)
    turned = face_model.turn_eyes(shaped, w)
    t = face_model.template
    eyes = np.zeros(t.vertex_count, dtype=bool)
    for part in EYEBALL_PARTS:
        eyes[slice(*t.parts[part])] = True
    assert torch.equal(turned[:, ~eyes], shaped[:, ~eyes])
    assert torch.equal(turned[0], shaped[0])
    for k, part in enumerate(EYEBALL_PARTS):
        ids = slice(*t.parts[part])
        before = shaped[:, ids].double()
        front = int(before[0, :, 2].argmax())
        # Rigid: distances between vertices are kept.
        for frame in (1, 2):
            after = turned[frame, ids].double()
            assert torch.allclose(torch.cdist(after[:200], after[:200]), torch.cdist(before[frame, :200], before[frame, :200]), atol=1e-4)
        # The front pole's direction from the eye's centre turns by the gaze's angles.
        centre = before[0].mean(0)
        d0 = before[0, front] - centre
        for frame, (yaw_deg, pitch_deg) in ((1, (0.5 * GAZE_YAW_DEG_PER_UNIT, 0.0)), (2, (0.0, (1.0 if k == 0 else 0.4) * GAZE_PITCH_DEG_PER_UNIT))):
            d1 = turned[frame, ids][front].double() - turned[frame, ids].double().mean(0)
            yaw = math.degrees(math.atan2(d1[0], d1[2]) - math.atan2(d0[0], d0[2]))
            pitch = math.degrees(math.atan2(-d1[1], math.hypot(d1[0], d1[2])) - math.atan2(-d0[1], math.hypot(d0[0], d0[2])))
            assert yaw == pytest.approx(yaw_deg, abs=0.5), (part, frame)
            assert pitch == pytest.approx(pitch_deg, abs=0.5), (part, frame)
    # The face region has no eyeballs: nothing to turn.
    region = face_model.restricted()
    assert torch.equal(region.turn_eyes(region.shape(w), w), region.shape(w))


def test_poses_and_cameras_are_within_range(people, frames):
    c = people.config
    deg = np.stack([f.euler_degrees for f in frames])
    assert (np.abs(deg) <= np.array([c.max_yaw_deg, c.max_pitch_deg, c.max_roll_deg]) + 1e-4).all()
    assert np.abs(deg[:, 0]).max() > 20  # the range is used, not only frontal views
    for f in frames:
        # The face centre lands near the image centre, in front of the camera.
        centre = euler_to_matrix(f.euler) @ people.face_center + f.translation
        assert centre[2] < -20
        u = f.principal[0] + f.focal * centre[0] / -centre[2]
        v = f.principal[1] - f.focal * centre[1] / -centre[2]
        assert abs(u - 64) < 12 and abs(v - 64) < 12
        fov = 2 * math.degrees(math.atan(0.5 * f.image_size / f.focal))
        assert c.fov_deg_range[0] - 1e-3 <= fov <= c.fov_deg_range[1] + 1e-3


def test_lighting_is_positive_and_nearly_monochromatic(frames):
    n = np.random.default_rng(0).normal(size=(2000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for f in frames:
        e = irradiance(n, f.gamma.astype(np.float64))
        assert e.min() > 0.0
        spread = (e.max(1) - e.min(1)) / e.mean(1)
        assert spread.max() < 0.25
    gamma = np.stack([f.gamma for f in frames])
    assert np.abs(gamma - gamma.reshape(-1, 3, 9).mean(1, keepdims=True).repeat(3, 1).reshape(-1, 27)).max() < 0.1


def test_sh_helpers_match_the_rust_definitions():
    # constant_light gives exactly its level; directional light approximates the clamped
    # cosine (the same checks as face/src/sh.rs tests).
    assert np.allclose(irradiance(np.array([[0.0, 0.0, 1.0], [1.0, 0, 0]]), constant_light([0.5, 0.6, 0.7])), [0.5, 0.6, 0.7])
    d = np.array([-0.5, 0.5, 0.7]) / np.linalg.norm([-0.5, 0.5, 0.7])
    g = directional_light(d, [1.0, 1.0, 1.0])
    assert abs(irradiance(d, g)[0] - 1.0) < 0.1 and abs(irradiance(-d, g)[0]) < 0.1


def test_compose_image_is_deterministic_and_keeps_the_face():
    rng = np.random.default_rng(0)
    h = w = 64
    rendered = np.zeros((h, w, 3), np.float32)
    rendered[..., 0] = 0.8
    mask = np.zeros((h, w), np.float32)
    mask[16:48, 16:48] = 1.0
    clean = ComposeConfig(blur_probability=0.0, noise_sigma=(0.0, 0.0), jpeg_probability=0.0)
    for kind in clean.background_kinds:
        cfg = ComposeConfig(background_kinds=(kind,), blur_probability=0.0, noise_sigma=(0.0, 0.0), jpeg_probability=0.0)
        out = compose_image(rendered, mask, np.random.default_rng(1), cfg)
        assert out.shape == (h, w, 3) and out.dtype == np.float32
        assert np.abs(out[16:48, 16:48] - rendered[16:48, 16:48]).max() < 1 / 255 + 1e-6, kind
    # Non-face image backgrounds are cropped and resized.
    photo = (rng.uniform(0, 1, (100, 150, 3)) * 255).astype(np.uint8)
    cfg = ComposeConfig(image_background_probability=1.0, blur_probability=0.0, noise_sigma=(0, 0), jpeg_probability=0.0)
    out = compose_image(rendered, mask, np.random.default_rng(1), cfg, backgrounds=[photo])
    assert out[:8].std() > 0.05
    # Full degradation: deterministic in the rng, values in range, face still recognisable.
    cfg = ComposeConfig(blur_probability=1.0, noise_sigma=(0.02, 0.02), jpeg_probability=1.0)
    a = compose_image(rendered, mask, np.random.default_rng(5), cfg)
    b = compose_image(rendered, mask, np.random.default_rng(5), cfg)
    assert np.array_equal(a, b)
    assert a.min() >= 0 and a.max() <= 1
    assert abs(a[24:40, 24:40, 0].mean() - 0.8) < 0.05
    # Torch and batched inputs come back as the same type and shape.
    t = compose_image(torch.from_numpy(np.stack([rendered] * 2)), torch.from_numpy(np.stack([mask] * 2)), rng, clean)
    assert isinstance(t, torch.Tensor) and t.shape == (2, h, w, 3)


def test_group_truth_holds_every_ground_truth_value(face_region_model, people, persons):
    m = face_region_model
    frames = people.group(0, 0, 4)
    t = people.truth(m, persons[0], frames)
    assert t["vertices"].shape == (4, m.vertex_count, 3)
    assert t["landmarks_3d"].shape == (4, 68, 3) and t["albedo"].shape == (4, 3, 512, 512)
    assert t["rotation"].shape == (4, 3, 3)
    assert torch.allclose(t["rotation"][0] @ t["rotation"][0].T, torch.eye(3), atol=1e-5)
    # The truth differs from the bare template by the person's identity and corrections.
    template = m.shape(t["weights"])
    diff = (t["vertices"] - template).norm(dim=-1)
    assert 0.1 < diff.mean() < 2.0
