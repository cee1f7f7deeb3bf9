"""A trained TrackNet widened without changing what it computes (Net2WiderNet, Chen,
Goodfellow and Shlens, "Net2Net", ICLR 2016), so a wider TrackNet can start from a
narrower one's training instead of from scratch.

Each layer's new channels copy an old channel of the same layer; whatever reads a copied
channel (the next convolution, the residual shortcut, the fully connected layers behind
the trunk) splits that channel's old weight among its copies. The split fractions are
random near 1/k and sum to 1: the widened network computes the same function (up to
float rounding) while the copies get different gradients, so training can make them
differ (an even split would keep the copies identical forever).

Owns: the channel maps and the weight rewrite for `networks.TrackNet` with the ResNet-18
trunk. Must not: change anything but the trunk's width (the heads' outputs and the pose
and light priors are copied unchanged); a checkpoint's w calibration is not TrackNet's and
is not carried (a widened run is calibrated again, as every run is)."""

from __future__ import annotations

import torch

from .networks import TrackNet, _ch


def channel_map(old: int, new: int, generator: torch.Generator) -> torch.Tensor:
    """For each of `new` channels, the old channel it copies: the old ones first, then
    random old ones (each old channel at most once more while they last)."""
    if new < old:
        raise ValueError(f"cannot widen {old} channels to {new}")
    extra = new - old
    picks = torch.cat([torch.randperm(old, generator=generator) for _ in range(-(-extra // old))])[:extra] if extra else torch.empty(0, dtype=torch.long)
    return torch.cat([torch.arange(old), picks])


def split_fractions(mapping: torch.Tensor, old: int, generator: torch.Generator, jitter: float) -> torch.Tensor:
    """For each new channel, its share of its old channel's outgoing weight: near
    1/copies, jittered by up to +-`jitter` (relative), the shares of one old channel
    summing to 1."""
    raw = 1.0 + jitter * (2.0 * torch.rand(mapping.shape[0], generator=generator, dtype=torch.float64) - 1.0)
    totals = torch.zeros(old, dtype=torch.float64).index_add_(0, mapping, raw)
    return (raw / totals[mapping]).float()


def widen_track(narrow: TrackNet, wide: TrackNet, seed: int = 0, jitter: float = 0.2) -> None:
    """Writes into `wide` (same architecture, wider trunk) the function of `narrow`.

    Raises ValueError where the two differ in anything but the trunk's width."""
    if not 0.0 <= jitter < 1.0:
        raise ValueError(f"jitter must be within [0, 1), got {jitter}")
    ne, we = narrow.encoder, wide.encoder
    if type(ne.pool) is not type(we.pool):
        raise ValueError("the two TrackNets pool the trunk differently")
    if len(ne.layers) != len(we.layers):
        raise ValueError("the two trunks have different depths")
    if (narrow.w_head is None) != (wide.w_head is None) or narrow.fc[0].out_features != wide.fc[0].out_features:
        raise ValueError("the two TrackNets' heads differ")
    if narrow.w_head is not None and narrow.w_head[0].out_features != wide.w_head[0].out_features:
        raise ValueError("the two TrackNets' w heads differ")
    generator = torch.Generator().manual_seed(seed)
    # One map per channel count of the residual stream: the stream's tensors (block outputs,
    # shortcuts) must agree on which channel is which.
    maps: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def mapping_for(old: int, new: int) -> tuple[torch.Tensor, torch.Tensor]:
        if old not in maps:
            m = channel_map(old, new, generator)
            maps[old] = (m, split_fractions(m, old, generator, jitter))
        elif maps[old][0].shape[0] != new:
            raise ValueError(f"{old} channels widen to both {maps[old][0].shape[0]} and {new}")
        return maps[old]

    identity3 = (torch.arange(3), torch.ones(3))

    def conv(src: torch.nn.Conv2d, dst: torch.nn.Conv2d, out_map, in_map) -> None:
        w = src.weight.detach()[out_map[0]][:, in_map[0]] * in_map[1][None, :, None, None]
        if w.shape != dst.weight.shape:
            raise ValueError(f"convolution {list(src.weight.shape)} cannot become {list(dst.weight.shape)}")
        dst.weight.data.copy_(w)

    def bn(src: torch.nn.BatchNorm2d, dst: torch.nn.BatchNorm2d, out_map) -> None:
        for name in ("weight", "bias", "running_mean", "running_var"):
            getattr(dst, name).data.copy_(getattr(src, name).detach()[out_map[0]])
        dst.num_batches_tracked.data.copy_(src.num_batches_tracked)

    c_old = ne.stem[0].out_channels
    current = mapping_for(c_old, we.stem[0].out_channels)
    conv(ne.stem[0], we.stem[0], current, identity3)
    bn(ne.stem[1], we.stem[1], current)
    for nb, wb in zip(ne.layers, we.layers):
        out = mapping_for(nb.conv1.out_channels, wb.conv1.out_channels)
        conv(nb.conv1, wb.conv1, out, current)
        bn(nb.bn1, wb.bn1, out)
        conv(nb.conv2, wb.conv2, out, out)
        bn(nb.bn2, wb.bn2, out)
        if (nb.down is None) != (wb.down is None):
            raise ValueError("the two trunks' shortcuts differ")
        if nb.down is not None:
            conv(nb.down[0], wb.down[0], out, current)
            bn(nb.down[1], wb.down[1], out)
        current = out

    # The trunk's features: channel-major (channel, cell) for a flattened grid, the channel
    # alone for the global average.
    cells = ne.out_features // nb.conv2.out_channels
    if we.out_features != current[0].shape[0] * cells:
        raise ValueError("the two trunks' feature sizes do not match their widths")
    index = (current[0][:, None] * cells + torch.arange(cells)[None, :]).reshape(-1)
    share = current[1][:, None].expand(-1, cells).reshape(-1)

    def linear_in(src: torch.nn.Linear, dst: torch.nn.Linear) -> None:
        dst.weight.data.copy_(src.weight.detach()[:, index] * share[None, :])
        dst.bias.data.copy_(src.bias.detach())

    copy_heads(narrow, wide, linear_in)


def copy_heads(src: TrackNet, dst: TrackNet, linear_in) -> None:
    """The layers behind the trunk from `src` to `dst`: `linear_in` maps the weights of those
    that read the trunk's features, the rest (and the pose and light priors) are copied."""
    linear_in(src.fc[0], dst.fc[0])
    dst.head.load_state_dict(src.head.state_dict())
    if src.w_head is not None:
        linear_in(src.w_head[0], dst.w_head[0])
        dst.w_head[2].load_state_dict(src.w_head[2].state_dict())
    for name in ("translation_prior", "gamma_prior"):
        getattr(dst, name).data.copy_(getattr(src, name))


def widths_match(narrow_width: float, wide_width: float) -> bool:
    """Whether every layer of `wide_width` has at least the channels of `narrow_width`."""
    return all(_ch(c, wide_width) >= _ch(c, narrow_width) for c in (64, 128, 256, 512))


def resize_track_input(small: TrackNet, large: TrackNet) -> None:
    """Writes into `large` (the same TrackNet built for another input size) the weights of
    `small`, so a TrackNet for more pixels starts from one trained on fewer (issue 31).

    The convolutions do not depend on the input size and are copied. With a flattened grid
    (`pool="flatten"`) the layers behind the trunk read one weight per (channel, cell): their
    weights are resampled bilinearly from the old grid to the new and scaled by the ratio of
    the cell counts, so a feature map that is uniform over the grid gives the same output.
    The resized network computes a different function (its trunk sees the face larger); it
    is a start for fine-tuning, not a finished network. Raises ValueError where the two
    differ in anything but the input size."""
    se, le = small.encoder, large.encoder
    if type(se.pool) is not type(le.pool):
        raise ValueError("the two TrackNets pool the trunk differently")
    if (small.w_head is None) != (large.w_head is None) or small.context_net is not None or large.context_net is not None:
        raise ValueError("the two TrackNets' heads differ (or hold a context branch, which is not resized)")
    trunk = {k: v for k, v in small.state_dict().items() if k.startswith("encoder.")}
    target = large.state_dict()
    if trunk.keys() != {k for k in target if k.startswith("encoder.")}:
        raise ValueError("the two trunks differ")
    for key, value in trunk.items():
        if target[key].shape != value.shape:
            raise ValueError(f"trunk weight {key}: {list(value.shape)} cannot become {list(target[key].shape)}")
    large.load_state_dict(trunk, strict=False)
    channels = se.layers[-1].conv2.out_channels
    old_cells, new_cells = se.out_features // channels, le.out_features // channels
    old_grid, new_grid = round(old_cells**0.5), round(new_cells**0.5)

    def linear_in(src: torch.nn.Linear, dst: torch.nn.Linear) -> None:
        weight = src.weight.detach()
        if old_cells != new_cells:
            grid = weight.view(weight.shape[0], channels, old_grid, old_grid)
            grid = torch.nn.functional.interpolate(grid, size=(new_grid, new_grid), mode="bilinear", align_corners=True)
            weight = grid.reshape(weight.shape[0], -1) * (old_cells / new_cells)
        if weight.shape != dst.weight.shape:
            raise ValueError(f"linear layer {list(src.weight.shape)} cannot become {list(dst.weight.shape)}")
        dst.weight.data.copy_(weight)
        dst.bias.data.copy_(src.bias.detach())

    copy_heads(small, large, linear_in)
