"""The stage-1 learning-rate schedule against its closed form."""

import math

import pytest

from likeness_train.train import TrainConfig, stage1_learning_rate, warmup_learning_rate


def test_constant_then_cosine_to_the_final_ratio():
    cfg = TrainConfig(stage1_steps=1000, lr_stage1=3e-4, lr_decay_from=0.5, lr_final_ratio=0.02)
    low = 3e-4 * 0.02
    assert stage1_learning_rate(0, cfg) == 3e-4
    assert stage1_learning_rate(499, cfg) == 3e-4
    assert stage1_learning_rate(500, cfg) == pytest.approx(3e-4)
    # Halfway through the decay the cosine is at the mean of the two ends.
    assert stage1_learning_rate(750, cfg) == pytest.approx((3e-4 + low) / 2)
    assert stage1_learning_rate(600, cfg) == pytest.approx(low + 0.5 * (3e-4 - low) * (1 + math.cos(math.pi * 0.2)))
    assert stage1_learning_rate(1000, cfg) == pytest.approx(low)
    rates = [stage1_learning_rate(s, cfg) for s in range(1001)]
    assert all(a >= b for a, b in zip(rates, rates[1:])), "never increases"


def test_decay_from_one_is_the_papers_constant_rate():
    cfg = TrainConfig(stage1_steps=800, lr_stage1=1e-4, lr_decay_from=1.0)
    assert {stage1_learning_rate(s, cfg) for s in range(0, 801, 50)} == {1e-4}


def test_warmup_rate_is_constant_unless_it_decays_like_stage_1():
    cfg = TrainConfig(landmark_warmup_steps=400, stage1_steps=1000, lr_stage1=3e-4, lr_decay_from=0.5, lr_final_ratio=0.02, warmup_lr_decay=False)
    assert {warmup_learning_rate(s, cfg) for s in range(0, 401, 20)} == {3e-4}
    cfg.warmup_lr_decay = True
    # The same closed form as stage 1, over the warm-up's own length.
    stage1_of_warmup_length = TrainConfig(stage1_steps=400, lr_stage1=3e-4, lr_decay_from=0.5, lr_final_ratio=0.02)
    for s in (0, 199, 200, 300, 399, 400):
        assert warmup_learning_rate(s, cfg) == pytest.approx(stage1_learning_rate(s, stage1_of_warmup_length))
    assert warmup_learning_rate(400, cfg) == pytest.approx(3e-4 * 0.02)


def test_camera_translation_round_trips_and_keeps_the_projection():
    """TrackNet's translation is for f_ref: scaled to a camera of focal f it projects a face
    where the true camera does, up to the perspective of the face's own depth."""
    import torch

    from likeness_train import render as R
    from likeness_train.train import camera_translation, reference_focal, reference_translation

    size = 128
    focal = torch.tensor([176.0, 219.0, 289.0])
    true_t = torch.tensor([[1.0, -2.0, -50.0], [0.5, 0.5, -62.0], [-1.0, 1.5, -81.0]])
    ref_t = reference_translation(true_t, focal, size)
    assert torch.allclose(camera_translation(ref_t, focal, size), true_t, atol=1e-5)
    assert torch.equal(ref_t[:, :2], true_t[:, :2]), "only the distance depends on the camera"
    # The reference camera with the reference translation sees the face's centre plane as
    # the true camera does; a point 5 cm in front of it moves by depth/distance to first order.
    eye = torch.eye(3).expand(3, 3, 3)
    centre = torch.tensor([[[3.0, 4.0, 0.0]]]).expand(3, 1, 3)
    at_ref, _ = R.project(centre, eye, ref_t, reference_focal(size), 64.0, 64.0)
    at_true, _ = R.project(centre, eye, true_t, focal, 64.0, 64.0)
    assert torch.allclose(at_ref, at_true, atol=1e-3)
    nose = torch.tensor([[[3.0, 4.0, 5.0]]]).expand(3, 1, 3)
    at_ref, _ = R.project(nose, eye, ref_t, reference_focal(size), 64.0, 64.0)
    at_true, _ = R.project(nose, eye, true_t, focal, 64.0, 64.0)
    offset = (at_true - 64.0).norm(dim=-1)
    assert ((at_ref - at_true).norm(dim=-1) < 0.1 * offset).all()
    assert reference_focal(size) == pytest.approx(0.5 * size / math.tan(math.radians(16.25)))


@pytest.mark.parametrize(
    "flag",
    [["--lr-decay-from", "1.5"], ["--lr-final-ratio", "nan"], ["--landmark-warmup-steps", "-1"], ["--track-w-grad-scale", "0"], ["--warmup-supervision", "-1"],
     ["--warmup-light-supervision", "nan"], ["--stage1-track-frozen-steps", "-1"], ["--stage1-track-lr-ratio", "-1"],
     ["--warmup-lr-ramp-steps", "-5"], ["--warmup-batches-per-step", "0"], ["--warmup-batches-per-step", "65"]],
)
def test_schedule_flags_out_of_range_are_refused_by_name(flag, capsys):
    from likeness_train.train import config_from_args

    with pytest.raises(SystemExit):
        config_from_args(["--out", "x", *flag])
    assert flag[0] in capsys.readouterr().err


def test_warmup_ramp_rises_linearly_then_follows_the_schedule():
    cfg = TrainConfig(landmark_warmup_steps=400, lr_stage1=1e-3, lr_decay_from=0.5, lr_final_ratio=0.02, warmup_lr_ramp_steps=100)
    assert warmup_learning_rate(0, cfg) == pytest.approx(1e-5)
    assert warmup_learning_rate(49, cfg) == pytest.approx(5e-4)
    assert warmup_learning_rate(99, cfg) == pytest.approx(1e-3)
    assert warmup_learning_rate(150, cfg) == pytest.approx(1e-3)
    unramped = TrainConfig(landmark_warmup_steps=400, lr_stage1=1e-3, lr_decay_from=0.5, lr_final_ratio=0.02)
    for s in (100, 250, 399):
        assert warmup_learning_rate(s, cfg) == pytest.approx(warmup_learning_rate(s, unramped))
