"""Where TrackNet's w error comes from: `python -m likeness_train.error_sources --checkpoint
CKPT --out results/probes/NAME.json`.

The same frames (the same people's expressions, poses, lights, backgrounds and cameras)
are rendered once as drawn and then with one nuisance removed at a time: the person's
identity (ICT identity coefficients 0), their personal blendshape corrections (dS_i = 0,
the template's motion), both (the template person), the head pose (within +-5 degrees),
and pose and person together. The checkpoint's TrackNet (calibrated where the checkpoint
is) runs on each, and the w MAE over all 53 channels is printed beside w = 0 on the same
frames. A nuisance whose removal lowers the MAE a lot is one the network cannot see past;
what is left with every nuisance removed is what the pixels of a frontal template face
leave (resolution, capacity, training).

`--flip-calibration DIR --flip-validation DIR` instead measures test-time flip averaging:
TrackNet's raw w on each image and on its mirror image (left and right channels swapped
back, `data.mirror_channels`), averaged, calibrated on DIR (as `calibrate.py` does) and
judged on the validation cache, beside the plain network calibrated the same way.

People of the held-out seeds are refused: nothing that chooses may look at them."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import torch

from .calibrate import fit_calibration, refused_cache, refused_seed
from .data import SyntheticData, mirror_channels
from .dataset import CachedData
from .face import FaceModel
from .networks import CalibratedTrackNet, load_networks
from .train import normalise

_TEMPLATE_PERSON = dict(identity_sigma_head=0.0, identity_sigma_tail=0.0, max_correction_cm=0.0, max_correction_mouth_cm=0.0, motion_scale_sigma=0.0)
_FRONTAL = dict(max_yaw_deg=5.0, max_pitch_deg=5.0, max_roll_deg=5.0)
# Each variant's overrides of `synthetic.SyntheticConfig`.
VARIANTS: dict[str, dict] = {
    "as drawn": {},
    "no identity": dict(identity_sigma_head=0.0, identity_sigma_tail=0.0),
    "no personal corrections": dict(max_correction_cm=0.0, max_correction_mouth_cm=0.0, motion_scale_sigma=0.0),
    "template person": _TEMPLATE_PERSON,
    "frontal (+-5 deg)": _FRONTAL,
    "frontal template person": {**_FRONTAL, **_TEMPLATE_PERSON},
}


def variant_mae(track, input_size: int, model: FaceModel, seed: int, batches: int, overrides: dict, people: int = 4, frames: int = 4) -> dict:
    """TrackNet's w MAE and the w = 0 MAE on `batches` batches of `seed` drawn with `overrides`."""
    data = SyntheticData(model, model.restricted(), seed=seed, image_size=input_size, frames=frames)
    data.people.config = dataclasses.replace(data.people.config, **overrides)
    predicted, truth = [], []
    with torch.no_grad():
        for k in range(batches):
            batch = data.batch(k, people)
            predicted.append(track(normalise(batch.images)).w)
            truth.append(batch.weights)
    p, t = torch.cat(predicted), torch.cat(truth)
    return {"frames": int(p.shape[0]), "mae": float((p - t).abs().mean()), "mae_zero": float(t.abs().mean())}


