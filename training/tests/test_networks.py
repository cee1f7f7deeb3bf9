"""Shapes and structure of ModelNet and TrackNet against the paper's architecture tables."""

import pytest
import torch

from likeness_train.networks import ModelNet, TrackNet, parameter_count


@pytest.mark.parametrize("size", [128, 224])
def test_model_net_maps_have_the_papers_shapes(size):
    net = ModelNet(input_size=size, width=0.25).eval()
    out = net(torch.randn(2, 3, 3, size, size))  # 2 people x 3 images
    assert out.dS0.shape == (2, 3, 128, 128)
    assert out.dS.shape == (2, 53, 3, 128, 128)
    assert out.dR0.shape == (2, 3, 128, 128)
    assert out.dR.shape == (2, 53, 3, 128, 128)


def test_model_net_starts_at_the_template():
    net = ModelNet(width=0.25).eval()
    out = net(torch.randn(1, 4, 3, 128, 128))
    for m in (out.dS0, out.dS, out.dR0, out.dR):
        assert torch.count_nonzero(m) == 0


def test_model_net_averages_features_so_the_order_of_images_does_not_matter():
    torch.manual_seed(0)
    net = ModelNet(width=0.25).eval()
    with torch.no_grad():
        for head in (net.shape_decoder.static_head, net.albedo_decoder.blendshape_head):
            head.weight.normal_(0, 0.1)
    images = torch.randn(1, 4, 3, 128, 128)
    a = net(images)
    b = net(images[:, [2, 0, 3, 1]])
    assert torch.allclose(a.dS0, b.dS0, atol=1e-5)
    assert torch.allclose(a.dR, b.dR, atol=1e-5)
    # A single image works too (N is free at test time).
    single = net(images[0, :1])
    assert single.dS0.shape == (1, 3, 128, 128)


def test_model_net_full_width_matches_the_table_parameter_scale():
    # Table (a)+(b) at full width: ~18.6M parameters (docs/training.md measured 18.6M).
    n = parameter_count(ModelNet(width=1.0))
    assert 17e6 < n < 20e6, n


def test_track_net_outputs_and_priors():
    net = TrackNet(width=0.5).eval()
    p = net(torch.randn(5, 3, 128, 128))
    assert p.w.shape == (5, 53) and p.euler.shape == (5, 3)
    assert p.translation.shape == (5, 3) and p.gamma.shape == (5, 27)
    assert torch.all((p.w >= 0) & (p.w <= 1))
    # Untrained: sparse weights, frontal pose, the prior translation.
    assert p.w.max() < 0.05
    assert torch.allclose(p.translation, torch.tensor([0.0, 0.0, -60.0]).expand(5, 3))
    assert parameter_count(TrackNet(width=1.0).encoder) == pytest.approx(11.18e6, rel=0.02)


def test_track_net_flatten_pool_keeps_the_feature_grid():
    """pool="flatten" feeds the whole final 4x4 grid (at 128 px) to the fully connected
    layers; "avg" is its mean. The same convolution weights give the same grid, so the
    flattened features averaged over the grid are the pooled features."""
    torch.manual_seed(0)
    avg = TrackNet(width=0.25, pool="avg").eval()
    flat = TrackNet(width=0.25, pool="flatten", input_size=128).eval()
    assert flat.encoder.out_features == 16 * avg.encoder.out_features
    flat.encoder.load_state_dict(avg.encoder.state_dict())
    x = torch.randn(2, 3, 128, 128)
    with torch.no_grad():
        grid = flat.encoder(x).view(2, avg.encoder.out_features, 16)
        assert torch.allclose(grid.mean(-1), avg.encoder(x), atol=1e-5)
    p = flat(x)
    assert p.w.shape == (2, 53) and p.euler.shape == (2, 3)
    with pytest.raises(ValueError):
        TrackNet(width=0.25, pool="max")
    with pytest.raises(ValueError):
        TrackNet(width=0.25, pool="flatten", input_size=100)


