"""Evaluation on held-out synthetic people (issue 3, item 6).

`python -m likeness_train.evaluate --checkpoint runs/full/checkpoint.pt --out results.json
[--people 40 --frames 4 --seed 1000]` renders people 0..P-1 of `--seed` (1000 by default, a
seed no training uses; the checkpoint's own training seed is refused), runs TrackNet and
ModelNet on each person's N frames and compares with the known truth (metrics.py):

- `vertex_error_mm`: equation (2) with the predicted w, dS_0, dS_i vs the true model-space
  face-region vertices (mean offset removed);
- `landmark_nme`: the predicted 68 landmarks projected with the predicted pose (and the
  known camera) vs the true 2D landmarks, over the outer inter-ocular distance (and
  `landmark_nme_box`, over sqrt(w h) of the true landmarks' box);
- `photometric_error`: the rendered prediction vs the input image on the mask M_n;
- `expression_mae` (and `per_channel_mae` per ICT blendshape name): |w - w_true|; beside it
  `per_channel` (predicted and true mean, correlation per channel) and `pose_mae_deg`;
  `expressions` (metrics.expression_report): MAE over all 53 and the visible channels beside
  w = 0 and w = each channel's mean on the same frames, per-channel MAE, correlation and
  activation F1 (w > 0.3);
- `personalization_recovery`: the predicted corrected blendshapes (S_i - S_0) + F(A_i dS_i)
  vs the person's true ones, relative to the template's error (1 = template, 0 = exact);
- `albedo_error`: equation (3) at 512 with the predicted w, dR_0, dR_i and the trained
  R_0^t vs the true albedo, over the face layer's covered texels.

Metrics are averaged over people (each person has the same number of frames, vertices and
texels, so per-image means are unchanged; ratios are per-person ratios averaged).
The `baseline` row uses the same TrackNet with ModelNet's corrections zeroed (the template
with the trained R_0^t): what personalization brings. The output is deterministic.
`--model-net-from DIR` takes ModelNet and R_0^t from an exported models directory (what
ships when a warm-up's TrackNet is exported beside an earlier run's ModelNet).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import fields
from pathlib import Path

import torch

from . import metrics as M
from .data import SyntheticData
from .face import FaceModel
from .networks import Corrections, TrainedNetworks, calibration_summary, load_networks
from .train import TrainConfig, ablate, normalise, render_prediction

HELD_OUT_SEED = 1000
METRIC_KEYS = ("expression_mae", "landmark_nme", "vertex_error_mm", "photometric_error", "personalization_recovery", "albedo_error")


def _zero_corrections(c: Corrections) -> Corrections:
    return Corrections(*(torch.zeros_like(t) for t in (c.dS0, c.dS, c.dR0, c.dR)))


def model_net_input(images: torch.Tensor, model_net) -> torch.Tensor:
    """TrackNet's normalised crops [N, 3, S, S] as ModelNet reads them: resized (with
    antialiasing) where ModelNet reads another size (a 160 px TrackNet beside a 128 px
    ModelNet), as the Rust pipeline samples the same crop rectangle at each network's size."""
    size = getattr(model_net, "input_size", None) or images.shape[-1]
    if images.shape[-1] == size:
        return images
    return torch.nn.functional.interpolate(images, size=(size, size), mode="bilinear", align_corners=False, antialias=True)


