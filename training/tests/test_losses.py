"""Each loss is zero at the ground truth, grows away from it, and has the gradient finite
differences give."""

import math

import pytest
import torch

from likeness_train import losses as L

torch.manual_seed(0)


def _images(b=2, h=12, w=10):
    return torch.rand(b, h, w, 3, dtype=torch.float64)


def _mask(b=2, h=12, w=10):
    m = torch.zeros(b, h, w, dtype=torch.float64)
    m[:, 2:10, 1:8] = 1
    return m


def _grows(fn, truth, direction):
    values = [fn(truth + s * direction).item() for s in (0.0, 0.1, 0.3, 1.0)]
    assert values[0] == pytest.approx(0.0, abs=1e-5), values
    assert values[1] < values[2] < values[3], values


def test_photometric_and_gradient_losses():
    img, mask = _images(), _mask()
    noise = torch.randn_like(img)
    _grows(lambda r: L.photometric_loss(img, r, mask), img, noise)
    _grows(lambda r: L.gradient_loss(img, r, mask), img, noise)
    # Outside the mask nothing counts.
    outside = img.clone()
    outside[:, 0] += 5
    assert L.photometric_loss(img, outside, mask).item() == pytest.approx(0.0, abs=1e-5)
    # l2,1: a constant colour error e on every masked pixel gives |e| per image.
    shifted = img + torch.tensor([0.3, 0.4, 0.0], dtype=torch.float64)
    assert L.photometric_loss(img, shifted, mask).item() == pytest.approx(2 * 0.5, rel=1e-6)
    # A constant shift has no image gradient.
    assert L.gradient_loss(img, shifted, mask).item() == pytest.approx(0.0, abs=1e-4)


def test_landmark_and_parsing_losses():
    lm = torch.rand(3, 68, 2, dtype=torch.float64) * 100
    _grows(lambda p: L.landmark_loss(lm, p), lm, torch.randn_like(lm))
    assert L.landmark_loss(lm, lm + torch.tensor([3.0, 4.0], dtype=torch.float64)).item() == pytest.approx(3 * 25.0)
    pa = torch.softmax(torch.randn(2, 8, 8, 9, dtype=torch.float64), -1)
    _grows(lambda p: L.parsing_loss(pa, p), pa, torch.randn_like(pa))


def _grid_mesh(n=5):
    ys, xs = torch.meshgrid(torch.arange(n), torch.arange(n), indexing="ij")
    verts = torch.stack([xs.flatten(), ys.flatten(), torch.zeros(n * n, dtype=torch.long)], -1).double()
    tris = []
    for y in range(n - 1):
        for x in range(n - 1):
            a, b, c, d = y * n + x, y * n + x + 1, (y + 1) * n + x, (y + 1) * n + x + 1
            tris += [[a, b, d], [a, d, c]]
    return verts, torch.tensor(tris)


def test_smoothness_loss():
    verts, tris = _grid_mesh()
    edges = L.unique_edges(tris)
    # Grid 5x5: 40 axis edges + 16 diagonals.
    assert edges.shape == (56, 2)
    constant = torch.full((1, verts.shape[0], 3), 0.7, dtype=torch.float64)
    assert L.smoothness_loss(constant, edges).item() == 0.0
    _grows(lambda x: L.smoothness_loss(x, edges), constant, torch.randn_like(constant))
    # One unit bump at an interior vertex of valence 6: 6 edges, each counted twice.
    bump = torch.zeros_like(constant)
    bump[0, 12, 2] = 1.0
    assert L.smoothness_loss(bump, edges).item() == pytest.approx(12.0)


def test_deformation_gradient_and_blendshape_gradient_loss():
    verts, tris = _grid_mesh()
    verts = verts + 0.1 * torch.randn_like(verts)  # non-planar, generic
    op = L.GradientOperator.for_rest(verts, tris)
    angle = 0.6
    rot = torch.tensor([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1.0]], dtype=torch.float64)
    g = op(verts @ rot.T + 3.0)
    assert torch.allclose(g, rot.expand_as(g), atol=1e-9)
    shapes = torch.stack([verts + 0.2 * torch.randn_like(verts) for _ in range(3)])
    _grows(lambda s: L.blendshape_gradient_loss(op, shapes, s), shapes, torch.randn_like(shapes))
    # A pure translation of a corrected shape keeps its gradients: the loss ignores it.
    assert L.blendshape_gradient_loss(op, shapes, shapes + 1.5).item() == pytest.approx(0.0, abs=1e-9)


