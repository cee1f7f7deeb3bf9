"""Evaluation of a smoke-trained checkpoint on held-out people: every metric finite and
plausible, the template baseline consistent, and the numbers deterministic."""

import json
import math

import pytest
import torch

from likeness_train.evaluate import METRIC_KEYS, evaluate, main as evaluate_main
from likeness_train.networks import load_networks
from likeness_train.train import TrainConfig, Trainer


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    config = TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=0, stage1_steps=1, stage2_steps=0, track_width=0.25, model_width=0.25, checkpoint_every_s=1e9)
    trainer = Trainer(config, out)
    trainer.run(log_every=1)
    return trainer.checkpoint_path


def test_evaluate_smoke_checkpoint(checkpoint, tmp_path, face_model):
    results_path = tmp_path / "results.json"
    evaluate_main(["--checkpoint", str(checkpoint), "--people", "2", "--frames", "2", "--out", str(results_path)])
    results = json.loads(results_path.read_text())
    metrics, baseline = results["metrics"], results["baseline"]["metrics"]
    assert set(METRIC_KEYS) <= set(metrics) and set(METRIC_KEYS) <= set(baseline)
    assert all(math.isfinite(v) for v in (*metrics.values(), *baseline.values()))
    assert 0 <= metrics["expression_mae"] <= 1
    assert 0 < metrics["landmark_nme"] < 10
    assert 0 < metrics["vertex_error_mm"] < 100
    assert 0 < metrics["photometric_error"] <= 3 ** 0.5
    assert 0 <= metrics["personalization_recovery"] < 5
    assert 0 < metrics["albedo_error"] < 1
    assert baseline["personalization_recovery"] == pytest.approx(1.0)
    # TrackNet is shared: the expression metric cannot differ between the rows.
    assert baseline["expression_mae"] == metrics["expression_mae"]
    assert len(results["per_channel_mae"]) == 53 and "jawOpen" in results["per_channel_mae"]
    assert results["evaluation"] == {"seed": 1000, "people": 2, "frames": 2, "image_size": 128}
    # The w = 0 reference is the mean true weight of the same held-out frames.
    from likeness_train.data import SyntheticData

    data = SyntheticData(face_model, face_model.restricted(), seed=1000, image_size=128, frames=2)
    true_w = torch.cat([data.batch(k, 1).weights for k in range(2)])
    assert results["baseline"]["zero_weights_expression_mae"] == pytest.approx(float(true_w.abs().mean()), rel=1e-6)

    # Deterministic: the same checkpoint evaluated again gives identical numbers.
    again = evaluate(load_networks(checkpoint), people=2, frames=2, model=face_model)
    assert again["metrics"] == metrics and again["baseline"]["metrics"] == baseline
    assert again["per_channel_mae"] == results["per_channel_mae"]


def test_training_seed_is_refused(checkpoint, face_model):
    with pytest.raises(ValueError):
        evaluate(load_networks(checkpoint), people=1, frames=2, seed=1, model=face_model)
