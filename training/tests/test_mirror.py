"""Mirrored batches (data.mirror_batch): a face seen in a mirror is the mirrored face with
its left and right swapped; checked against projecting the template with the mirrored
parameters, and the light against the SH irradiance at mirrored normals."""

import numpy as np
import pytest
import torch

from likeness_train import render as R
from likeness_train.data import MIRROR_68, Batch, mirror_batch, mirror_channels
from likeness_train.synthetic import irradiance

SIZE = 128


def _batch(landmarks, weights, euler, translation, gamma, principal) -> Batch:
    n = weights.shape[0]
    g = torch.Generator().manual_seed(3)
    return Batch(
        images=torch.rand(n, 3, SIZE, SIZE, generator=g), landmarks=landmarks, parsing=torch.rand(n, SIZE, SIZE, 9, generator=g),
        weights=weights, euler=euler, translation=translation, gamma=gamma, focal=torch.full((n,), 200.0), principal=principal,
        vertices=None, dS=None, dR0=None, dR=None, identity_coeffs=torch.zeros(1, 100), people=1, frames=n,
    )


def _project(region, weights, euler, translation, principal):
    points = region.landmarks(region.shape(weights))
    pixels, _ = R.project(points, R.euler_to_matrix(euler), translation, torch.full((weights.shape[0],), 200.0), principal[:, 0], principal[:, 1])
    return pixels