def test_regularization_loss():
    w = torch.zeros(4, 53, dtype=torch.float64)
    mono = torch.randn(4, 1, 9, dtype=torch.float64).expand(4, 3, 9).reshape(4, 27)
    # Monochromatic light costs only lambda_gamma * ||gamma||.
    expected = L.LAMBDA_GAMMA * mono.norm(dim=1).sum()
    # (up to the sqrt epsilon, 1e-6 per image)
    assert L.regularization_loss(w, mono).item() == pytest.approx(expected.item(), abs=1e-5)
    assert L.regularization_loss(w, torch.zeros(4, 27, dtype=torch.float64)).item() == pytest.approx(0.0, abs=1e-5)
    w2 = torch.full((4, 53), 0.1, dtype=torch.float64)
    assert L.regularization_loss(w2, torch.zeros(4, 27, dtype=torch.float64)).item() == pytest.approx(4 * 53 * 0.1, abs=1e-4)
    coloured = mono.clone()
    coloured[:, 0] += 1.0
    assert L.regularization_loss(w, coloured) > L.regularization_loss(w, mono)


def test_gradients_match_finite_differences():
    img, mask = _images(1, 6, 5), _mask(1, 6, 5)
    rendered = (img + 0.1 * torch.randn_like(img)).requires_grad_()
    assert torch.autograd.gradcheck(lambda r: L.photometric_loss(img, r, mask), (rendered,))
    assert torch.autograd.gradcheck(lambda r: L.gradient_loss(img, r, mask), (rendered,))
    verts, tris = _grid_mesh(3)
    op = L.GradientOperator.for_rest(verts + 0.05 * torch.randn_like(verts), tris)
    template = torch.stack([verts + 0.1 * torch.randn_like(verts)])
    corrected = (template + 0.05 * torch.randn_like(template)).requires_grad_()
    assert torch.autograd.gradcheck(lambda s: L.blendshape_gradient_loss(op, template, s), (corrected,))
    edges = L.unique_edges(tris)
    x = torch.randn(1, verts.shape[0], 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda v: L.smoothness_loss(v, edges), (x,))
    w = torch.rand(2, 53, dtype=torch.float64, requires_grad=True)
    gamma = torch.randn(2, 27, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a, b: L.regularization_loss(a, b), (w, gamma))
    lm = torch.rand(1, 68, 2, dtype=torch.float64)
    pred = torch.rand(1, 68, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p: L.landmark_loss(lm, p), (pred,))


def test_supported_gradient_loss_equals_the_dense_one():
    verts, tris = _grid_mesh(6)
    verts = verts + 0.1 * torch.randn_like(verts)
    template = torch.stack([verts + 0.2 * torch.randn_like(verts) for _ in range(4)])
    support = torch.rand(4, verts.shape[0]) < 0.3
    delta = 0.1 * torch.randn(2, 4, verts.shape[0], 3, dtype=torch.float64) * support[None, :, :, None]
    corrected = template[None] + delta
    fast = L.SupportedGradientLoss(verts, tris, template, support)
    op = L.GradientOperator.for_rest(verts, tris)
    dense = sum(L.blendshape_gradient_loss(op, template, corrected[p]) for p in range(2))
    assert fast(corrected).item() == pytest.approx(dense.item(), rel=1e-9)
    assert dense.item() > 0


def test_shape_mean_reduction_is_the_mean_over_each_shapes_supported_triangles():
    verts, tris = _grid_mesh(6)
    template = torch.stack([verts + 0.2 * torch.randn_like(verts) for _ in range(3)])
    support = torch.rand(3, verts.shape[0]) < 0.3
    delta = 0.1 * torch.randn(1, 3, verts.shape[0], 3, dtype=torch.float64) * support[None, :, :, None]
    corrected = template[None] + delta
    op = L.GradientOperator.for_rest(verts, tris)
    expected = 0.0
    for i in range(3):
        touched = support[i][op.triangles].any(dim=1)
        per_triangle = (op(corrected[0, i]) - op(template[i])).pow(2).sum((-1, -2))
        expected += float(per_triangle[touched].sum() / touched.sum().clamp_min(1))
    mean = L.SupportedGradientLoss(verts, tris, template, support, reduction="shape_mean")
    assert mean(corrected).item() == pytest.approx(expected, rel=1e-9)
    with pytest.raises(ValueError):
        L.SupportedGradientLoss(verts, tris, template, support, reduction="median")


