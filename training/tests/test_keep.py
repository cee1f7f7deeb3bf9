"""The kept checkpoint: smaller than the run's (no optimiser), the same networks in every
reader (evaluation's load_networks, --init-track-from), bad input refused by name."""

import pytest
import torch

from likeness_train.keep import keep
from likeness_train.keep import main as keep_main
from likeness_train.networks import load_networks
from likeness_train.train import TrainConfig, Trainer


def _config(**overrides):
    base = dict(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25)
    return TrainConfig(**{**base, **overrides})


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A run's checkpoint after one real warm-up step, so the optimiser has moments to drop
    and TrackNet's weights differ from a fresh initialisation."""
    out = tmp_path_factory.mktemp("run")
    trainer = Trainer(_config(), out)
    trainer.run()
    return trainer.checkpoint_path


def test_kept_checkpoint_has_the_same_networks_without_the_optimiser(trained, tmp_path):
    out = tmp_path / "kept" / "net.pt"
    keep_main(["--checkpoint", str(trained), "--out", str(out)])
    original = torch.load(trained, map_location="cpu", weights_only=False)
    kept = torch.load(out, map_location="cpu", weights_only=False)
    assert "optimizer" in original and "optimizer" not in kept
    assert out.stat().st_size < trained.stat().st_size
    assert kept["step"] == original["step"] and kept["config"] == original["config"]
    # A warm-up never trains ModelNet or R_0^t: they are left out and built afresh.
    assert original["stage"] == 0 and "model_net" not in kept and "mean_albedo" not in kept
    assert load_networks(out).mean_albedo is None

    a, b = load_networks(trained), load_networks(out)
    torch.manual_seed(0)
    image = torch.rand(2, 3, 128, 128)
    with torch.no_grad():
        x, y = a.track(image), b.track(image)
    for field in ("w", "euler", "translation", "gamma"):
        assert torch.equal(getattr(x, field), getattr(y, field)), field

    # --init-track-from reads it as it reads the run's own checkpoint.
    fresh = Trainer(_config(init_track_from=str(out)), tmp_path / "next")
    for name, value in original["track_net"].items():
        assert torch.equal(fresh.track.state_dict()[name], value), name


def test_a_float16_copy_holds_the_rounded_weights_and_tracks_alike(trained, tmp_path):
    full, half = tmp_path / "full.pt", tmp_path / "half.pt"
    keep_main(["--checkpoint", str(trained), "--out", str(full)])
    keep_main(["--checkpoint", str(trained), "--out", str(half), "--float16"])
    assert half.stat().st_size < 0.6 * full.stat().st_size
    original = torch.load(trained, map_location="cpu", weights_only=False)["track_net"]
    stored = torch.load(half, map_location="cpu", weights_only=False)["track_net"]
    for name, value in original.items():
        if value.is_floating_point():
            assert stored[name].dtype == torch.float16, name
            assert torch.equal(stored[name].float(), value.half().float()), name
        else:
            assert torch.equal(stored[name], value), name
    # Every reader loads it into float32 networks that track as the original does, up to
    # the weights' rounding.
    a, b = load_networks(trained), load_networks(half)
    assert all(p.dtype == torch.float32 for p in b.track.parameters())
    torch.manual_seed(0)
    image = torch.rand(2, 3, 128, 128)
    with torch.no_grad():
        x, y = a.track(image), b.track(image)
    for field in ("w", "euler", "translation", "gamma"):
        assert torch.allclose(getattr(x, field), getattr(y, field), atol=2e-2), field
    fresh = Trainer(_config(init_track_from=str(half)), tmp_path / "next")
    for name, value in original.items():
        assert fresh.track.state_dict()[name].dtype == value.dtype, name


def test_keep_refuses_bad_input(trained, tmp_path):
    with pytest.raises(SystemExit, match="no such checkpoint"):
        keep_main(["--checkpoint", str(tmp_path / "missing.pt"), "--out", str(tmp_path / "a.pt")])
    with pytest.raises(SystemExit, match="is the checkpoint itself"):
        keep_main(["--checkpoint", str(trained), "--out", str(trained)])
    garbage = tmp_path / "garbage.pt"
    garbage.write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="cannot be read"):
        keep(garbage, tmp_path / "b.pt")
    other = tmp_path / "other.pt"
    torch.save({"config": {}}, other)
    with pytest.raises(ValueError, match="no track_net"):
        keep(other, tmp_path / "c.pt")
    assert not (tmp_path / "b.pt").exists() and not (tmp_path / "c.pt").exists()


def test_a_checkpoint_past_the_warm_up_keeps_model_net_and_the_albedo(tmp_path):
    trainer = Trainer(_config(landmark_warmup_steps=0, stage1_steps=1), tmp_path / "run")
    trainer.run()
    original = torch.load(trainer.checkpoint_path, map_location="cpu", weights_only=False)
    assert original["stage"] >= 1
    kept = keep(trainer.checkpoint_path, tmp_path / "kept.pt")
    assert "optimizer" not in kept
    for name, value in original["model_net"].items():
        assert torch.equal(kept["model_net"][name], value), name
    assert torch.equal(kept["mean_albedo"], original["mean_albedo"])
    nets = load_networks(tmp_path / "kept.pt")
    for name, value in original["model_net"].items():
        assert torch.equal(nets.model.state_dict()[name], value), name
