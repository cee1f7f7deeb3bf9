"""Fits TrackNet's w calibration (`networks.WCalibration`) on people it never trained on.

`python -m likeness_train.calibrate --checkpoint runs/NAME/warmup.pt --data
.cache/calib-s0-128 --out runs/NAME/calibrated.pt` runs the checkpoint's TrackNet (float32,
eval mode, as the export) over every frame of the cache, fits one monotone piecewise-linear
map per channel that minimises the mean |g_i(w_i) - w_i^true| over those frames, prints the
cache's MAE before and after per channel, and writes a copy of the checkpoint with
`w_calibration` added; `evaluate.py` and `export.py` then use the calibrated TrackNet.

Why: the w term trains w towards each channel's conditional mean, the MAE is minimised by
its conditional median, which is 0 wherever a channel is less likely on than off (every
channel here is on in 8-46 % of the frames); WCalibration says more.

`--validate DIR` also prints (and keeps in the checkpoint's `w_calibration`) the calibrated
MAE on a second cache whose people neither the training nor the calibration saw, seed 5
(`.cache/valid-v4-s5-128`): the figure runs are chosen by before anyone looks at the
held-out people, since seed 0's own MAE is in-sample for the map.

The people must be new to TrackNet: the seed of the training's `--data` and `--extra-data`
caches is refused (TrackNet is more accurate on people it has seen, so a map fitted there
shrinks too little), and so are the held-out seeds, which must stay unseen by everything
that is tuned. Seed 0 (`preprocess.CALIBRATION_SEED`) is the one meant for this:
`python -m likeness_train.dataset --out .cache/calib-s0-128 --seed 0 --batches 256
--workers 1` (4,096 frames, ~5 min)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import torch

from .dataset import CachedData, read_spec
from .networks import CALIBRATION_KNOTS, NUM_BLENDSHAPES, CalibratedTrackNet, WCalibration, calibration_summary, load_networks
from .train import normalise


def coefficients_from_slopes(slopes: torch.Tensor) -> torch.Tensor:
    """[53, K] segment slopes s_j >= 0 (slope of g on [t_j, t_j+1]) -> WCalibration's
    coefficients c (c_0 = s_0, c_j = s_j - s_j-1), whose partial sums are the slopes."""
    return torch.cat([slopes[:, :1], slopes[:, 1:] - slopes[:, :-1]], dim=1)


def fit_calibration(predicted: torch.Tensor, truth: torch.Tensor, iterations: int = 1500, lr: float = 0.05) -> WCalibration:
    """The WCalibration minimising the mean absolute error of g(predicted) against truth,
    both [F, 53]: projected Adam on the segment slopes (kept >= 0, so g is monotone), from
    the identity. The L1 objective is convex in the slopes, so where it starts only sets how
    fast it gets there."""
    if predicted.shape != truth.shape or predicted.dim() != 2 or predicted.shape[1] != NUM_BLENDSHAPES:
        raise ValueError(f"predicted and truth must both be [frames, {NUM_BLENDSHAPES}], got {list(predicted.shape)} and {list(truth.shape)}")
    if predicted.shape[0] < 1:
        raise ValueError("no frames to fit a calibration on")
    if not (torch.isfinite(predicted).all() and torch.isfinite(truth).all()):
        raise ValueError("predicted and truth must be finite")
    knots = torch.tensor(CALIBRATION_KNOTS)
    basis = torch.relu(predicted.float().unsqueeze(-1) - knots)  # [F, 53, K]
    slopes = torch.ones(NUM_BLENDSHAPES, len(knots), requires_grad=True)
    optimiser = torch.optim.Adam([slopes], lr=lr)
    for _ in range(iterations):
        g = (basis * coefficients_from_slopes(slopes)).sum(-1).clamp(0.0, 1.0)
        loss = (g - truth).abs().mean()
        optimiser.zero_grad(set_to_none=True)
        loss.backward()
        optimiser.step()
        with torch.no_grad():
            slopes.clamp_(min=0.0)
    return WCalibration(coefficients_from_slopes(slopes.detach()))


def predict_w(track: torch.nn.Module, cache: CachedData, log=None) -> tuple[torch.Tensor, torch.Tensor]:
    """TrackNet's w and the truth [F, 53] over every frame of the cache."""
    predicted, truth = [], []
    people = cache.spec.people_per_batch
    with torch.no_grad():
        for k in range(len(cache)):
            batch = cache.batch(k, people)
            if getattr(track, "context_net", None) is not None:  # each frame with its person's others
                predicted.append(track.forward_people(normalise(batch.images), batch.people, batch.frames).w)
            else:
                predicted.append(track(normalise(batch.images)).w)
            truth.append(batch.weights)
            if log and (k + 1) % 64 == 0:
                log(f"batch {k + 1}/{len(cache)}")
    return torch.cat(predicted), torch.cat(truth)


def trained_seeds(config: dict) -> set[int]:
    """The seeds whose people the checkpoint's TrackNet trained on: its own and its extra
    caches' (read from their manifests where they still exist)."""
    seeds = {config.get("seed")}
    for directory in config.get("extra_data") or []:
        manifest = Path(directory) / "manifest.json"
        if manifest.is_file():
            seeds.add(read_spec(manifest).seed)
    return seeds


