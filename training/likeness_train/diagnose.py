"""Whether the losses can see expressions: `python -m likeness_train.diagnose`.

1. What one blendshape weight costs at the truth: for a few synthetic people (every value
   true: pose, light, corrections, the other weights) it sets one weight to 0, 0.5 and 1
   and prints the weighted data terms (photometric, landmark, parsing) per image, averaged
   over the people. A shape whose row barely changes is one the images hardly constrain.
2. `--overfit B --data DIR`: the warm-up trained on B fixed batches only (`overfit`).
3. `--fit`: w fitted at the truth. Every value is true except w, which starts at 0.05 and
   is fitted with Adam on the weighted data terms plus L_reg; the pooled correlation of the
   fitted w with the truth is the most a tracker could get out of these losses (training
   README, "Where it stands").
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import tempfile

import torch

from .networks import Corrections, TrackParams
from .train import TrainConfig, Trainer, reference_translation

SHAPES = ("eyeSquint_R", "eyeBlink_R", "cheekSquint_L", "jawOpen", "mouthSmile_L")


def weight_costs(shapes=SHAPES, batches=(3, 11, 29), values=(0.0, 0.5, 1.0)) -> dict[tuple[str, float], dict[str, float]]:
    with tempfile.TemporaryDirectory() as tmp:
        t = Trainer(TrainConfig(people_per_batch=1, frames=4), Path(tmp))
    names = t.model.expression_names
    rows: dict[tuple[str, float], list[dict[str, float]]] = {}
    for b in batches:
        batch = t.synthetic.batch(b, 1)
        person = t.synthetic.people.person(b)
        truth = Corrections(person.dS0[None], person.dS[None], person.dR0[None], person.dR[None])
        for shape in shapes:
            i = names.index(shape)
            for v in values:
                w = batch.weights.clone()
                w[:, i] = v
                # The true translation, expressed for TrackNet's reference camera.
                translation = reference_translation(batch.translation, batch.focal, t.cfg.input_size)
                params = TrackParams(w, batch.euler, translation, batch.gamma)
                with torch.no_grad():
                    terms = t.losses(batch, params, truth, with_reg=False)
                rows.setdefault((shape, v), []).append({k: float(t.cfg.weights[k] * x) for k, x in terms.items() if k in ("ph", "lm", "pa")})
    return {key: {k: sum(d[k] for d in lst) / len(lst) for k in lst[0]} for key, lst in rows.items()}


def fit_weights_at_truth(batches=(3, 11), people: int = 2, iterations: int = 150) -> dict[str, float]:
    """Fits w alone (everything else true) on the training losses; returns the pooled
    correlation and MAE of the fitted w against the truth, the MAE of predicting 0 and that
    of the start (w = 0.05)."""
    with tempfile.TemporaryDirectory() as tmp:
        t = Trainer(TrainConfig(people_per_batch=people, frames=4), Path(tmp))
    truths, fitted = [], []
    for b in batches:
        batch = t.synthetic.batch(b, people)
        persons = [t.synthetic.people.person(b * people + p) for p in range(people)]
        truth = Corrections(*(torch.stack([getattr(person, k) for person in persons]) for k in ("dS0", "dS", "dR0", "dR")))
        translation = reference_translation(batch.translation, batch.focal, t.cfg.input_size)
        logits = torch.full_like(batch.weights, -3.0, requires_grad=True)  # sigmoid(-3) ~ 0.05
        optimizer = torch.optim.Adam([logits], lr=0.05)
        for _ in range(iterations):
            params = TrackParams(torch.sigmoid(logits), batch.euler, translation, batch.gamma)
            terms = t.losses(batch, params, truth, with_reg=True)
            total = sum(t.cfg.weights[k] * terms[k] for k in ("ph", "lm", "pa", "reg") if k in terms)
            optimizer.zero_grad()
            total.backward()
            optimizer.step()
        truths.append(batch.weights)
        fitted.append(torch.sigmoid(logits).detach())
    true_w, fitted_w = torch.cat(truths), torch.cat(fitted)
    correlation = torch.corrcoef(torch.stack([true_w.flatten(), fitted_w.flatten()]))[0, 1]
    return {
        "pooled_correlation": float(correlation),
        "mae": float((true_w - fitted_w).abs().mean()),
        "zero_mae": float(true_w.abs().mean()),
        "start_mae": float((true_w - 0.05).abs().mean()),
    }


def overfit(data: str, batches: int, steps: int, every: int = 50) -> dict:
    """Whether TrackNet can fit w at all: the warm-up (the training defaults) cycling over
    the first `batches` batches of the cache `data`; returns the w term's constant floor on
    those frames and its mean over each `every` steps. Far below the floor: the labels and
    the network are sound, and what a probe lacks is generalisation."""
    from .probe import constant_floor

    with tempfile.TemporaryDirectory() as tmp:
        t = Trainer(TrainConfig(data=data, landmark_warmup_steps=10**9, threads=1), Path(tmp))
        t.data_index = lambda: t.step % batches
        truth = torch.cat([t.data.batch(k, t.cfg.people_per_batch).weights for k in range(batches)])
        values = [t.train_step()["sup"] for _ in range(steps)]
    curve = [sum(values[k : k + every]) / len(values[k : k + every]) for k in range(0, steps, every)]
    return {"floor": constant_floor(truth, t.cfg.w_loss), "sup_every": every, "sup": curve}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", default=",".join(SHAPES))
    parser.add_argument("--fit", action="store_true", help="also fit w at the truth (~2 min)")
    parser.add_argument("--overfit", type=int, default=0, metavar="BATCHES", help="only: train the warm-up on the first BATCHES batches of --data and print the w term against its floor")
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--data", type=str, default=None)
    args = parser.parse_args(argv)
    torch.set_flush_denormal(True)
    if args.overfit:
        if args.data is None or args.overfit < 1 or args.steps < 1:
            parser.error("--overfit BATCHES needs --data DIR, BATCHES >= 1 and --steps >= 1")
        print(json.dumps(overfit(args.data, args.overfit, args.steps)))
        return
    if args.fit:
        print("w fitted at the truth:", json.dumps(fit_weights_at_truth()))
    for (shape, v), avg in weight_costs(tuple(args.shapes.split(","))).items():
        print(f"{shape:14s} w={v:.1f} " + " ".join(f"{k}={x:8.3f}" for k, x in avg.items()) + f" sum={sum(avg.values()):8.3f}")


if __name__ == "__main__":
    main()
