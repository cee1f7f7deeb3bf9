"""What one blendshape weight costs at the truth: `python -m likeness_train.diagnose`.

For a few synthetic people (every value true: pose, light, corrections, the other weights)
it sets one weight to 0, 0.5 and 1 and prints the weighted data terms (photometric,
landmark, parsing) per image, averaged over the people. A shape whose row barely changes is
one the images hardly constrain (training README, "Where it stands").
"""

from __future__ import annotations

import argparse
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", default=",".join(SHAPES))
    args = parser.parse_args(argv)
    torch.set_flush_denormal(True)
    for (shape, v), avg in weight_costs(tuple(args.shapes.split(","))).items():
        print(f"{shape:14s} w={v:.1f} " + " ".join(f"{k}={x:8.3f}" for k, x in avg.items()) + f" sum={sum(avg.values()):8.3f}")


if __name__ == "__main__":
    main()
