"""ONNX export of TrackNet and ModelNet, with the manifest the Rust inference reads.

`python -m likeness_train.export --checkpoint CKPT --out assets/models` writes
`track_net.onnx` ([B,3,H,W] -> w, euler, translation, gamma), `model_net.onnx`
([N,3,H,W] -> dS0, dS, dR0, dR for one person) and `manifest.json`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import nn

from .networks import ModelNet, TrackNet, load_networks

# Input normalisation shared by training and inference: RGB in [0, 1], then (x - mean) / std.
IMAGE_MEAN = (0.5, 0.5, 0.5)
IMAGE_STD = (0.5, 0.5, 0.5)


@dataclass
class Manifest:
    input_size: int
    track_width: float
    model_width: float
    blendshape_names: list[str]
    uv_size: int = 128
    normalisation: dict = field(default_factory=lambda: {"mean": list(IMAGE_MEAN), "std": list(IMAGE_STD), "range": "RGB in [0, 1] before normalising"})
    outputs: dict = field(
        default_factory=lambda: {
            "track_net": {"w": "[B,53] sigmoid", "euler": "[B,3] yaw, pitch, roll radians", "translation": "[B,3] cm, camera space", "gamma": "[B,27] SH r0..r8 g0..g8 b0..b8"},
            "model_net": {"dS0": "[1,3,128,128] cm", "dS": "[1,53,3,128,128] cm", "dR0": "[1,3,128,128]", "dR": "[1,53,3,128,128]"},
        }
    )
    camera: dict = field(default_factory=dict)
    training_commit: str = ""
    metrics: dict = field(default_factory=dict)


class _TrackWrapper(nn.Module):
    def __init__(self, net: TrackNet):
        super().__init__()
        self.net = net

    def forward(self, images):
        p = self.net(images)
        return p.w, p.euler, p.translation, p.gamma


class _ModelWrapper(nn.Module):
    """One person: [N,3,H,W] -> corrections with a leading person axis of 1."""

    def __init__(self, net: ModelNet):
        super().__init__()
        self.net = net

    def forward(self, images):
        c = self.net(images.unsqueeze(0))
        return c.dS0, c.dS, c.dR0, c.dR


def git_commit() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def export_onnx(track: TrackNet, model: ModelNet, input_size: int, out_dir: Path) -> tuple[Path, Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    track_path, model_path = out_dir / "track_net.onnx", out_dir / "model_net.onnx"
    track.eval()
    model.eval()
    with warnings.catch_warnings():
        # The legacy exporter writes one self-contained opset-17 file (no .onnx.data beside
        # it) and warns that it is deprecated; see docs/training.md.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _TrackWrapper(track),
            (torch.zeros(1, 3, input_size, input_size),),
            str(track_path),
            input_names=["images"],
            output_names=["w", "euler", "translation", "gamma"],
            dynamic_axes={"images": {0: "batch"}, "w": {0: "batch"}, "euler": {0: "batch"}, "translation": {0: "batch"}, "gamma": {0: "batch"}},
            opset_version=17,
            dynamo=False,
        )
        torch.onnx.export(
            _ModelWrapper(model),
            (torch.zeros(4, 3, input_size, input_size),),
            str(model_path),
            input_names=["images"],
            output_names=["dS0", "dS", "dR0", "dR"],
            dynamic_axes={"images": {0: "frames"}},
            opset_version=17,
            dynamo=False,
        )
    return track_path, model_path


def parity(track: TrackNet, model: ModelNet, track_path: Path, model_path: Path, input_size: int, seed: int = 0) -> dict:
    """Max abs difference between PyTorch and ONNX Runtime on random inputs."""
    import onnxruntime as ort

    g = torch.Generator().manual_seed(seed)
    images = torch.rand(3, 3, input_size, input_size, generator=g) * 2 - 1
    result = {}
    with torch.no_grad():
        ref_track = [t.numpy() for t in _TrackWrapper(track.eval())(images)]
        ref_model = [t.numpy() for t in _ModelWrapper(model.eval())(images)]
    for name, path, ref in (("track_net", track_path, ref_track), ("model_net", model_path, ref_model)):
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        got = session.run(None, {"images": images.numpy()})
        result[name] = float(max(np.abs(a - b).max() for a, b in zip(got, ref)))
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("assets/models"))
    parser.add_argument("--metrics", type=Path, default=None, help="results.json of `python -m likeness_train.evaluate` for the manifest's `metrics`")
    args = parser.parse_args(argv)
    nets = load_networks(args.checkpoint)
    cfg, ckpt, track, model = nets.config, nets.checkpoint, nets.track, nets.model
    track_path, model_path = export_onnx(track, model, cfg["input_size"], args.out)
    diffs = parity(track, model, track_path, model_path, cfg["input_size"])
    manifest = Manifest(
        input_size=cfg["input_size"],
        track_width=cfg["track_width"],
        model_width=cfg["model_width"],
        blendshape_names=list(cfg["blendshape_names"]),
        camera=cfg.get("camera", {}),
        training_commit=ckpt.get("commit", git_commit()),
        metrics=json.loads(args.metrics.read_text())["metrics"] if args.metrics else ckpt.get("metrics", {}),
    )
    (args.out / "manifest.json").write_text(json.dumps(asdict(manifest), indent=2) + "\n")
    print(f"wrote {track_path} ({track_path.stat().st_size / 1e6:.1f} MB), {model_path} ({model_path.stat().st_size / 1e6:.1f} MB)")
    print(f"ONNX Runtime vs PyTorch max abs difference: {diffs}")


if __name__ == "__main__":
    main()
