"""The ablation study (paper, table 1; issue 3, item 6): rows A -> B -> C -> D -> final, each
trained by the same training command with flags, evaluated on the same held-out people.

`python -m likeness_train.ablation --runs runs/ablation --data .cache/data-s1-128
--stage1-steps 800 --stage2-steps 200 --out results/ablation.md [--full results/full.json]`

For each row it runs `python -m likeness_train.train --out RUNS/ROW FLAGS...` (which resumes
an interrupted row from its checkpoint), then `python -m likeness_train.evaluate` into
`RUNS/ROW/results.json` (skipped when that file is newer than the checkpoint), and writes the
table. Each row's results are also kept in `results/ablation/ROW.json` (committed): a row whose
stored results match the budget and flags is not trained again. `--full FILE` adds the full
training's row (its evaluation `results.json`) below the ablation rows.

The rows, as the paper's (B and C use every loss but the parsing and gradient losses):
- A, "3DMM prior": ModelNet's identity-level corrections dS_0 and dR_0 only. Our template has
  no learned identity regressor, so dS_0 is what fits a person's shape here;
- B, A + blendshape corrections dS_i;
- C, B + dynamic albedo corrections dR_i;
- D, C + parsing loss;
- final, D + blendshape gradient loss.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from .evaluate import METRIC_KEYS
from .train import TrainConfig

ROWS: dict[str, tuple[str, list[str]]] = {
    "A": ("3DMM prior (identity corrections dS_0, dR_0 only)", ["--no-expression-corrections", "--no-dynamic-albedo", "--no-parsing-loss", "--no-gradient-loss"]),
    "B": ("A + blendshape corrections dS_i", ["--no-dynamic-albedo", "--no-parsing-loss", "--no-gradient-loss"]),
    "C": ("B + dynamic albedo corrections dR_i", ["--no-parsing-loss", "--no-gradient-loss"]),
    "D": ("C + parsing loss", ["--no-gradient-loss"]),
    "final": ("D + blendshape gradient loss", []),
}

# Column headings: what each metric is and which way is better.
HEADINGS = {
    "vertex_error_mm": "3D vertex error (mm) ↓",
    "landmark_nme": "landmark NME ↓",
    "photometric_error": "photometric error ↓",
    "expression_mae": "w MAE ↓",
    "personalization_recovery": "personalization recovery ↓ (1 = template)",
    "albedo_error": "albedo error ↓",
}


def _run(args: list[str]) -> None:
    print("$ " + " ".join(args), flush=True)
    if subprocess.run(args).returncode != 0:
        raise SystemExit(f"failed: {' '.join(args)} (rerun the ablation to resume from its checkpoint)")


def _read_results(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SystemExit(f"cannot read evaluation results {path}: {e}") from None


def _matches(results: dict, stage1: int, stage2: int, row: str, people: int, warmup_steps: int, frozen_steps: int | None = None) -> bool:
    """A stored row counts only if it was trained with this budget, this row's flags and the
    same loss normalisation, and evaluated on as many people."""
    from .train import config_from_args

    cfg = results.get("config", {})
    budget = ["--stage1-steps", str(stage1), "--stage2-steps", str(stage2), "--landmark-warmup-steps", str(warmup_steps)]
    if frozen_steps is not None:
        budget += ["--stage1-track-frozen-steps", str(frozen_steps)]
    expected, _ = config_from_args(["--out", "x", *budget, *ROWS[row][1]])
    keys = ("stage1_steps", "stage2_steps", "expression_corrections", "dynamic_albedo", "parsing_loss", "gradient_loss", "input_size", "track_width", "model_width", "sd_reduction", "bg_reduction", "weights",
            "landmark_warmup_steps", "warmup_lr_decay", "warmup_supervision", "warmup_light_supervision", "track_pool",
            "stage1_track_frozen_steps", "stage1_track_lr_ratio", "stage1_supervision")
    return all(cfg.get(k) == getattr(expected, k) for k in keys) and results.get("evaluation", {}).get("people") == people


def start_from_warmup(out: Path, warmup: Path, warmup_steps: int) -> None:
    """Puts a finished landmark warm-up (train.WARMUP_CHECKPOINT of any run with the same
    warm-up) in a row's directory, so the row resumes at stage 1: the warm-up trains TrackNet
    alone and does not depend on the row's flags, so the rows need not repeat it."""
    import torch

    if (out / "checkpoint.pt").exists():
        return
    try:
        state = torch.load(warmup, map_location="cpu", weights_only=False)
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same error for the user
        raise SystemExit(f"cannot read the warm-up checkpoint {warmup}: {e}") from None
    # Stage 0 at its last step, or stage 1 before its first step (what runs from before
    # train.WARMUP_CHECKPOINT saved at the switch): the same networks either way.
    if not isinstance(state, dict) or state.get("stage") not in (0, 1) or state.get("step") != warmup_steps:
        found = (state.get("stage"), state.get("step")) if isinstance(state, dict) else type(state).__name__
        raise SystemExit(f"{warmup} is not the end of a {warmup_steps}-step warm-up (stage, step = {found})")
    out.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(warmup, out / "checkpoint.pt")


