"""The exported ONNX models compute what the PyTorch networks compute."""

import pytest
import torch

from likeness_train.export import export_onnx, parity
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
    export_main(["--checkpoint", str(first), "--out", str(shipped)])
    before = {n: (shipped / n).read_bytes() for n in ("model_net.onnx", "mean_albedo.safetensors", "track_net.onnx")}
    first_manifest = json.loads((shipped / "manifest.json").read_text())
    out = tmp_path / "models"
    export_main(["--checkpoint", str(second), "--out", str(out), "--model-net-from", str(shipped)])
    for name in ("model_net.onnx", "mean_albedo.safetensors"):
        assert (out / name).read_bytes() == before[name], name
    assert (out / "track_net.onnx").read_bytes() != before["track_net.onnx"]
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["training"]["model_net_from"]["training_commit"] == first_manifest["training_commit"]
    assert manifest["parity_max_abs_diff"]["model_net"] == first_manifest["parity_max_abs_diff"]["model_net"]
    assert manifest["parity_max_abs_diff"]["track_net"] < 1e-4

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
    manifest["input_size"] = 224
    (out / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(SystemExit, match="reads 224 px images"):
        evaluate_main(["--checkpoint", str(second), "--out", str(result_path), "--model-net-from", str(out)])
    with pytest.raises(SystemExit, match="no such file"):
        evaluate_main(["--checkpoint", str(second), "--out", str(result_path), "--model-net-from", str(tmp_path / "first")])
