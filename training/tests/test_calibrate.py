"""TrackNet's w calibration: the map itself, its fit against known conditional medians, and
the command from a checkpoint and a cache of new people to a calibrated checkpoint that
evaluates and exports."""

import json

import pytest
import torch

from likeness_train.calibrate import fit_calibration
from likeness_train.calibrate import main as calibrate_main
from likeness_train.dataset import CacheSpec, write_cache
from likeness_train.networks import CALIBRATION_KNOTS, NUM_BLENDSHAPES, CalibratedTrackNet, WCalibration, load_networks
from likeness_train.train import TrainConfig, Trainer


def test_the_identity_calibration_changes_nothing_and_bad_maps_are_refused():
    w = torch.rand(100, NUM_BLENDSHAPES)
    assert torch.allclose(WCalibration()(w), w, atol=1e-6)
    k = len(CALIBRATION_KNOTS)
    decreasing = torch.zeros(NUM_BLENDSHAPES, k)
    decreasing[:, 0], decreasing[:, 3] = 1.0, -2.0  # slope 1 then -1: not monotone
    with pytest.raises(ValueError, match="monotone"):
        WCalibration(decreasing)
    with pytest.raises(ValueError, match="must be"):
        WCalibration(torch.ones(NUM_BLENDSHAPES, k + 1))
    nan = torch.zeros(NUM_BLENDSHAPES, k)
    nan[0, 0] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        WCalibration(nan)


def test_fit_recovers_a_dead_zone_map():
    """truth = clamp(2 (w - 0.3), 0, 1) is a map of the family (a knot at 0.3): the fit
    must find it, a dead zone below 0.3 included."""
    torch.manual_seed(0)
    predicted = torch.rand(1500, NUM_BLENDSHAPES)
    truth = (2 * (predicted - 0.3)).clamp(0, 1)
    g = fit_calibration(predicted, truth)
    with torch.no_grad():
        assert float((g(predicted) - truth).abs().mean()) < 0.01
        probe = torch.tensor([[0.1], [0.25], [0.5], [0.9]]).expand(-1, NUM_BLENDSHAPES)
        want = torch.tensor([[0.0], [0.0], [0.4], [1.0]]).expand(-1, NUM_BLENDSHAPES)
        assert float((g(probe) - want).abs().max()) < 0.03


def test_fit_gives_the_conditional_median_zero_for_a_channel_mostly_off():
    """A channel off in 70 % of the frames whatever w says has conditional median 0: the
    L1-best monotone map is 0 (the MAE of w = 0), not the mean the cross-entropy aims at."""
    torch.manual_seed(1)
    predicted = torch.rand(1500, NUM_BLENDSHAPES)
    on = torch.rand(1500, NUM_BLENDSHAPES) < 0.3
    truth = torch.where(on, predicted, torch.zeros_like(predicted))
    g = fit_calibration(predicted, truth)
    with torch.no_grad():
        calibrated = g(predicted)
    assert float(calibrated.abs().max()) < 0.05
    assert float((calibrated - truth).abs().mean()) <= float(truth.abs().mean()) + 1e-3
    assert float((calibrated - truth).abs().mean()) < float((predicted - truth).abs().mean())


def test_fit_refuses_bad_input():
    with pytest.raises(ValueError, match="frames"):
        fit_calibration(torch.rand(10, 3), torch.rand(10, 3))
    bad = torch.rand(10, NUM_BLENDSHAPES)
    bad[0, 0] = float("inf")
    with pytest.raises(ValueError, match="finite"):
        fit_calibration(bad, torch.rand(10, NUM_BLENDSHAPES))


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    config = TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25)
    trainer = Trainer(config, out)
    trainer.save()
    return trainer.checkpoint_path


def _cache(root, seed):
    directory = root / f"cache-s{seed}"
    write_cache(directory, CacheSpec(seed=seed, batches=2, people_per_batch=1, frames=2, image_size=128, batches_per_shard=2), workers=1)
    return directory