def flip_averaged(raw_track, cache: CachedData, mirror: list[int]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Raw w, flip-averaged raw w and the truth over every frame of the cache."""
    plain, averaged, truth = [], [], []
    with torch.no_grad():
        for k in range(len(cache)):
            batch = cache.batch(k, cache.spec.people_per_batch)
            x = normalise(batch.images)
            w = raw_track(x).w
            plain.append(w)
            averaged.append(0.5 * (w + raw_track(x.flip(-1)).w[:, mirror]))
            truth.append(batch.weights)
    return torch.cat(plain), torch.cat(averaged), torch.cat(truth)


def flip_probe(nets, calibration_dir: Path, validation_dir: Path) -> dict:
    raw = nets.track.track if isinstance(nets.track, CalibratedTrackNet) else nets.track
    names = nets.config.get("blendshape_names")
    if not names:
        names = FaceModel.load().expression_names
    mirror = mirror_channels(list(names))
    calibration, validation = CachedData(calibration_dir), CachedData(validation_dir)
    for cache in (calibration, validation):
        why = refused_cache(cache, nets.config)
        if why:
            raise ValueError(f"{cache.directory}: {why}")
    if calibration.spec.seed == validation.spec.seed:
        raise ValueError(f"{validation.directory}: the validation people are the calibration's (seed {calibration.spec.seed}), on which the map is in-sample")
    cp, ca, ct = flip_averaged(raw.eval(), calibration, mirror)
    vp, va, vt = flip_averaged(raw.eval(), validation, mirror)
    out = {"calibration": str(calibration_dir), "validation": str(validation_dir), "frames": int(vt.shape[0]), "mae_zero": float(vt.abs().mean())}
    for name, c, v in (("plain", cp, vp), ("flip averaged", ca, va)):
        g = fit_calibration(c, ct)
        with torch.no_grad():
            out[name] = {"mae_raw": float((v - vt).abs().mean()), "mae_calibrated": float((g(v) - vt).abs().mean())}
    return out


def main(argv: list[str] | None = None) -> None:
    from .clips import CLIPS_SEED
    from .evaluate import HELD_OUT_SEED
    from .fixtures import FIXTURE_SEED

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=7, help="the people to render (not a held-out seed)")
    parser.add_argument("--batches", type=int, default=48, help="batches of 4 people x 4 frames per variant")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--flip-calibration", type=Path, default=None, metavar="DIR")
    parser.add_argument("--flip-validation", type=Path, default=None, metavar="DIR")
    args = parser.parse_args(argv)
    if args.seed in (HELD_OUT_SEED, CLIPS_SEED, FIXTURE_SEED):
        parser.error(f"--seed {args.seed} holds held-out people; pick another")
    if not 1 <= args.batches <= 100_000:
        parser.error(f"--batches {args.batches}: must be within [1, 100000]")
    if not 1 <= args.threads <= 256:
        parser.error(f"--threads {args.threads}: must be within [1, 256]")
    if (args.flip_calibration is None) != (args.flip_validation is None):
        parser.error("--flip-calibration and --flip-validation go together")
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)
    try:
        nets = load_networks(args.checkpoint)
    except (FileNotFoundError, ValueError, RuntimeError, KeyError) as e:
        raise SystemExit(f"error: {args.checkpoint}: {e}") from e
    if args.flip_calibration is None:
        # People the checkpoint trained on would flatter every row (held-out ones are refused above).
        why = refused_seed(args.seed, nets.config)
        if why:
            parser.error(f"--seed {args.seed}: {why}")
    t0 = time.time()
    result: dict = {"checkpoint": str(args.checkpoint)}
    if args.flip_calibration is not None:
        try:
            result["flip"] = flip_probe(nets, args.flip_calibration, args.flip_validation)
        except (FileNotFoundError, ValueError) as e:
            raise SystemExit(f"error: {e}") from e
        f = result["flip"]
        print(f"{f['frames']} frames of {args.flip_validation}; w = 0: {f['mae_zero']:.4f}")
        for name in ("plain", "flip averaged"):
            print(f"{name:<14} raw {f[name]['mae_raw']:.4f} calibrated {f[name]['mae_calibrated']:.4f}")
    else:
        model = FaceModel.load()
        result.update(seed=args.seed, variants={})
        print(f"{'frames of seed ' + str(args.seed):<26} {'w MAE':>7} {'w = 0':>7}")
        for name, overrides in VARIANTS.items():
            row = variant_mae(nets.track, nets.config["input_size"], model, args.seed, args.batches, overrides)
            result["variants"][name] = row
            print(f"{name:<26} {row['mae']:>7.4f} {row['mae_zero']:>7.4f}", flush=True)
    result["elapsed_s"] = round(time.time() - t0, 1)
    try:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=2) + "\n")
    except OSError as e:
        print(json.dumps(result, indent=2))  # the measurement is not lost
        raise SystemExit(f"error: cannot write {args.out}: {e}") from e
    print(f"wrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