def refused_seed(seed: int, config: dict) -> str | None:
    """Why people of `seed` cannot calibrate this checkpoint, or None."""
    from .clips import CLIPS_SEED
    from .evaluate import HELD_OUT_SEED
    from .fixtures import FIXTURE_SEED

    held_out = {HELD_OUT_SEED: "the held-out evaluation's", CLIPS_SEED: "the tracking clips'", FIXTURE_SEED: "the test fixtures'"}
    if seed in held_out:
        return f"seed {seed} holds {held_out[seed]} people, which nothing tuned may see"
    if seed in trained_seeds(config):
        return f"seed {seed} holds people TrackNet trained on; a map fitted on them shrinks too little for new people"
    return None


def refused_cache(cache: CachedData, config: dict) -> str | None:
    """Why this cache's frames cannot calibrate or judge this checkpoint's TrackNet (its
    people, `refused_seed`, or its image size), or None."""
    size = config.get("input_size")
    if cache.spec.image_size != size:
        return f"its images are {cache.spec.image_size} px, this TrackNet reads {size} px"
    return refused_seed(cache.spec.seed, config)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--data", type=Path, required=True, help="a cache of people TrackNet never trained on (seed 0)")
    parser.add_argument("--out", type=Path, required=True, help="the calibrated checkpoint to write")
    parser.add_argument("--iterations", type=int, default=1500)
    parser.add_argument(
        "--validate", type=Path, default=None, metavar="DIR",
        help="also print the calibrated MAE on a second cache of people neither the training nor the calibration saw (how runs are chosen: seed 5)",
    )
    args = parser.parse_args(argv)
    if not 1 <= args.iterations <= 1_000_000:
        parser.error(f"--iterations {args.iterations}: must be within [1, 1000000]")
    if args.out.resolve() == args.checkpoint.resolve():
        parser.error("--out is the --checkpoint: write the calibrated copy beside it")
    torch.set_flush_denormal(True)
    try:
        nets = load_networks(args.checkpoint)
        cache = CachedData(args.data)
    except (FileNotFoundError, ValueError, RuntimeError, KeyError) as e:
        raise SystemExit(f"error: {e}") from e
    why = refused_cache(cache, nets.config)
    if why:
        raise SystemExit(f"error: {args.data}: {why}; calibrate on seed 0 (see --help)")
    validation = None
    if args.validate is not None:
        try:
            validation = CachedData(args.validate)
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: --validate: {e}") from e
        why = refused_cache(validation, nets.config)
        if why is None and validation.spec.seed == cache.spec.seed:
            why = "it is the calibration's own seed, on which the map is in-sample"
        if why:
            raise SystemExit(f"error: --validate {args.validate}: {why}")
    track = nets.track.track if isinstance(nets.track, CalibratedTrackNet) else nets.track  # refit from the raw w
    t0 = time.time()
    predicted, truth = predict_w(track.eval(), cache, log=lambda m: print(m, file=sys.stderr, flush=True))
    calibration = fit_calibration(predicted, truth, iterations=args.iterations)
    with torch.no_grad():
        calibrated = calibration(predicted)
    before, after = (predicted - truth).abs().mean(0), (calibrated - truth).abs().mean(0)
    zero = truth.abs().mean(0)
    names = nets.config.get("blendshape_names") or [str(i) for i in range(NUM_BLENDSHAPES)]
    print(f"calibration set: {args.data} (seed {cache.spec.seed}), {predicted.shape[0]} frames")
    print(f"{'channel':<18} {'raw MAE':>8} {'calibrated':>10} {'w = 0':>7}")
    for i, name in enumerate(names):
        print(f"{name:<18} {before[i]:>8.4f} {after[i]:>10.4f} {zero[i]:>7.4f}")
    print(f"{'all 53':<18} {before.mean():>8.4f} {after.mean():>10.4f} {zero.mean():>7.4f}")
    validated = None
    if validation is not None:
        v_predicted, v_truth = predict_w(track.eval(), validation)
        with torch.no_grad():
            v_calibrated = calibration(v_predicted)
        validated = {
            "data": str(args.validate),
            "seed": validation.spec.seed,
            "frames": int(v_predicted.shape[0]),
            "mae_raw": float((v_predicted - v_truth).abs().mean()),
            "mae_calibrated": float((v_calibrated - v_truth).abs().mean()),
            "mae_zero": float(v_truth.abs().mean()),
        }
        print(
            f"validation set: {args.validate} (seed {validation.spec.seed}), {validated['frames']} frames: "
            f"raw {validated['mae_raw']:.4f}, calibrated {validated['mae_calibrated']:.4f}, w = 0 {validated['mae_zero']:.4f}"
        )
    state = dict(nets.checkpoint)
    state["w_calibration"] = {
        "coefficients": calibration.coefficients.clone(),
        "knots": list(CALIBRATION_KNOTS),
        "data": str(args.data),
        "seed": cache.spec.seed,
        "frames": int(predicted.shape[0]),
        "mae_raw": float(before.mean()),
        "mae_calibrated": float(after.mean()),
        "mae_zero": float(zero.mean()),
        "validation": validated,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(f".{args.out.name}.tmp")
    torch.save(state, tmp)
    tmp.replace(args.out)
    summary = calibration_summary(state)
    print(f"wrote {args.out} in {time.time() - t0:.0f} s: {json.dumps(summary)}")


if __name__ == "__main__":
    main()
