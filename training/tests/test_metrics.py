"""Metrics against hand-computed values."""

import numpy as np
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


def test_activation_f1_by_hand():
    truth = torch.tensor([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.9, 0.4, 0.0], [0.1, 0.0, 0.0]])
    predicted = torch.tensor([[0.6, 0.0, 0.0], [0.4, 0.0, 0.0], [0.2, 0.0, 0.0], [0.0, 0.0, 0.0]])
    f1 = M.activation_f1(predicted, truth)
    # Channel 0: predicted active in frames 0, 1; truly in 0, 2: tp 1, F1 = 2 / (2 + 2).
    assert f1[0].item() == pytest.approx(0.5)
    assert f1[1].item() == pytest.approx(0.0)  # truly active once, never found
    assert torch.isnan(f1[2])  # never active on either side


def test_landmark_nme_over_the_box():
    truth = torch.zeros(1, 68, 2)
    truth[0, :, 0] = torch.linspace(0, 40, 68)  # a 40 x 10 box: sqrt(w h) = 20
    truth[0, :, 1] = torch.linspace(0, 10, 68)
    predicted = truth + torch.tensor([3.0, 4.0])  # every point 5 px off
    assert M.landmark_nme_box(predicted, truth).item() == pytest.approx(0.25)


def test_expression_report_puts_the_prediction_beside_the_trivial_predictors():
    truth = torch.tensor([[1.0, 0.0], [0.0, 0.0], [0.0, 0.5], [0.0, 0.0]])
    predicted = torch.tensor([[0.8, 0.2], [0.0, 0.2], [0.2, 0.3], [0.0, 0.2]])
    report = M.expression_report(predicted, truth, torch.tensor([True, False]), ["a", "b"])
    # Per channel: prediction a 0.1, b 0.2; zero 0.25, 0.125; mean (0.25, 0.125): 0.375, 0.1875.
    assert report["per_channel"]["a"]["mae"] == pytest.approx(0.1)
    assert report["per_channel"]["b"]["mae_zero"] == pytest.approx(0.125)
    assert report["per_channel"]["a"]["mae_constant_mean"] == pytest.approx(0.375)
    assert report["mae_all"]["predicted"] == pytest.approx(0.15)
    assert report["mae_visible"]["predicted"] == pytest.approx(0.1)  # channel a only
    assert report["mae_visible"]["zero"] == pytest.approx(0.25)
    assert report["channels_beating_zero"] == 1 and report["visible_channels_beating_zero"] == 1
    assert "b" in M.format_expression_report(report)


def test_every_channel_is_visible_once_the_eyes_turn(face_model):
    """At 128 px each ICT shape moves some face or eyeball vertex by >= 1 px at w = 1; the
    gaze shapes only because the eyeballs turn (their lids move < 1 px)."""
    motion = M.channel_motion_px(face_model)
    assert (motion >= M.VISIBLE_MIN_PX).all(), motion.min()
    t = face_model.template
    face_end = t.parts["face"][1]
    pixels_per_cm = 0.85 * 128 / float(np.ptp(t.neutral[:face_end, 1]))
    look = face_model.expression_names.index("eyeLookOut_L")
    lids = float(torch.from_numpy(t.expression_deltas[look, :face_end]).norm(dim=-1).max()) * pixels_per_cm
    assert lids < 1.0 < 2.0 < float(motion[look])