def test_a_mirrored_batch_is_the_mirrored_face_with_left_and_right_swapped(face_region_model):
    region = face_region_model
    names = region.expression_names
    channels = mirror_channels(names)
    g = torch.Generator().manual_seed(7)
    n = 4
    weights = torch.rand(n, 53, generator=g) * (torch.rand(n, 53, generator=g) < 0.2)
    euler = torch.tensor([[0.4, 0.1, 0.2], [-0.3, -0.2, 0.1], [0.0, 0.3, -0.25], [0.6, 0.0, 0.0]])
    translation = torch.tensor([[2.0, -1.0, -60.0], [-3.0, 1.5, -55.0], [0.5, 0.0, -70.0], [1.0, 2.0, -65.0]])
    principal = torch.tensor([[64.0, 64.0], [60.0, 66.0], [64.0, 64.0], [70.0, 61.0]])
    gamma = torch.randn(n, 27, generator=g) * 0.2
    batch = _batch(_project(region, weights, euler, translation, principal), weights, euler, translation, gamma, principal)
    flip = torch.tensor([True, True, False, True])
    mirrored = mirror_batch(batch, flip, channels)

    # The expectation, independently: the template with the other side's weights, the head
    # turned and rolled the other way, shifted the other way, seen by the mirrored camera.
    f = flip[:, None]
    expected_weights = torch.where(f, weights[:, channels], weights)
    expected_euler = torch.where(f, euler * torch.tensor([-1.0, 1.0, -1.0]), euler)
    expected_translation = torch.where(f, translation * torch.tensor([-1.0, 1.0, 1.0]), translation)
    expected_principal = torch.where(f, torch.stack([SIZE - principal[:, 0], principal[:, 1]], 1), principal)
    expected_landmarks = _project(region, expected_weights, expected_euler, expected_translation, expected_principal)
    # ICT's left and right shapes mirror each other to ~0.1 mm at the landmarks (the test
    # below), ~0.1 px here.
    assert torch.allclose(mirrored.landmarks, expected_landmarks, atol=0.15), (mirrored.landmarks - expected_landmarks).abs().max()
    assert not torch.allclose(mirrored.landmarks, batch.landmarks, atol=1.0)
    assert torch.equal(mirrored.weights, expected_weights)
    assert names[channels[names.index("eyeLookIn_L")]] == "eyeLookIn_R"
    assert names[channels[names.index("jawLeft")]] == "jawRight"
    assert names[channels[names.index("jawOpen")]] == "jawOpen"

    # Pixels: column x shows what column SIZE - 1 - x showed.
    assert torch.equal(mirrored.images[0], batch.images[0].flip(-1))
    assert torch.equal(mirrored.images[2], batch.images[2])
    assert torch.equal(mirrored.parsing[1], batch.parsing[1].flip(1))

    # The light: the mirrored light at a mirrored normal is the original light at the normal.
    normals = np.random.default_rng(0).normal(size=(500, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    for k in range(n):
        original = irradiance(normals, batch.gamma[k].double().numpy())
        seen = irradiance(normals * ([-1, 1, 1] if flip[k] else [1, 1, 1]), mirrored.gamma[k].double().numpy())
        assert np.allclose(seen, original, atol=1e-6)

    # Twice is the original.
    again = mirror_batch(mirrored, flip, channels)
    for key in ("images", "landmarks", "parsing", "weights", "euler", "translation", "principal", "gamma"):
        assert torch.allclose(getattr(again, key), getattr(batch, key), atol=1e-5), key
    # Nothing flipped: the same batch.
    assert mirror_batch(batch, torch.zeros(n, dtype=torch.bool), channels) is batch


def test_the_landmark_mirror_is_a_permutation_that_pairs_the_templates_landmarks(face_model):
    assert sorted(MIRROR_68) == list(range(68))
    assert all(MIRROR_68[MIRROR_68[k]] == k for k in range(68))
    t = face_model.template
    landmarks = t.neutral[t.landmarks_68]
    assert np.abs(landmarks[MIRROR_68] * [-1, 1, 1] - landmarks).max() < 0.05  # cm


@pytest.mark.parametrize("name", ["browDown", "eyeBlink", "mouthSmile", "cheekSquint"])
def test_left_and_right_shapes_are_mirror_images_at_the_landmarks(face_model, name):
    """What makes swapping channels right: the _L shape mirrored is the _R shape."""
    names = face_model.expression_names
    deltas = face_model.template.expression_deltas[:, face_model.template.landmarks_68]
    left, right = deltas[names.index(f"{name}_L")], deltas[names.index(f"{name}_R")]
    assert np.abs(left[MIRROR_68] * [-1, 1, 1] - right).max() < 0.05


def test_a_mirrored_gaze_is_the_other_eye_turned_the_mirrored_way(face_model):
    """Swapping the eyeLook channels (`mirror_channels`) is right for the turned eyeballs
    too: the eyes turned by w, seen in a mirror, are the eyes turned by the swapped w (as
    point sets: the left eyeball mirrored is the right one). The wrong mapping, w unswapped,
    is far off, so the check can fail."""
    from likeness_train.face import EYEBALL_PARTS

    names = face_model.expression_names
    channels = mirror_channels(names)
    w = torch.zeros(3, 53)
    for frame, values in enumerate(({"eyeLookOut_L": 0.8, "eyeLookIn_R": 0.8}, {"eyeLookUp_L": 0.6, "eyeLookDown_R": 0.3}, {"eyeLookIn_L": 0.5, "eyeLookDown_L": 0.7, "eyeLookOut_R": 0.2})):
        for name, value in values.items():
            w[frame, names.index(name)] = value
    turned = face_model.turn_eyes(face_model.shape(w), w).double()
    swapped = face_model.turn_eyes(face_model.shape(w[:, channels]), w[:, channels]).double()
    unswapped_neutral = face_model.shape(torch.zeros(1, 53)).double()
    parts = [slice(*face_model.template.parts[p]) for p in EYEBALL_PARTS]
    mirror = torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64)

    def gap(a, b):  # the farthest point of set a from set b (cm)
        return float(torch.cdist(a, b).min(dim=1).values.max())

    # How symmetric ICT's two eyeballs are to begin with.
    rest = max(gap(unswapped_neutral[0, parts[k]] * mirror, unswapped_neutral[0, parts[1 - k]]) for k in (0, 1))
    for frame in range(3):
        for k in (0, 1):
            seen = turned[frame, parts[k]] * mirror
            assert gap(seen, swapped[frame, parts[1 - k]]) < rest + 0.01, (frame, k)
            wrong = face_model.turn_eyes(face_model.shape(w), w).double()[frame, parts[1 - k]]
            assert gap(seen, wrong) > rest + 0.05, (frame, k)
