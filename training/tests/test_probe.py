"""The go/no-go probe's floor and verdict (likeness_train.probe)."""

import pytest
import torch

from likeness_train.probe import constant_floor, verdict, windows
from likeness_train.train import w_loss
from likeness_train.networks import TrackParams


def _truth():
    g = torch.Generator().manual_seed(0)
    return (torch.rand(400, 53, generator=g) * (torch.rand(400, 53, generator=g) < 0.15)).double()


def _per_image(constant: torch.Tensor, truth: torch.Tensor, kind: str) -> float:
    w = constant.expand_as(truth).clamp(1e-7, 1 - 1e-7)
    params = TrackParams(w, None, None, None, w_logits=torch.logit(w))
    return float(w_loss(params, truth, kind)) / truth.shape[0]


@pytest.mark.parametrize("kind", ["sq", "l1", "bce_l1"])
def test_no_constant_prediction_goes_below_the_floor_and_the_best_reaches_it(kind):
    truth = _truth()
    floor = constant_floor(truth, kind)
    g = torch.Generator().manual_seed(1)
    for _ in range(20):
        assert _per_image(torch.rand(1, 53, generator=g).double(), truth, kind) >= floor - 1e-9
    best = {"sq": truth.mean(0, keepdim=True), "l1": truth.median(0, keepdim=True).values}.get(kind)
    if best is not None:
        assert _per_image(best, truth, kind) == pytest.approx(floor, rel=1e-6)
    else:  # the floor is reached: by a constant found here independently (golden section)
        import math

        best = []
        for t in truth.T:
            a, b = 1e-6, 1 - 1e-6
            f = lambda c: float(-(t * math.log(c) + (1 - t) * math.log(1 - c)).mean() + (c - t).abs().mean())  # noqa: E731
            for _ in range(80):
                m1, m2 = a + 0.382 * (b - a), a + 0.618 * (b - a)
                a, b = (a, m2) if f(m1) < f(m2) else (m1, b)
            best.append(0.5 * (a + b))
        assert _per_image(torch.tensor(best, dtype=torch.float64)[None], truth, kind) == pytest.approx(floor, rel=1e-4)


def test_verdict_needs_the_loss_below_half_the_floor_and_every_visible_channel_rising():
    log = [{"step": s, "sup": 10.0 - 0.009 * s, "grad_sup": 1.0, "grad_lm": 2.0} for s in range(1, 1001)]
    assert windows(log, "sup")[0] == (100, pytest.approx(10.0 - 0.009 * 50.5))
    channels = {"a": {"visible": True, "correlation": 0.5}, "b": {"visible": False, "correlation": 0.0}}
    evaluation = {"expressions": {"per_channel": channels, "median_visible_correlation": 0.5, "mae_all": {}}}
    assert verdict(log, floor=3.0, evaluation=evaluation)["go"]  # last window ~1.5 = 0.5 x floor
    assert not verdict(log, floor=2.5, evaluation=evaluation)["go"]
    channels["a"]["correlation"] = 0.05
    result = verdict(log, floor=3.0, evaluation=evaluation)
    assert not result["go"] and result["visible_channels_not_rising"] == ["a"]
    assert verdict(log, floor=3.0, evaluation=None)["go"] is None