def test_loss_balance_at_the_truth(tmp_path):
    """With the training's normalisation and weights, the true person must be cheap for the
    regularisers and cheaper in total than a wrong expression: otherwise training prefers
    zero corrections and lets w absorb the person (what the first full run did)."""
    from likeness_train.networks import Corrections, TrackParams
    from likeness_train.train import TrainConfig, Trainer, reference_translation

    torch.set_flush_denormal(True)
    trainer = Trainer(TrainConfig(people_per_batch=1, frames=2), tmp_path)
    weights = trainer.cfg.weights
    batch = trainer.synthetic.batch(3, 1)
    person = trainer.synthetic.people.person(3)
    truth = Corrections(person.dS0[None], person.dS[None], person.dR0[None], person.dR[None])

    def total(w, corrections):
        translation = reference_translation(batch.translation, batch.focal, trainer.cfg.input_size)
        params = TrackParams(w, batch.euler, translation, batch.gamma)
        with torch.no_grad():
            terms = trainer.losses(batch, params, corrections, with_reg=False)
        data = sum(weights[k] * float(terms[k]) for k in ("ph", "lm", "pa"))
        regularisers = sum(weights[k] * float(terms[k]) for k in ("sd", "bg"))
        return data, regularisers

    data_true, reg_true = total(batch.weights, truth)
    jaw = trainer.model.expression_names.index("jawOpen")
    wrong = batch.weights.clone()
    wrong[:, jaw] = (wrong[:, jaw] + 0.5).clamp(max=1.0)
    data_wrong, _ = total(wrong, truth)
    zero = Corrections(*(torch.zeros_like(t) for t in (truth.dS0, truth.dS, truth.dR0, truth.dR)))
    data_zero, reg_zero = total(batch.weights, zero)
    assert reg_zero == 0.0
    # Per image, a jawOpen error of 0.5 must cost more than twice what the person's whole
    # true corrections cost in the regularisers (with the literal sums it cost ~1/2,000 of
    # it; with the training's balance ~5x).
    assert data_wrong - data_true > 2 * reg_true, (data_true, data_wrong, reg_true)
    # The person's own corrections explain the images better than the template, by more
    # than they cost in the regularisers.
    assert data_zero - data_true > reg_true, (data_zero, data_true, reg_true)


def test_mean_reductions_divide_by_their_element_counts():
    verts, tris = _grid_mesh(5)
    edges = L.unique_edges(tris)
    x = torch.randn(2, verts.shape[0], 3, dtype=torch.float64)
    assert L.smoothness_loss(x, edges, "mean").item() == pytest.approx(L.smoothness_loss(x, edges).item() / (2 * edges.shape[0]))
    with pytest.raises(ValueError):
        L.smoothness_loss(x, edges, "median")
    template = torch.stack([verts + 0.2 * torch.randn_like(verts) for _ in range(2)])
    support = torch.rand(2, verts.shape[0]) < 0.5
    corrected = template[None] + 0.1 * torch.randn(1, 2, verts.shape[0], 3, dtype=torch.float64) * support[None, :, :, None]
    total = L.SupportedGradientLoss(verts, tris, template, support)
    mean = L.SupportedGradientLoss(verts, tris, template, support, reduction="mean")
    assert mean(corrected).item() == pytest.approx(total(corrected).item() / total.shape_idx.shape[0], rel=1e-9)


def test_diagnose_weight_costs_grow_away_from_the_truth():
    """`python -m likeness_train.diagnose`: on people whose jawOpen is 0, opening the jaw
    costs every data term more, the full opening more than half of it."""
    from likeness_train.diagnose import weight_costs

    torch.set_flush_denormal(True)
    # Person 2's four frames keep the jaw closed (synthetic version 2 opens it in 40 % of
    # the frames, so most people have an open jaw somewhere).
    costs = weight_costs(("jawOpen",), batches=(2,))
    sums = [sum(costs[("jawOpen", v)].values()) for v in (0.0, 0.5, 1.0)]
    assert sums[0] < sums[1] < sums[2], sums


def test_diagnose_fit_at_truth_recovers_the_weights():
    """`python -m likeness_train.diagnose --fit`: with every other value true, the training
    losses alone bring w from 0.05 towards the truth (the signal a tracker can learn from).
    Not below the MAE of w = 0, since synthetic version 3: the images' eyeballs turn with the
    gaze, the prediction is rendered on the face region without them, and the photometric
    term parks residuals in eye and mouth channels (batch 3: MAE 0.083 against 0.066 for
    w = 0; eyeLookDown_L 0.24 against 0.04). Hence the supervised w term (issue 31)."""
    from likeness_train.diagnose import fit_weights_at_truth

    torch.set_flush_denormal(True)
    result = fit_weights_at_truth(batches=(3,), people=1, iterations=80)
    assert result["pooled_correlation"] > 0.5, result
    assert result["mae"] < result["start_mae"], result


def test_overfit_cycles_over_the_given_batches_and_reports_the_floor(tmp_path):
    """`diagnose --overfit`: the warm-up on a fixed set of batches (here 1, 8 steps)."""
    from likeness_train.dataset import CacheSpec, write_cache
    from likeness_train.diagnose import overfit

    spec = CacheSpec(seed=1, batches=1, people_per_batch=4, frames=4, image_size=128, batches_per_shard=1)
    write_cache(tmp_path / "c", spec, workers=1)
    result = overfit(str(tmp_path / "c"), batches=1, steps=8, every=4)
    assert len(result["sup"]) == 2 and result["floor"] > 0
    assert all(math.isfinite(v) for v in result["sup"])
