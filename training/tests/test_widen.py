"""widen.py: a widened TrackNet computes what the narrow one did, and its copies can part."""

import pytest
import torch

from likeness_train.networks import TrackNet
from likeness_train.widen import channel_map, resize_track_input, split_fractions, widen_track, widths_match


def randomised(net: TrackNet, seed: int) -> TrackNet:
    # A fresh TrackNet has zero heads and unit BatchNorm statistics, which would hide a
    # wrong mapping; every parameter and statistic is drawn at random instead.
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in net.parameters():
            p.copy_(0.2 * torch.randn(p.shape, generator=g))
        for m in net.modules():
            if isinstance(m, torch.nn.BatchNorm2d):
                m.running_mean.copy_(0.1 * torch.randn(m.running_mean.shape, generator=g))
                m.running_var.copy_(0.5 + torch.rand(m.running_var.shape, generator=g))
    return net


@pytest.mark.parametrize("pool, w_head", [("flatten", "own"), ("avg", "shared")])
def test_widened_tracknet_computes_the_narrow_function(pool, w_head):
    narrow = randomised(TrackNet(width=0.25, pool=pool, input_size=64, w_head=w_head, w_hidden=32, hidden=64), 1)
    wide = TrackNet(width=0.375, pool=pool, input_size=64, w_head=w_head, w_hidden=32, hidden=64)
    widen_track(narrow, wide, seed=3)
    images = torch.randn(3, 3, 64, 64, generator=torch.Generator().manual_seed(2))
    for train in (False, True):  # running statistics, then the batch's own
        narrow.train(train)
        wide.train(train)
        with torch.no_grad():
            a, b = narrow(images), wide(images)
        for name in ("w", "euler", "translation", "gamma"):
            assert torch.allclose(getattr(a, name), getattr(b, name), atol=2e-5, rtol=1e-4), name


def test_copies_get_different_shares_that_sum_to_one():
    g = torch.Generator().manual_seed(0)
    mapping = channel_map(8, 13, g)
    assert mapping[:8].tolist() == list(range(8))
    assert set(mapping[8:].tolist()) <= set(range(8)) and len(set(mapping[8:].tolist())) == 5
    shares = split_fractions(mapping, 8, g, jitter=0.2)
    totals = torch.zeros(8).index_add_(0, mapping, shares)
    assert torch.allclose(totals, torch.ones(8), atol=1e-6)
    copied = mapping[8:]
    assert not torch.allclose(shares[copied], shares[8:])  # an even split would keep copies equal forever


def test_narrowing_is_refused():
    with pytest.raises(ValueError, match="cannot widen"):
        channel_map(8, 4, torch.Generator())
    narrow = TrackNet(width=0.375, input_size=64, hidden=64, w_hidden=32)
    wide = TrackNet(width=0.25, input_size=64, hidden=64, w_hidden=32)
    with pytest.raises(ValueError):
        widen_track(narrow, wide)
    assert widths_match(0.5, 0.75) and not widths_match(0.75, 0.5)


@pytest.mark.parametrize("pool, w_head", [("flatten", "own"), ("avg", "shared")])
def test_resized_tracknet_reads_a_uniform_grid_as_the_small_one(pool, w_head):
    # The independent expectation: features equal over the grid (each channel one value)
    # mean the same to both heads, whatever the grid's size; the trunk is copied exactly.
    small = randomised(TrackNet(width=0.25, pool=pool, input_size=64, w_head=w_head, w_hidden=32, hidden=64), 4)
    large = TrackNet(width=0.25, pool=pool, input_size=96, w_head=w_head, w_hidden=32, hidden=64)
    resize_track_input(small, large)
    for key, value in small.state_dict().items():
        if key.startswith("encoder."):
            assert torch.equal(large.state_dict()[key], value), key
    channels = small.encoder.layers[-1].conv2.out_channels
    per_channel = torch.randn(2, channels, 1, 1, generator=torch.Generator().manual_seed(5))
    small_cells = small.encoder.out_features // channels
    large_cells = large.encoder.out_features // channels
    assert (small_cells, large_cells) == ((4, 9) if pool == "flatten" else (1, 1))
    with torch.no_grad():
        a = small.heads(per_channel.expand(-1, -1, small_cells, 1).reshape(2, -1), None)
        b = large.heads(per_channel.expand(-1, -1, large_cells, 1).reshape(2, -1), None)
    for name in ("w", "euler", "translation", "gamma"):
        assert torch.allclose(getattr(a, name), getattr(b, name), atol=1e-5, rtol=1e-4), name


def test_resizing_refuses_other_differences():
    small = TrackNet(width=0.25, input_size=64, hidden=64, w_hidden=32, pool="flatten", w_head="own")
    with pytest.raises(ValueError, match="trunk"):
        resize_track_input(small, TrackNet(width=0.375, input_size=96, hidden=64, w_hidden=32, pool="flatten", w_head="own"))
    with pytest.raises(ValueError, match="pool"):
        resize_track_input(small, TrackNet(width=0.25, input_size=96, hidden=64, w_hidden=32, pool="avg", w_head="own"))
    with pytest.raises(ValueError, match="context"):
        resize_track_input(small, TrackNet(width=0.25, input_size=96, hidden=64, w_hidden=32, pool="flatten", w_head="own", context=True))
