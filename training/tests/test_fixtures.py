"""The tracking parity fixture (fixtures.py): the layout the Rust tests read, and inputs
that are exactly the sampler's output for the stored PNG and crop."""

import json

import numpy as np
import pytest

from likeness_train import fixtures as FX
from likeness_train.preprocess import CropFraming, Rect, crop_for_landmarks, sample_rect


@pytest.fixture(scope="module")
def fixture_dir(tmp_path_factory, face_model):
    out = tmp_path_factory.mktemp("fx") / "tracking-fixture"
    FX.write_fixture(out, model=face_model)
    return out


@pytest.fixture(scope="module")
def tensors(fixture_dir):
    from safetensors.numpy import load_file

    return load_file(str(fixture_dir / "fixture.safetensors"))


def test_fixture_layout_and_shapes(fixture_dir, tensors):
    info = json.loads((fixture_dir / "fixture.json").read_text())
    k = info["frames"]
    assert k >= 4 and len(info["files"]) == k and len(info["canvas_sizes"]) == k
    assert info["seed"] == FX.FIXTURE_SEED and info["seed"] not in (1, 1000)
    assert len({tuple(s) for s in info["canvas_sizes"]}) >= 2
    manifest = json.loads((FX.MODELS / "manifest.json").read_text())
    assert info["framing"] == {"centre_offset": manifest["crop"]["centre_offset"], "scale": manifest["crop"]["scale"]}
    assert info["models"]["track_net.onnx"] == FX.sha256(FX.MODELS / "track_net.onnx")
    s, m = info["track_input_size"], info["input_size"]  # TrackNet's, ModelNet's
    assert (s, m) == (manifest.get("track_input_size", manifest["input_size"]), manifest["input_size"])
    shapes = {"landmarks": (68, 2), "crop": (4,), "input": (1, 3, s, s), "model_input": (1, 3, m, m), "w": (53,), "euler": (3,), "translation": (3,), "gamma": (27,)}
    for i in range(k):
        for name, shape in shapes.items():
            t = tensors[f"{name}_{i}"]
            assert t.shape == shape and t.dtype == np.float32 and np.isfinite(t).all(), (name, i)
        assert ((tensors[f"w_{i}"] >= 0) & (tensors[f"w_{i}"] <= 1)).all()
    assert tensors["dS0"].shape == (1, 3, 128, 128) and tensors["dS"].shape == (1, 53, 3, 128, 128)
    assert tensors["dR0"].shape == (1, 3, 128, 128) and tensors["dR"].shape == (1, 53, 3, 128, 128)
    assert set(tensors) == {f"{n}_{i}" for n in shapes for i in range(k)} | {"dS0", "dS", "dR0", "dR"}


def test_fixture_inputs_are_the_preprocessed_frames(fixture_dir, tensors):
    info = json.loads((fixture_dir / "fixture.json").read_text())
    framing = CropFraming(tuple(info["framing"]["centre_offset"]), info["framing"]["scale"])
    norm = info["normalisation"]
    filters, inside = [], []
    for i, (name, (w, h)) in enumerate(zip(info["files"], info["canvas_sizes"])):
        image = FX.read_png(fixture_dir / name)
        assert image.shape == (h, w, 3) and image.dtype == np.uint8
        rect = Rect(*tensors[f"crop_{i}"])
        assert rect == crop_for_landmarks(tensors[f"landmarks_{i}"], framing)
        s, m = info["track_input_size"], info["input_size"]
        x = sample_rect(image, rect, s, s, norm["mean"], norm["std"])
        assert np.array_equal(x, tensors[f"input_{i}"]), i  # bit for bit
        assert np.array_equal(sample_rect(image, rect, m, m, norm["mean"], norm["std"]), tensors[f"model_input_{i}"]), i
        filters.append(rect.box_filter(s, s)[0])
        inside.append(rect.inside(w, h))
        # The true landmarks are where the frame spec put the face.
        spec = FX.FRAMES[i]
        centre = tensors[f"landmarks_{i}"][:60].mean(0)
        assert np.abs(centre - np.array(spec.centre)).max() < 0.3 * spec.face_px
    # The sampler's cases: upscaled, downscaled by 2 or more, and a crop outside the canvas.
    assert 1 in filters and max(filters) >= 2 and not all(inside)
    assert [p["box_filter"][0] for p in info["per_frame"]] == filters


def test_fixture_network_outputs_are_onnx_runtime_on_the_inputs(tensors):
    track = FX.ort_session(FX.MODELS / "track_net.onnx")
    w, euler, translation, gamma = track.run(None, {"images": tensors["input_0"]})
    for name, value in (("w", w), ("euler", euler), ("translation", translation), ("gamma", gamma)):
        assert np.array_equal(value[0], tensors[f"{name}_0"]), name
    # A frontal-ish synthetic face in front of the camera: TrackNet's translation has z < 0.
    assert all(tensors[f"translation_{i}"][2] < 0 for i in range(len(FX.FRAMES)))


def test_fixture_frames_are_deterministic(fixture_dir, face_model):
    again = FX.make_frames(face_model, specs=FX.FRAMES[:1])[0]
    assert np.array_equal(again["image"], FX.read_png(fixture_dir / "frames" / "frame_0.png"))


def test_fixture_refuses_bad_output_folders(tmp_path, face_model):
    with pytest.raises(ValueError, match="parent folder"):
        FX.write_fixture(tmp_path / "missing" / "fixture", model=face_model)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="did not write"):
        FX.write_fixture(foreign, model=face_model)
    with pytest.raises(SystemExit):
        FX.main(["--out", str(tmp_path / "x"), "--seed", "1"])
    with pytest.raises(SystemExit):
        FX.main(["--out", str(tmp_path / "missing" / "x")])
