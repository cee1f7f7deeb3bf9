"""How fast one TrackNet training step runs in each arithmetic and memory layout, side by
side in one run (the claim behind TrainConfig.precision).

`python -m likeness_train.bench_step [--batch 64] [--repeats 8] [--threads 1]` prints a
table: seconds per forward + backward + Adam step of TrackNet (the training's default
widths) on a random batch, the median of `repeats` after one untimed step, and each row's
speed relative to float32 in PyTorch's default NCHW layout. bf16 is only fast where the CPU
has bfloat16 instructions (AVX512-BF16 or AMX); elsewhere PyTorch emulates it."""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from .networks import TrackNet
from .train import TrainConfig

VARIANTS = (("fp32", False), ("fp32", True), ("bf16", False), ("bf16", True))


def step_seconds(precision: str, channels_last: bool, batch: int, repeats: int, size: int) -> float:
    cfg = TrainConfig()
    torch.manual_seed(0)
    net = TrackNet(width=cfg.track_width, pool=cfg.track_pool, input_size=size, w_head=cfg.track_w_head, w_hidden=cfg.track_w_hidden)
    images = torch.randn(batch, 3, size, size)
    if channels_last:
        net.to(memory_format=torch.channels_last)
        images = images.contiguous(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(net.parameters(), lr=1e-4)
    times = []
    for i in range(repeats + 1):
        start = time.perf_counter()
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
            p = net(images)
        loss = p.w.float().sum() + p.euler.float().pow(2).sum() + p.translation.float().pow(2).sum() + p.gamma.float().pow(2).sum()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        if i > 0:  # the first step allocates and picks kernels
            times.append(time.perf_counter() - start)
    return statistics.median(times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=8)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--size", type=int, default=TrainConfig().input_size)
    args = parser.parse_args(argv)
    for name, low, high in (("batch", 1, 4096), ("repeats", 1, 10_000), ("threads", 1, 256), ("size", 32, 1024)):
        if not low <= getattr(args, name) <= high:
            parser.error(f"--{name} {getattr(args, name)}: must be within [{low}, {high}]")
    if args.size % 32:
        parser.error(f"--size {args.size}: ResNet-18's input must be a multiple of 32")
    torch.set_num_threads(args.threads)
    print(f"TrackNet training step, batch {args.batch} at {args.size} px, {args.threads} thread(s), median of {args.repeats}")
    print(f"{'precision':<10} {'layout':<14} {'s/step':>8} {'images/s':>9} {'speed-up':>9}")
    base = None
    for precision, channels_last in VARIANTS:
        s = step_seconds(precision, channels_last, args.batch, args.repeats, args.size)
        base = base or s
        layout = "channels_last" if channels_last else "NCHW"
        print(f"{precision:<10} {layout:<14} {s:>8.3f} {args.batch / s:>9.1f} {base / s:>8.2f}x", flush=True)


if __name__ == "__main__":
    main()
