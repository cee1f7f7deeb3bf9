"""Metrics against hand-computed values."""

import pytest
import torch

from likeness_train import metrics as M


def test_vertex_error_ignores_a_common_offset_and_is_in_mm():
    truth = torch.rand(2, 50, 3)
    assert M.vertex_error_mm(truth + torch.tensor([1.0, -2.0, 0.5]), truth).item() == pytest.approx(0.0, abs=1e-5)
    bumped = truth.clone()
    bumped[:, :25, 0] += 0.1  # half the vertices 1 mm off along x
    # After removing the mean offset (0.05 cm), every vertex is 0.05 cm = 0.5 mm off.
    assert M.vertex_error_mm(bumped, truth).item() == pytest.approx(0.5, rel=1e-4)


def test_landmark_nme():
    truth = torch.zeros(1, 68, 2)
    truth[0, 36] = torch.tensor([0.0, 0.0])
    truth[0, 45] = torch.tensor([100.0, 0.0])
    pred = truth + torch.tensor([3.0, 4.0])
    assert M.landmark_nme(pred, truth).item() == pytest.approx(0.05)


def test_expression_and_recovery():
    w = torch.rand(4, 53)
    assert M.expression_mae(w + 0.1, w).item() == pytest.approx(0.1, rel=1e-5)
    template = torch.zeros(53, 10, 3)
    true = torch.ones(1, 53, 10, 3) * 0.1
    assert M.personalization_recovery(template.unsqueeze(0), true, template).item() == pytest.approx(1.0)
    assert M.personalization_recovery(true, true, template).item() == pytest.approx(0.0)
    half = true * 0.5
    assert M.personalization_recovery(half, true, template).item() == pytest.approx(0.5, rel=1e-5)


def test_photometric_and_albedo_error():
    img = torch.rand(1, 4, 4, 3)
    mask = torch.zeros(1, 4, 4)
    mask[0, :2] = 1
    off = img + torch.tensor([0.3, 0.4, 0.0])
    assert M.photometric_error(img, off, mask).item() == pytest.approx(0.5, rel=1e-5)
    a = torch.rand(2, 3, 8, 8)
    assert M.albedo_error(a + 0.2, a).item() == pytest.approx(0.2, rel=1e-5)


def test_per_channel_correlation_and_pose_error():
    import math

    from likeness_train.metrics import per_channel_correlation, pose_mae_deg

    t = torch.rand(50, 3, dtype=torch.float64)
    predicted = torch.stack([2 * t[:, 0] + 1, 1 - t[:, 1], torch.full((50,), 0.3, dtype=torch.float64)], dim=1)
    c = per_channel_correlation(predicted, t)
    assert c[0].item() == pytest.approx(1.0) and c[1].item() == pytest.approx(-1.0) and c[2].item() == 0.0
    e = pose_mae_deg(torch.tensor([[math.radians(10), 0.0, -math.radians(4)]]), torch.zeros(1, 3))
    assert e["yaw"] == pytest.approx(10.0) and e["pitch"] == 0.0 and e["roll"] == pytest.approx(4.0)
