"""The go/no-go probe of TrackNet's expression objective (issue 31) before any long run.

A short warm-up (`python -m likeness_train.train --out runs/probe --landmark-warmup-steps
1000 --stage1-steps 0 --stage2-steps 0 ...`) and its held-out evaluation (`python -m
likeness_train.evaluate --checkpoint runs/probe/checkpoint.pt --out results/probe.json`)
pass when, within those steps:

- the supervised w term (`sup` in the log, TrainConfig.w_loss per image) falls well below
  (at most `FLOOR_FRACTION` of) the constant-predictor floor: the least that term can be
  for a prediction that ignores the image, computed on the batches the run read;
- the held-out correlation of w with the truth rises (above `MIN_CORRELATION`, from ~0 for
  the untrained network's constant output) on every visible channel.

`python -m likeness_train.probe --run runs/probe --data .cache/data-v3-s1-128
--evaluation results/probe.json` prints the curve (window means of `sup`, the floor, the
gradient norms of each term at TrackNet's trunk), the verdict, and writes them with
`--out`.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import torch

FLOOR_FRACTION = 0.5
MIN_CORRELATION = 0.1


def constant_floor(truth: torch.Tensor, kind: str) -> float:
    """The least per-image value of the w term (train.w_loss) that one constant prediction
    for all frames reaches, on truth [F, 53]: at the mean for "sq", the median for "l1"; for
    "bce_l1" each channel's minimum over a grid of 10,001 constants in [0, 1] (the sum is
    convex in the constant, so the grid's minimum is within ~1e-4 of it)."""
    truth = truth.double()
    if kind == "sq":
        return float((truth - truth.mean(0, keepdim=True)).pow(2).sum(1).mean())
    if kind == "l1":
        return float((truth - truth.median(0, keepdim=True).values).abs().sum(1).mean())
    if kind == "bce_l1":
        total = 0.0
        grid = torch.linspace(0.0, 1.0, 10_001, dtype=torch.float64).clamp(1e-7, 1 - 1e-7)
        for t in truth.T:  # one channel [F]
            # Mean cross-entropy is linear in mean(t); mean |c - t| from the sorted values and
            # their prefix sums (a grid x frames difference would be 5 GB for 64,000 frames).
            entropy = -(t.mean() * grid.log() + (1 - t.mean()) * (1 - grid).log())
            values = t.sort().values
            prefix = torch.cat([values.new_zeros(1), values.cumsum(0)])
            below = torch.searchsorted(values, grid, right=True)  # how many t <= c
            n = values.numel()
            l1 = (grid * below - prefix[below] + (prefix[-1] - prefix[below]) - grid * (n - below)) / n
            total += float((entropy + l1).min())
        return total
    raise ValueError(f"unknown w loss {kind!r}")


def read_log(run: Path) -> list[dict]:
    path = run / "log.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: run the warm-up first (see this module's doc)")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def windows(log: list[dict], key: str, size: int = 100) -> list[tuple[int, float]]:
    """(last step, mean of `key`) over the windows of `size` steps (1-100, 101-200, ...)."""
    groups: dict[int, list[float]] = {}
    for entry in log:
        if key in entry:
            groups.setdefault((entry["step"] - 1) // size, []).append(entry[key])
    return [((g + 1) * size, sum(v) / len(v)) for g, v in sorted(groups.items())]


def verdict(log: list[dict], floor: float, evaluation: dict | None) -> dict:
    sup = windows(log, "sup")
    last = sup[-1][1] if sup else float("nan")
    result = {
        "steps": max((e["step"] for e in log), default=0),
        "sup_windows": sup,
        "floor": floor,
        "final_sup_over_floor": last / floor if floor > 0 else float("nan"),
        "gradients": {k: windows(log, k) for k in sorted({k for e in log for k in e if k.startswith("grad_")})},
    }
    passed = result["final_sup_over_floor"] <= FLOOR_FRACTION
    if evaluation is not None:
        channels = evaluation["expressions"]["per_channel"]
        flat = [n for n, c in channels.items() if c["visible"] and not c["correlation"] > MIN_CORRELATION]
        result["visible_channels_not_rising"] = flat
        result["median_visible_correlation"] = evaluation["expressions"]["median_visible_correlation"]
        result["mae_all"] = evaluation["expressions"]["mae_all"]
        passed = passed and not flat
    result["go"] = passed if evaluation is not None else None
    return result


def main(argv: list[str] | None = None) -> None:
    from .dataset import CachedData

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, required=True, help="the probe's training directory (its log.jsonl and checkpoint.pt)")
    parser.add_argument("--data", type=Path, required=True, help="the cache the probe trained on")
    parser.add_argument("--evaluation", type=Path, default=None, help="the held-out evaluation of the probe's checkpoint")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    log = read_log(args.run)
    checkpoint = torch.load(args.run / "checkpoint.pt", map_location="cpu", weights_only=False)
    config = checkpoint["config"]
    kind = config.get("w_loss", "sq")
    steps = max(e["step"] for e in log)
    cache = CachedData(args.data)
    read = steps * config.get("warmup_batches_per_step", 1)
    truth = torch.cat([cache.weights(k) for k in range(min(read, len(cache)))])
    evaluation = json.loads(args.evaluation.read_text()) if args.evaluation else None
    result = {"w_loss": kind, **verdict(log, constant_floor(truth, kind), evaluation)}
    print(f"w loss {kind}: constant-predictor floor {result['floor']:.3f} per image (over {truth.shape[0]} training frames)")
    for step, value in result["sup_windows"]:
        print(f"  steps up to {step:5d}: sup {value:.3f} ({value / result['floor']:.2f} of the floor)")
    for name, curve in result["gradients"].items():
        print(f"  {name} at the trunk: " + ", ".join(f"{v:.3g}" for _, v in curve[:: max(1, len(curve) // 5)]))
    if evaluation is not None:
        print(f"held-out: median visible correlation {result['median_visible_correlation']:.3f}; not rising: {result['visible_channels_not_rising'] or 'none'}")
    print("GO" if result["go"] else ("NO GO" if result["go"] is False else "no evaluation given: no verdict"))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