def evaluate(nets: TrainedNetworks, people: int = 40, frames: int = 4, seed: int = HELD_OUT_SEED, model: FaceModel | None = None, log=None) -> dict:
    cfg_dict = nets.config
    if seed == cfg_dict.get("seed"):
        raise ValueError(f"seed {seed} is the checkpoint's training seed; evaluate on held-out people (default {HELD_OUT_SEED})")
    train_cfg = TrainConfig(**{f.name: cfg_dict[f.name] for f in fields(TrainConfig) if f.name in cfg_dict})
    model = model or FaceModel.load()
    region = model.restricted()
    size = cfg_dict["input_size"]
    data = SyntheticData(model, region, seed=seed, image_size=size, frames=frames)
    corner_uv = model.face_region().corner_uv.float()
    # Texels of the face layer that belong to the face (label > background in T).
    coverage = torch.from_numpy(model.fixture.parsing_map[0] > 0).float()
    mean_albedo = nets.mean_albedo if nets.mean_albedo is not None else region.mean_albedo_face
    template_deltas = region.blendshapes(None)  # [1, 53, Vf, 3]
    sums = {name: dict.fromkeys(METRIC_KEYS + ("landmark_nme_box",), 0.0) for name in ("personalized", "template")}
    w_pred, w_true, euler_pred, euler_true = [], [], [], []
    for k in range(people):
        # One person per batch: person k of the seed whatever `people` is.
        batch = data.batch(k, 1)
        with torch.no_grad():
            x = normalise(batch.images)
            params = nets.track(x)
            c = ablate(nets.model(model_net_input(x, nets.model).unsqueeze(0)), train_cfg)
            true_albedo = region.albedo(batch.weights, batch.dR0.expand(frames, -1, -1, -1), batch.dR.expand(frames, -1, -1, -1, -1))
            true_deltas = region.blendshapes(batch.dS)
            images = batch.images.permute(0, 2, 3, 1)
            for name, corrections in (("personalized", c), ("template", _zero_corrections(c))):
                p = render_prediction(region, corner_uv, batch, params, corrections, mean_albedo, size)
                s = sums[name]
                s["expression_mae"] += float(M.expression_mae(params.w, batch.weights))
                s["landmark_nme"] += float(M.landmark_nme(p.landmarks, batch.landmarks))
                s["landmark_nme_box"] += float(M.landmark_nme_box(p.landmarks, batch.landmarks))
                s["vertex_error_mm"] += float(M.vertex_error_mm(p.shape, batch.vertices))
                s["photometric_error"] += float(M.photometric_error(images, p.out.image, p.out.mask))
                deltas = template_deltas if name == "template" else region.blendshapes(corrections.dS)
                s["personalization_recovery"] += float(M.personalization_recovery(deltas, true_deltas, template_deltas))
                s["albedo_error"] += float(M.albedo_error(p.albedo, true_albedo, coverage))
        w_pred.append(params.w)
        w_true.append(batch.weights)
        euler_pred.append(params.euler)
        euler_true.append(batch.euler)
        if log:
            log(f"person {k + 1}/{people}")
    w_pred_all, w_true_all = torch.cat(w_pred), torch.cat(w_true)
    per_channel = M.per_channel_mae(w_pred_all, w_true_all)
    correlation = M.per_channel_correlation(w_pred_all, w_true_all)
    result = {name: {key: value / people for key, value in s.items()} for name, s in sums.items()}
    visible = M.visible_channels(model, size)
    return {
        "expressions": M.expression_report(w_pred_all, w_true_all, visible, model.expression_names),
        "evaluation": {"seed": seed, "people": people, "frames": frames, "image_size": size},
        "metrics": result["personalized"],
        "per_channel_mae": dict(zip(model.expression_names, (float(v) for v in per_channel))),
        "per_channel": {
            name: {"predicted_mean": float(w_pred_all[:, i].mean()), "true_mean": float(w_true_all[:, i].mean()), "correlation": float(correlation[i])}
            for i, name in enumerate(model.expression_names)
        },
        "median_channel_correlation": float(correlation.median()),
        "pose_mae_deg": M.pose_mae_deg(torch.cat(euler_pred), torch.cat(euler_true)),
        "baseline": {
            "name": "template",
            "what": "same TrackNet, ModelNet corrections dS_0, dS_i, dR_0, dR_i zeroed (template shape, trained R_0^t)",
            "metrics": result["template"],
            # What predicting w = 0 everywhere scores: a TrackNet must beat this to track at all.
            "zero_weights_expression_mae": float(torch.cat(w_true).abs().mean()),
        },
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--people", type=int, default=40)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--seed", type=int, default=HELD_OUT_SEED)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument(
        "--model-net-from", type=Path, default=None, metavar="DIR",
        help="ModelNet and R_0^t from an exported models directory (model_net.onnx, mean_albedo.safetensors) instead of the checkpoint's: a warm-up trains TrackNet alone",
    )
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    torch.set_flush_denormal(True)  # see dataset._worker: ~20x faster synthetic people
    t0 = time.time()
    try:
        nets = load_networks(args.checkpoint, model_net_from=args.model_net_from)
    except (FileNotFoundError, ValueError) as e:
        raise SystemExit(str(e)) from e
    results = evaluate(nets, args.people, args.frames, args.seed, log=lambda m: print(m, flush=True))
    ckpt = nets.checkpoint
    results = {
        "checkpoint": str(args.checkpoint),
        "step": ckpt.get("step"),
        "stage": ckpt.get("stage"),
        "commit": ckpt.get("commit"),
        "training_elapsed_s": ckpt.get("elapsed_s"),
        "config": {k: v for k, v in nets.config.items() if k != "blendshape_names"},
        # What calibrate.py fitted (None: TrackNet's raw w).
        "w_calibration": calibration_summary(ckpt),
        # Where ModelNet and R_0^t came from: the checkpoint, or an exported models directory.
        "model_net_from": str(args.model_net_from) if args.model_net_from else "checkpoint",
        **results,
        "elapsed_s": round(time.time() - t0, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=2) + "\n")
    width = max(len(k) for k in METRIC_KEYS)
    print(f"{'metric':<{width}}  personalized  template")
    for key in METRIC_KEYS:
        print(f"{key:<{width}}  {results['metrics'][key]:12.4f}  {results['baseline']['metrics'][key]:8.4f}")
    print(f"median per-channel correlation of w: {results['median_channel_correlation']:.3f}; pose error (deg): {results['pose_mae_deg']}")
    print(f"expression_mae of w = 0 everywhere: {results['baseline']['zero_weights_expression_mae']:.4f}")
    print(f"landmark NME over the landmark box sqrt(w h): {results['metrics']['landmark_nme_box']:.4f} (template {results['baseline']['metrics']['landmark_nme_box']:.4f})")
    print(M.format_expression_report(results["expressions"]))
    print(f"wrote {args.out} ({results['elapsed_s']} s)")


if __name__ == "__main__":
    main()
