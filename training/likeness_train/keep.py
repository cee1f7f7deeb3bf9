"""Keeps a run's networks where git keeps them: a checkpoint without its optimiser state.

`python -m likeness_train.keep --checkpoint runs/NAME/warmup.pt --out checkpoints/NAME.pt`
writes the checkpoint's config, step, TrackNet, ModelNet, mean albedo, metrics and any
w calibration, and leaves out the optimiser's moments (twice TrackNet's size again). A
landmark warm-up's checkpoint (stage 0) trains TrackNet alone: its ModelNet and R_0^t are
still their initial values, so they are left out too (46 -> ~27 MB for the 13,000-step
warm-up) and the readers build them afresh (`networks.load_networks`).

Why: runs live in `training/runs/`, which git ignores, and the next session may start on a
fresh machine: the 20,000-step warm-up of 2026-12-06 was lost that way. A kept checkpoint
is read by `evaluate.py`, `calibrate.py`, `export.py` and `train.py --init-track-from` like
the run's own; what it cannot do is resume that run's optimiser (a run started from it gets
a fresh one, as `--init-track-from` always does)."""

from __future__ import annotations

import argparse
import os
import pickle
import sys
from pathlib import Path

import torch

# What a kept checkpoint carries: everything the readers above use, nothing of the
# optimiser. The first two must be present for the file to be a checkpoint at all; a
# training checkpoint also has ModelNet (kept only once stage 1 has trained it).
REQUIRED_KEYS = ("config", "track_net")
KEPT_KEYS = REQUIRED_KEYS + ("model_net", "step", "stage", "mean_albedo", "metrics", "w_calibration", "commit", "elapsed_s")
UNTRAINED_IN_WARMUP = ("model_net", "mean_albedo")


def kept_state(state: dict) -> dict:
    """The kept part of a loaded checkpoint; ValueError when it is not a training checkpoint."""
    if not isinstance(state, dict):
        raise ValueError("not a training checkpoint (not a dictionary)")
    missing = [key for key in REQUIRED_KEYS if key not in state]
    if missing:
        raise ValueError(f"not a training checkpoint (no {', '.join(missing)})")
    warmup = state.get("stage") == 0
    return {key: state[key] for key in KEPT_KEYS if key in state and not (warmup and key in UNTRAINED_IN_WARMUP)}


# The state dicts `--float16` stores at half width (their floating-point tensors only).
NETWORK_KEYS = ("track_net", "model_net")


def halved(kept: dict) -> dict:
    """`kept` with the networks' floating-point tensors stored as float16. The readers load
    them into float32 networks (`load_state_dict` converts), so what changes is the
    rounding of each weight, the same rounding the shipped ONNX files store
    (`export.store_weights_fp16`); the file halves (24 -> 12 MB for TrackNet)."""
    out = dict(kept)
    for key in NETWORK_KEYS:
        if key in out:
            out[key] = {name: (t.half() if torch.is_tensor(t) and t.is_floating_point() else t) for name, t in out[key].items()}
    return out


def keep(checkpoint: Path, out: Path, float16: bool = False) -> dict:
    """Writes `checkpoint`'s kept part to `out` atomically and returns it; with `float16`,
    the networks' weights at half width (`halved`)."""
    if not checkpoint.is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    if out.exists() and os.path.samefile(out, checkpoint):
        raise ValueError(f"--out {out} is the checkpoint itself; write the kept copy elsewhere")
    try:
        state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    except (pickle.UnpicklingError, RuntimeError, EOFError, OSError) as e:
        raise ValueError(f"{checkpoint}: cannot be read as a checkpoint ({e})") from e
    try:
        kept = kept_state(state)
    except ValueError as e:
        raise ValueError(f"{checkpoint}: {e}") from e
    if float16:
        kept = halved(kept)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    torch.save(kept, tmp)
    tmp.replace(out)
    return kept


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--checkpoint", type=Path, required=True, help="a run's checkpoint.pt, warmup.pt or calibrated.pt")
    parser.add_argument("--out", type=Path, required=True, help="where to write the kept copy (training/checkpoints/NAME.pt)")
    parser.add_argument("--float16", action="store_true", help="store the networks' weights as float16 (half the file; the readers load them into float32)")
    args = parser.parse_args(argv)
    try:
        kept = keep(args.checkpoint, args.out, float16=args.float16)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(str(e)) from e
    size = args.out.stat().st_size / 1e6
    print(f"kept {args.checkpoint} (step {kept.get('step', '?')}) as {args.out}: {size:.1f} MB", file=sys.stderr)


if __name__ == "__main__":
    main()