def train_and_evaluate(
    row: str, runs: Path, common: list[str], people: int, stored: Path, stage1: int, stage2: int, warmup: Path | None = None, warmup_steps: int = 0,
    frozen_steps: int | None = None,
) -> dict:
    """Trains and evaluates one row, or reuses its stored results (committed with the
    repository, so a row survives the machine it was trained on)."""
    if stored.exists():
        results = _read_results(stored)
        if _matches(results, stage1, stage2, row, people, warmup_steps, frozen_steps):
            print(f"row {row}: using {stored}", flush=True)
            return results
    out = runs / row
    if warmup is not None:
        start_from_warmup(out, warmup, warmup_steps)
    python = sys.executable
    _run([python, "-m", "likeness_train.train", "--out", str(out), *common, *ROWS[row][1]])
    checkpoint, results = out / "checkpoint.pt", out / "results.json"
    if not results.exists() or results.stat().st_mtime < checkpoint.stat().st_mtime:
        _run([python, "-m", "likeness_train.evaluate", "--checkpoint", str(checkpoint), "--out", str(results), "--people", str(people)])
    data = _read_results(results)
    stored.parent.mkdir(parents=True, exist_ok=True)
    stored.write_text(json.dumps(data, indent=2) + "\n")
    return data


def table(rows: list[tuple[str, str, dict]]) -> str:
    """Markdown table: one line per (row, description, results.json)."""
    head = "| row | what | steps | wall time | " + " | ".join(HEADINGS[k] for k in METRIC_KEYS) + " |"
    rule = "|" + "---|" * (4 + len(METRIC_KEYS))
    lines = [head, rule]
    for name, what, r in rows:
        m = r["metrics"]
        cfg = r.get("config", {})
        steps = f"{cfg.get('stage1_steps', '?')} + {cfg.get('stage2_steps', '?')}"
        wall = r.get("training_elapsed_s")
        wall_text = f"{wall / 60:.0f} min" if isinstance(wall, (int, float)) else "?"
        lines.append(f"| {name} | {what} | {steps} | {wall_text} | " + " | ".join(_fmt(k, m[k]) for k in METRIC_KEYS) + " |")
    return "\n".join(lines)


def _fmt(key: str, value: float) -> str:
    if key == "landmark_nme":
        return f"{100 * value:.2f} %"
    if key in ("vertex_error_mm",):
        return f"{value:.3f}"
    return f"{value:.4f}"


BEGIN, END = "<!-- ablation table: written by `python -m likeness_train.ablation` -->", "<!-- end of ablation table -->"


def splice(document: str, text: str) -> str:
    """Puts the table between the markers of an existing document (the discussion around it
    is kept) or makes a new document of it."""
    block = f"{BEGIN}\n{text}\n{END}"
    if BEGIN in document and END in document:
        before, rest = document.split(BEGIN, 1)
        return before + block + rest.split(END, 1)[1]
    return f"# Ablation\n\n{block}\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=Path("runs/ablation"))
    parser.add_argument("--out", type=Path, default=Path("results/ablation.md"))
    parser.add_argument("--rows", default=",".join(ROWS), help="comma-separated subset of " + ",".join(ROWS))
    parser.add_argument("--stage1-steps", type=int, default=800)
    parser.add_argument("--stage2-steps", type=int, default=200)
    parser.add_argument("--landmark-warmup-steps", type=int, default=TrainConfig().landmark_warmup_steps)
    parser.add_argument(
        "--stage1-track-frozen-steps", type=int, default=TrainConfig().stage1_track_frozen_steps,
        help="stage-1 steps with TrackNet frozen (scale it with --stage1-steps)",
    )
    parser.add_argument("--warmup-from", type=Path, default=None, help="the full run's warm-up (RUN/warmup.pt): the rows start at stage 1 from it")
    parser.add_argument("--data", type=str, default=None, help="cache directory (see dataset.py)")
    parser.add_argument("--people", type=int, default=40, help="held-out people to evaluate on")
    parser.add_argument("--full", type=Path, default=None, help="results.json of the full training run, added as the last row")
    args = parser.parse_args(argv)
    rows = [r for r in args.rows.split(",") if r]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        raise SystemExit(f"unknown ablation row(s) {unknown}; known: {list(ROWS)}")
    for name in ("landmark_warmup_steps", "stage1_track_frozen_steps"):
        if getattr(args, name) < 0:
            raise SystemExit(f"--{name.replace('_', '-')} {getattr(args, name)}: must be >= 0")
    common = ["--stage1-steps", str(args.stage1_steps), "--stage2-steps", str(args.stage2_steps), "--landmark-warmup-steps", str(args.landmark_warmup_steps),
              "--stage1-track-frozen-steps", str(args.stage1_track_frozen_steps)]
    if args.data:
        common += ["--data", args.data]
    t0 = time.time()
    collected = []
    for row in rows:
        stored = args.out.parent / "ablation" / f"{row}.json"
        results = train_and_evaluate(
            row, args.runs, common, args.people, stored, args.stage1_steps, args.stage2_steps, args.warmup_from, args.landmark_warmup_steps,
            args.stage1_track_frozen_steps,
        )
        collected.append((row, ROWS[row][0], results))
    if args.full is not None:
        results = _read_results(args.full)
        collected.append(("full", "final, the full training (the shipped models)", results))
    baseline = collected[-1][2]["baseline"]["metrics"] if collected else None
    text = table(collected)
    if baseline is not None:
        text += "\n\nTemplate baseline (the last row's TrackNet with every ModelNet correction zeroed): " + ", ".join(
            f"{HEADINGS[k].split(' ↓')[0]} {_fmt(k, baseline[k])}" for k in METRIC_KEYS
        )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(splice(args.out.read_text() if args.out.exists() else "", text))
    tmp.replace(args.out)
    print(text)
    print(f"wrote {args.out} ({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
