"""The exported ONNX models compute what the PyTorch networks compute."""

import pytest
import torch

from likeness_train.export import FP16_MIN_ELEMENTS, export_onnx, onnx_outputs_max_abs_diff, parity, store_weights_fp16
from likeness_train.networks import ModelNet, TrackNet


@pytest.mark.parametrize("pool", ["avg", "flatten"])
def test_onnx_runtime_matches_pytorch(tmp_path, pool):
    torch.manual_seed(1)
    track = TrackNet(width=0.25, pool=pool)
    model = ModelNet(input_size=128, width=0.25)
    # Non-trivial heads (they start at zero) so the parity check means something.
    with torch.no_grad():
        for head in (track.head, model.shape_decoder.blendshape_head, model.albedo_decoder.static_head):
            head.weight.normal_(0, 0.05)
    track_path, model_path = export_onnx(track, model, 128, tmp_path)
    diffs = parity(track, model, track_path, model_path, 128)
    print("ONNX Runtime vs PyTorch max abs difference:", diffs)
    assert diffs["track_net"] < 1e-4
    assert diffs["model_net"] < 1e-4


def test_a_tracknet_only_export_keeps_the_exported_model_net_and_evaluates_with_it(tmp_path):
    """`--model-net-from`: a warm-up's TrackNet shipped beside an earlier run's ModelNet and
    R_0^t: those files are kept byte for byte, TrackNet is the new one, the manifest says
    where ModelNet came from, and evaluate.py runs the pair through ONNX Runtime."""
    import json

    from likeness_train.evaluate import main as evaluate_main
    from likeness_train.export import main as export_main
    from likeness_train.networks import ExportedModelNet, load_networks
    from likeness_train.train import TrainConfig, Trainer

    def checkpoint(name, seed):
        config = TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25)
        trainer = Trainer(config, tmp_path / name)
        with torch.no_grad():  # ModelNet's heads start at zero; make its output non-trivial
            trainer.modelnet.albedo_decoder.static_head.weight.normal_(0, 0.05)
            g = torch.Generator().manual_seed(seed)  # Trainer seeds the global RNG itself
            for p in trainer.track.parameters():
                p.add_(0.01 * torch.randn(p.shape, generator=g))
        trainer.save()
        return trainer.checkpoint_path

    first, second = checkpoint("first", 1), checkpoint("second", 2)
    shipped = tmp_path / "shipped"
    # float32 weights, so that the exported ModelNet can be held to PyTorch's at 1e-4 below
    export_main(["--checkpoint", str(first), "--out", str(shipped), "--fp32-weights"])
    before = {n: (shipped / n).read_bytes() for n in ("model_net.onnx", "mean_albedo.safetensors", "track_net.onnx")}
    first_manifest = json.loads((shipped / "manifest.json").read_text())
    # With float16 weights (the default) the kept float32 ModelNet is stored as float16 too,
    # its outputs within float16's precision of the kept file's.
    halved = tmp_path / "halved"
    export_main(["--checkpoint", str(second), "--out", str(halved), "--model-net-from", str(shipped)])
    assert (halved / "model_net.onnx").stat().st_size < 0.6 * len(before["model_net.onnx"])
    assert (halved / "mean_albedo.safetensors").read_bytes() == before["mean_albedo.safetensors"]
    rounded = json.loads((halved / "manifest.json").read_text())["fp16_storage_max_abs_diff"]["model_net"]
    assert set(rounded) == {"dS0", "dS", "dR0", "dR"} and 0 < max(rounded.values()) < 1e-2, rounded
    out = tmp_path / "models"
    export_main(["--checkpoint", str(second), "--out", str(out), "--model-net-from", str(shipped), "--fp32-weights"])
    for name in ("model_net.onnx", "mean_albedo.safetensors"):
        assert (out / name).read_bytes() == before[name], name
    assert (out / "track_net.onnx").read_bytes() != before["track_net.onnx"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["training"]["model_net_from"]["training_commit"] == first_manifest["training_commit"]
    assert manifest["parity_max_abs_diff"]["model_net"] == first_manifest["parity_max_abs_diff"]["model_net"]
    assert manifest["parity_max_abs_diff"]["track_net"] < 1e-4
    # Both exports kept float32 (`--fp32-weights`).
    assert manifest["fp16_storage_max_abs_diff"] is None
    assert first_manifest["fp16_storage_max_abs_diff"] is None

    # The exported ModelNet behind ModelNet's interface computes what the PyTorch one did.
    nets = load_networks(second, model_net_from=out)
    assert isinstance(nets.model, ExportedModelNet)
    images = torch.rand(2, 2, 3, 128, 128) * 2 - 1
    with torch.no_grad():
        want = load_networks(first).model(images)
    got = nets.model(images)
    for a, b in zip((got.dS0, got.dS, got.dR0, got.dR), (want.dS0, want.dS, want.dR0, want.dR)):
        assert a.shape == b.shape and float((a - b).abs().max()) < 1e-4
    assert torch.equal(nets.mean_albedo, load_networks(first).mean_albedo.to(torch.float16).float())

    result_path = tmp_path / "eval.json"
    evaluate_main(["--checkpoint", str(second), "--out", str(result_path), "--people", "1", "--frames", "2", "--threads", "1", "--model-net-from", str(out)])
    result = json.loads(result_path.read_text())
    assert result["model_net_from"] == str(out)
    with pytest.raises(SystemExit, match="not an exported models directory"):
        export_main(["--checkpoint", str(second), "--out", str(tmp_path / "x"), "--model-net-from", str(tmp_path / "first")])
    manifest["input_size"] = 96  # no ModelNet reads 96 px
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(SystemExit, match="reads 96 px images"):
        evaluate_main(["--checkpoint", str(second), "--out", str(result_path), "--model-net-from", str(out)])
    with pytest.raises(SystemExit, match="no such file"):
        evaluate_main(["--checkpoint", str(second), "--out", str(result_path), "--model-net-from", str(tmp_path / "first")])

    # A TrackNet for 160 px crops (issue 31) ships beside the kept 128 px ModelNet: the
    # manifest gives each network its size, the files read those sizes, and the evaluation
    # feeds ModelNet the crops resized to its own.
    config = TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25, input_size=160)
    large = Trainer(config, tmp_path / "large")
    large.save()
    with pytest.raises(SystemExit, match="reads 160 px and its ModelNet was never trained"):
        export_main(["--checkpoint", str(large.checkpoint_path), "--out", str(tmp_path / "y"), "--fp32-weights"])
    mixed = tmp_path / "mixed"
    export_main(["--checkpoint", str(large.checkpoint_path), "--out", str(mixed), "--model-net-from", str(shipped), "--fp32-weights"])
    sizes = json.loads((mixed / "manifest.json").read_text())
    assert (sizes["input_size"], sizes["track_input_size"]) == (128, 160)
    assert sizes["crop"] == first_manifest["crop"]
    import onnx

    def input_side(path):
        return onnx.load(str(path)).graph.input[0].type.tensor_type.shape.dim[3].dim_value

    assert (input_side(mixed / "track_net.onnx"), input_side(mixed / "model_net.onnx")) == (160, 128)
    # Without --web-track-net the browser's TrackNet is the same file; with it, the named
    # checkpoint's (a 128 px one beside the 160 px), and never a larger one than native.
    assert (mixed / "track_net_web.onnx").read_bytes() == (mixed / "track_net.onnx").read_bytes()
    assert sizes["web_track_net"] == {"file": "track_net_web.onnx", "input_size": 160, "same_as": "track_net.onnx"}
    export_main(["--checkpoint", str(large.checkpoint_path), "--out", str(mixed), "--model-net-from", str(mixed), "--fp32-weights", "--web-track-net", str(second)])
    web = json.loads((mixed / "manifest.json").read_text())["web_track_net"]
    assert (web["file"], web["input_size"], web["checkpoint"]) == ("track_net_web.onnx", 128, second.name)
    assert web["parity_max_abs_diff"] < 1e-4 and input_side(mixed / "track_net_web.onnx") == 128
    # Refused before anything is written: a larger browser TrackNet, a missing or junk file.
    for bad, message in ((large.checkpoint_path, "at most TrackNet's 128 px"), (tmp_path / "none.pt", "no such checkpoint"), (tmp_path / "junk.pt", "not a training checkpoint")):
        (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
        with pytest.raises(SystemExit, match=message):
            export_main(["--checkpoint", str(second), "--out", str(tmp_path / "z"), "--fp32-weights", "--web-track-net", str(bad)])
        assert not (tmp_path / "z").exists()
    evaluate_main(["--checkpoint", str(large.checkpoint_path), "--out", str(result_path), "--people", "1", "--frames", "2", "--threads", "1", "--model-net-from", str(mixed)])
    assert json.loads(result_path.read_text())["evaluation"]["image_size"] == 160


def test_float16_storage_halves_the_file_rounds_each_weight_once_and_keeps_the_outputs(tmp_path, monkeypatch):
    """store_weights_fp16: every large float32 initializer becomes exactly its float16
    rounding behind a Cast, small ones stay float32, the file shrinks to about half, and
    ONNX Runtime's outputs move by about float16's relative precision (2^-11) times the
    activations' size, far below the export's refusal threshold for w."""
    import shutil

    import numpy as np
    import onnx
    from onnx import TensorProto, numpy_helper

    torch.manual_seed(3)
    track = TrackNet(width=0.25, pool="flatten")
    with torch.no_grad():
        track.head.weight.normal_(0, 0.05)
    path, _ = export_onnx(track, None, 128, tmp_path)
    reference = tmp_path / "fp32.onnx"
    shutil.copyfile(path, reference)
    before = {i.name: numpy_helper.to_array(i) for i in onnx.load(str(reference)).graph.initializer}

    converted = store_weights_fp16(path)
    after = onnx.load(str(path))
    large = [n for n, v in before.items() if v.dtype == np.float32 and v.size >= FP16_MIN_ELEMENTS]
    assert converted == len(large) > 0
    stored = {i.name: i for i in after.graph.initializer}
    for name in large:
        init = stored[f"{name}__fp16"]
        assert init.data_type == TensorProto.FLOAT16
        assert np.array_equal(numpy_helper.to_array(init), before[name].astype(np.float16))
    for name, values in before.items():
        if name not in large:
            assert numpy_helper.to_array(stored[name]).dtype == values.dtype
    casts = [n for n in after.graph.node if n.op_type == "Cast"]
    assert {c.output[0] for c in casts} >= set(large)
    assert path.stat().st_size < 0.55 * reference.stat().st_size

    diffs = onnx_outputs_max_abs_diff(reference, path, 128, batch=3)
    print("float16 storage, max abs difference per output:", diffs)
    assert set(diffs) == {"w", "euler", "translation", "gamma"}
    assert 0 < diffs["w"] < 2e-3
    # A second pass finds nothing left to convert and leaves the file as it is.
    size = path.stat().st_size
    assert store_weights_fp16(path) == 0 and path.stat().st_size == size

    # The export refuses float16 weights that would move w by more than its tolerance.
    import likeness_train.export as export

    export_onnx(track, None, 128, tmp_path)
    monkeypatch.setattr(export, "FP16_W_TOLERANCE", 0.0)
    with pytest.raises(SystemExit, match="float16 weights move w by"):
        export.to_fp16_storage(path, 128, batch=3)
