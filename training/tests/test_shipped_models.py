"""The committed models in assets/models (issue 3, item 7): the manifest says what the Rust
side needs, and the ONNX files, run by ONNX Runtime on held-out synthetic people, track and
personalize as the manifest's metrics claim (within tolerances well above the measured
values, so a broken or swapped export fails and noise does not)."""

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from likeness_train.data import SyntheticData
from likeness_train.evaluate import HELD_OUT_SEED, METRIC_KEYS, model_net_input
from likeness_train.export import IMAGE_MEAN, IMAGE_STD

MODELS = Path(__file__).resolve().parents[2] / "assets" / "models"
# The evaluation of what ships (`evaluate.py --model-net-from ../assets/models` for a
# TrackNet exported beside an earlier ModelNet), not necessarily of one full run.
RESULTS = Path(__file__).resolve().parents[1] / "results" / "shipped.json"


@pytest.fixture(scope="module")
def manifest() -> dict:
    path = MODELS / "manifest.json"
    if not path.exists():
        pytest.fail(f"{path} is missing: the trained models are part of the repository", pytrace=False)
    return json.loads(path.read_text())


def test_manifest_describes_the_models(manifest, face_model):
    assert manifest["blendshape_names"] == face_model.expression_names
    assert manifest["normalisation"]["mean"] == list(IMAGE_MEAN) and manifest["normalisation"]["std"] == list(IMAGE_STD)
    assert manifest["uv_size"] == 128 and manifest["input_size"] == 128
    assert len(manifest["training_commit"]) == 40 and int(manifest["training_commit"], 16) >= 0
    for key in METRIC_KEYS:
        assert math.isfinite(manifest["metrics"][key]), key
    # The manifest's metrics are the committed evaluation of the same run.
    results = json.loads(RESULTS.read_text())
    assert results["step"] == manifest["training"]["step"]
    # ModelNet reads `input_size`, TrackNet `track_input_size` (160 px since 2026-12-08), and
    # the evaluation rendered the frames TrackNet reads.
    assert results["evaluation"]["image_size"] == manifest.get("track_input_size", manifest["input_size"])
    for key in METRIC_KEYS:
        assert manifest["metrics"][key] == pytest.approx(results["metrics"][key], rel=1e-9), key
    size = sum(p.stat().st_size for p in MODELS.iterdir())
    assert size <= 60e6, f"assets/models holds {size / 1e6:.1f} MB, the budget is 60"


def test_onnx_models_track_and_personalize_held_out_people(manifest, face_model):
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    track = ort.InferenceSession(str(MODELS / "track_net.onnx"), options, providers=["CPUExecutionProvider"])
    model = ort.InferenceSession(str(MODELS / "model_net.onnx"), options, providers=["CPUExecutionProvider"])
    # TrackNet's crops (160 px) and ModelNet's (128 px) differ: ModelNet reads the same
    # renders resized to its own size, as evaluate.model_net_input does.
    size, model_size, frames, people = manifest.get("track_input_size", manifest["input_size"]), manifest["input_size"], 4, 3
    data = SyntheticData(face_model, face_model.restricted(), seed=HELD_OUT_SEED, image_size=size, frames=frames)
    mean = np.array(manifest["normalisation"]["mean"], np.float32).reshape(1, 3, 1, 1)
    std = np.array(manifest["normalisation"]["std"], np.float32).reshape(1, 3, 1, 1)
    euler_err, dR0_corr, gamma_err, gamma_prior_err = [], [], [], []
    for k in range(people):
        batch = data.batch(k, 1)
        x = (batch.images.numpy() - mean) / std
        w, euler, translation, gamma = track.run(None, {"images": x})
        assert w.shape == (frames, 53) and ((w >= 0) & (w <= 1)).all()
        assert np.isfinite(translation).all()
        euler_err.append(np.degrees(np.abs(euler - batch.euler.numpy())))
        # The ambient (band-0) coefficients: the light's level and colour.
        band0 = [0, 9, 18]
        assert (gamma[:, band0] > 0).all()
        gamma_err.append(np.abs(gamma - batch.gamma.numpy())[:, band0].mean())
        gamma_prior_err.append(np.abs(batch.gamma.numpy() - _ambient_prior())[:, band0].mean())
        model_x = model_net_input(torch.from_numpy(x), SimpleNamespace(input_size=model_size)).numpy()
        assert model_x.shape == (frames, 3, model_size, model_size)
        dS0, dS, dR0, dR = model.run(None, {"images": model_x})
        assert (dS0.shape, dS.shape, dR0.shape, dR.shape) == ((1, 3, 128, 128), (1, 53, 3, 128, 128), (1, 3, 128, 128), (1, 53, 3, 128, 128))
        assert all(np.isfinite(t).all() for t in (dS0, dS, dR0, dR))
        covered = torch.from_numpy(face_model.fixture.parsing_map[0] > 0)
        covered = torch.nn.functional.interpolate(covered[None, None].float(), size=(128, 128), mode="nearest")[0, 0].bool().numpy()
        true = batch.dR0[0].numpy()[:, covered].ravel()
        predicted = dR0[0][:, covered].ravel()
        dR0_corr.append(np.corrcoef(true, predicted)[0, 1])
    euler_mae = np.concatenate(euler_err).mean(0)
    print("held-out yaw/pitch/roll MAE (deg):", euler_mae, "dR0 correlation:", dR0_corr, "gamma MAE:", np.mean(gamma_err), "prior:", np.mean(gamma_prior_err))
    # Measured on 40 people: 2.8 / 4.0 / 2.3 degrees.
    assert (euler_mae < 8.0).all()
    # The ambient light is only a little closer to the truth than the fixed prior (measured
    # 0.114 against 0.151 on these people): a brighter albedo under a dimmer light renders
    # the same image, and ModelNet's per-person albedo absorbs the difference. Only its sign
    # is checked: light is positive.
    assert all(e < 2 * p for e, p in zip(gamma_err, gamma_prior_err))
    # ModelNet's static albedo correction follows the person's true one.
    assert np.mean(dR0_corr) > 0.3


def _ambient_prior() -> np.ndarray:
    """TrackNet's fixed prior gamma (train.Trainer): ambient 0.7, no directional part."""
    prior = np.zeros(27, np.float32)
    prior[[0, 9, 18]] = 0.7 / (math.pi / (4 * math.pi) ** 0.5)
    return prior