def test_track_net_output_scales_scale_outputs_and_their_gradients():
    """euler = s_r raw, translation = prior + s_t raw, w = sigmoid(g raw): the same head
    output maps to scaled pose, and the trunk receives the pose gradient times the scale."""
    torch.manual_seed(0)
    x = torch.randn(2, 3, 128, 128)
    base = TrackNet(width=0.25).eval()
    scaled = TrackNet(width=0.25, rotation_scale=0.05, translation_scale=0.5, w_gain=4.0).eval()
    scaled.load_state_dict(base.state_dict())
    with torch.no_grad():
        for net in (base, scaled):
            net.head.weight.normal_(0, 0.01)
        scaled.head.weight.copy_(base.head.weight)
        scaled.head.bias.copy_(base.head.bias)
    a, b = base(x), scaled(x)
    assert torch.allclose(b.euler, 0.05 * a.euler, atol=1e-6)
    assert torch.allclose(b.translation - scaled.translation_prior, 0.05 * (a.translation - base.translation_prior), atol=1e-5)
    raw_w = torch.logit(a.w.double()).float()
    assert torch.allclose(b.w, torch.sigmoid(4.0 * raw_w), atol=1e-5)
    # Untrained w still starts near 0 whatever the gain.
    assert TrackNet(width=0.25, w_gain=4.0).eval()(x).w.max() < 0.05


def test_track_net_w_grad_scale_scales_only_the_trunk_gradient_of_w():
    """Forward values are unchanged; the trunk receives the w outputs' gradient times s and
    the pose outputs' gradient unchanged; the head's own gradient is unchanged."""
    torch.manual_seed(0)
    x = torch.randn(3, 3, 64, 64)
    base = TrackNet(width=0.25).train()
    scaled = TrackNet(width=0.25, w_grad_scale=7.0).train()
    with torch.no_grad():
        base.head.weight.normal_(0, 0.05)
    scaled.load_state_dict(base.state_dict())

    def grads(net, part):
        net.zero_grad()
        p = net(x)
        (p.w.sum() if part == "w" else p.euler.sum()).backward()
        return net.fc[0].weight.grad.clone(), net.head.weight.grad.clone()

    # BatchNorm in train mode: both nets see the same batch, so the forward values agree.
    assert torch.allclose(base(x).w, scaled(x).w, atol=1e-6)
    trunk_b, head_b = grads(base, "w")
    trunk_s, head_s = grads(scaled, "w")
    assert torch.allclose(trunk_s, 7.0 * trunk_b, rtol=1e-4, atol=1e-5 * float(trunk_s.abs().max()))
    assert torch.allclose(head_s, head_b, rtol=1e-4, atol=1e-5 * float(head_b.abs().max()))
    trunk_b, _ = grads(base, "pose")
    trunk_s, _ = grads(scaled, "pose")
    assert torch.allclose(trunk_s, trunk_b, rtol=1e-4, atol=1e-5 * float(trunk_b.abs().max()))
    # Eval mode (and so the ONNX export) has no scaling path at all.
    scaled.eval()
    base.eval()
    assert torch.allclose(base(x).w, scaled(x).w, atol=1e-6)


def test_track_net_with_its_own_w_head_takes_w_from_it_and_nothing_else():
    """--track-w-head own: w = sigmoid(w_head(features)); the shared layers get no gradient
    from w, the trunk does; pose, translation and light are the shared head's as before."""
    torch.manual_seed(0)
    x = torch.randn(3, 3, 64, 64)
    net = TrackNet(width=0.25, w_head="own").train()
    features = net.encoder(x)
    p = net.heads(features)
    assert torch.allclose(p.w, torch.sigmoid(net.w_head(features)), atol=1e-6)
    assert torch.allclose(p.w_logits, net.w_head(features), atol=1e-6)
    assert p.w.max() < 0.05, "untrained w starts near 0"
    assert float(p.w.detach().std()) > 0, "and varies with the image: the trunk gets w's gradient from the first step"
    net.zero_grad()
    net(x).w.sum().backward()
    assert net.fc[0].weight.grad is None or float(net.fc[0].weight.grad.abs().max()) == 0.0
    assert float(net.encoder.stem[0].weight.grad.abs().max()) > 0
    with pytest.raises(ValueError, match="w_head"):
        TrackNet(width=0.25, w_head="separate")