def test_calibrate_writes_a_checkpoint_that_evaluates_and_exports_calibrated(checkpoint, tmp_path, capsys):
    from likeness_train.export import main as export_main

    out = tmp_path / "calibrated.pt"
    calibrate_main(["--checkpoint", str(checkpoint), "--data", str(_cache(tmp_path, 0)), "--out", str(out), "--iterations", "50"])
    printed = capsys.readouterr().out
    assert "all 53" in printed and "wrote" in printed
    nets = load_networks(out)
    assert isinstance(nets.track, CalibratedTrackNet)
    summary = {k: v for k, v in torch.load(out, weights_only=False)["w_calibration"].items() if k != "coefficients"}
    assert summary["seed"] == 0 and summary["frames"] == 4
    # Fitted on 4 frames to minimise their MAE from the identity: never worse there.
    assert summary["mae_calibrated"] <= summary["mae_raw"] + 1e-6
    raw = load_networks(checkpoint)
    images = torch.rand(3, 3, 128, 128)
    with torch.no_grad():
        a, b = raw.track(images), nets.track(images)
    assert torch.equal(a.euler, b.euler) and torch.equal(a.translation, b.translation)
    assert torch.allclose(b.w, nets.track.calibration(a.w))
    export_main(["--checkpoint", str(out), "--out", str(tmp_path / "models")])
    manifest = json.loads((tmp_path / "models" / "manifest.json").read_text())
    assert manifest["parity_max_abs_diff"]["track_net"] < 1e-4
    assert manifest["training"]["w_calibration"]["seed"] == 0


def test_calibrate_refuses_people_that_are_trained_on_or_held_out(checkpoint, tmp_path):
    import shutil

    from likeness_train.evaluate import HELD_OUT_SEED

    out = tmp_path / "c.pt"
    with pytest.raises(SystemExit, match="trained on"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(_cache(tmp_path, 1)), "--out", str(out)])
    held = tmp_path / "held"
    shutil.copytree(_cache(tmp_path, 0), held)
    manifest = json.loads((held / "manifest.json").read_text())
    (held / "manifest.json").write_text(json.dumps({**manifest, "seed": HELD_OUT_SEED}))
    with pytest.raises(SystemExit, match="held-out"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(held), "--out", str(out)])
    with pytest.raises(SystemExit):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(held), "--out", str(checkpoint)])
    with pytest.raises(SystemExit, match="error"):
        calibrate_main(["--checkpoint", str(tmp_path / "missing.pt"), "--data", str(held), "--out", str(out)])
    assert not out.exists()


def test_validate_reports_the_calibrated_mae_on_other_people(checkpoint, tmp_path, capsys):
    out = tmp_path / "validated.pt"
    calibrate_main(["--checkpoint", str(checkpoint), "--data", str(_cache(tmp_path, 0)), "--out", str(out), "--iterations", "50", "--validate", str(_cache(tmp_path, 5))])
    printed = capsys.readouterr().out
    assert "validation set" in printed
    validation = torch.load(out, weights_only=False)["w_calibration"]["validation"]
    assert validation["seed"] == 5 and validation["frames"] == 4
    # An independent recomputation: the calibrated TrackNet over the same cache.
    from likeness_train.calibrate import predict_w
    from likeness_train.dataset import CachedData

    predicted, truth = predict_w(load_networks(out).track, CachedData(tmp_path / "cache-s5"))
    assert validation["mae_calibrated"] == pytest.approx(float((predicted - truth).abs().mean()), abs=1e-6)
    assert validation["mae_zero"] == pytest.approx(float(truth.abs().mean()), abs=1e-7)
    with pytest.raises(SystemExit, match="in-sample"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(tmp_path / "cache-s0"), "--out", str(tmp_path / "x.pt"), "--validate", str(tmp_path / "cache-s0")])
    with pytest.raises(SystemExit, match="trained on"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(tmp_path / "cache-s0"), "--out", str(tmp_path / "y.pt"), "--validate", str(_cache(tmp_path, 1))])


def test_a_cache_of_another_image_size_is_refused_by_name(checkpoint, tmp_path):
    directory = tmp_path / "cache-64"
    write_cache(directory, CacheSpec(seed=0, batches=1, people_per_batch=1, frames=2, image_size=64, batches_per_shard=1), workers=1)
    with pytest.raises(SystemExit, match="64 px, this TrackNet reads 128 px"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(directory), "--out", str(tmp_path / "c.pt")])
    with pytest.raises(SystemExit, match="64 px"):
        calibrate_main(["--checkpoint", str(checkpoint), "--data", str(_cache(tmp_path, 0)), "--out", str(tmp_path / "d.pt"), "--validate", str(directory)])
