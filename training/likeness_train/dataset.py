"""Pre-rendered training batches (issue 3): rendering one 128 px image on the fly costs
~110 ms, more than a training step spends per image, so the full training reads batches
rendered once into shards.

`python -m likeness_train.dataset --out training/.cache/data-s1-128 --seed 1 --batches 5000
--people-per-batch 4 --frames 4` renders `SyntheticData.batch(k, P)` for k < K into
`shard-00000.npz`, ... (64 batches each; compressed npz). It resumes: complete shards are
skipped, and each shard is written to a temporary file and renamed, so an interruption
never leaves a half shard under the final name. `--workers 2` renders shards in parallel
(one torch thread each: the renderer is mostly single-threaded numba/numpy).

What a shard keeps, per batch (P people x N frames, P*N images of S x S):
- images as uint8: `compose_image` already quantises to 8 bits, so this is exact;
- the parsing image as a uint8 label index (argmax) with 255 where nothing is covered:
  the rendered parsing image is one-hot except on ~0.3 % of the covered pixels (bilinear
  label borders), so the parsing loss keeps its meaning at 1/18 of float16 soft maps;
- landmarks, weights, pose, gamma, focal, principal point, identity coefficients as float32.
The per-person maps dS, dR_0, dR_i (~10 MB per person in float16, ~200 GB for 5000 batches
of 4 people) and the true vertices are not stored: training does not read them, and
evaluation recomputes them from the person index (`SyntheticData.person_truth`).
Disk: ~1.07 MB per 4x4 batch at 128 px before compression (see `estimate_bytes`).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import sys
import time
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .data import Batch, SyntheticData

LAYOUT_VERSION = 1
# What synthetic.SyntheticPeople draws; a cache of another version holds other data.
# Version 3: the eyeballs turn with the eyeLook weights, mouthClose only with jawOpen, the
# principal point at the image centre. Version 4: the face framed 1.5x tighter
# (`SyntheticConfig.face_fill` 0.85 -> 1.3).
SYNTHETIC_VERSION = 4
UNCOVERED = 255  # parsing label of pixels no triangle covers (an all-zero soft vector)
FLOAT_KEYS = ("landmarks", "weights", "euler", "translation", "gamma", "focal", "principal", "identity_coeffs")


@dataclass
class CacheSpec:
    """What a cache directory holds; `manifest.json` records it and a mismatch is refused."""

    seed: int
    batches: int
    people_per_batch: int
    frames: int
    image_size: int
    batches_per_shard: int = 64
    version: int = LAYOUT_VERSION
    # Missing from caches written before it existed, which hold version 1.
    synthetic_version: int = SYNTHETIC_VERSION

    def shards(self) -> int:
        return -(-self.batches // self.batches_per_shard)

    def shard_range(self, shard: int) -> range:
        start = shard * self.batches_per_shard
        return range(start, min(start + self.batches_per_shard, self.batches))


def estimate_bytes(people: int, frames: int, image_size: int, labels: int = 9) -> dict[str, int]:
    """Uncompressed bytes per batch of what a shard stores, with float16 soft parsing maps
    for comparison."""
    n, px = people * frames, image_size * image_size
    floats = n * (68 * 2 + 53 + 3 + 3 + 27 + 1 + 2) * 4 + people * 100 * 4
    return {"images": n * 3 * px, "parsing_labels": n * px, "floats": floats, "total": n * 4 * px + floats, "parsing_float16_soft": n * px * labels * 2}


def shard_path(directory: Path, shard: int) -> Path:
    return directory / f"shard-{shard:05d}.npz"


def encode(batch: Batch) -> dict[str, np.ndarray]:
    """One batch as the arrays a shard stores (without a leading batch axis)."""
    images = np.rint(batch.images.numpy() * 255.0).clip(0, 255).astype(np.uint8)
    parsing = batch.parsing
    labels = parsing.argmax(dim=-1).to(torch.uint8)
    labels[parsing.sum(dim=-1) < 0.5] = UNCOVERED
    out = {"images": images, "parsing": labels.numpy()}
    for key in FLOAT_KEYS:
        out[key] = getattr(batch, key).numpy().astype(np.float32)
    return out


def decode(arrays: dict[str, np.ndarray], labels: int, people: int, frames: int, index: int) -> Batch:
    images = torch.from_numpy(arrays["images"].astype(np.float32) / 255.0)
    lab = torch.from_numpy(arrays["parsing"].astype(np.int64))
    covered = lab != UNCOVERED
    parsing = F.one_hot(lab.where(covered, torch.zeros_like(lab)), labels).float() * covered[..., None]
    floats = {key: torch.from_numpy(np.ascontiguousarray(arrays[key])) for key in FLOAT_KEYS}
    return Batch(images=images, parsing=parsing, vertices=None, dS=None, dR0=None, dR=None, people=people, frames=frames, index=index, **floats)


def read_spec(manifest: Path) -> CacheSpec:
    """A cache's manifest; one written before `synthetic_version` existed holds version 1."""
    return CacheSpec(**{"synthetic_version": 1, **json.loads(manifest.read_text())})


def shard_complete(path: Path, spec: CacheSpec, shard: int) -> bool:
    """A shard exists under its final name only after its rename, but a file copied or
    truncated by hand is still checked: it must open and hold exactly its batch indices."""
    if not path.is_file():
        return False
    try:
        with np.load(path) as z:
            return np.array_equal(z["batch_index"], np.asarray(spec.shard_range(shard)))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return False


def write_shard(data: SyntheticData, spec: CacheSpec, directory: Path, shard: int) -> None:
    indices = list(spec.shard_range(shard))
    per_batch = [encode(data.batch(k, spec.people_per_batch)) for k in indices]
    arrays = {key: np.stack([b[key] for b in per_batch]) for key in per_batch[0]}
    arrays["batch_index"] = np.asarray(indices)
    final = shard_path(directory, shard)
    tmp = final.with_name(f".{final.name}.{os.getpid()}.tmp")
    with open(tmp, "wb") as f:
        np.savez_compressed(f, **arrays)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(final)  # atomic on one file system


def _worker(args: tuple[dict, str, list[int]]) -> int:
    spec_dict, directory, shards = args
    # One thread per worker: the two workers are what use the two cores.
    torch.set_num_threads(1)
    # Synthetic people's Gaussian-bump fields underflow into denormal floats, which made
    # drawing a person ~30x slower once the renderer had run (21.8 s vs 1.1 s per 4x4
    # batch measured); flushing them to zero changes values below 1e-38 only.
    torch.set_flush_denormal(True)
    from .face import FaceModel

    spec = CacheSpec(**spec_dict)
    model = FaceModel.load()
    data = SyntheticData(model, model.restricted(), seed=spec.seed, image_size=spec.image_size, frames=spec.frames)
    for shard in shards:
        t0 = time.time()
        write_shard(data, spec, Path(directory), shard)
        print(f"shard {shard} ({len(spec.shard_range(shard))} batches) in {time.time() - t0:.1f} s", flush=True)
    return len(shards)


def write_cache(directory: Path, spec: CacheSpec, workers: int = 2) -> int:
    """Renders the missing shards; returns how many were written."""
    directory.mkdir(parents=True, exist_ok=True)
    manifest = directory / "manifest.json"
    if manifest.exists():
        existing = asdict(read_spec(manifest))
        if {k: v for k, v in existing.items() if k != "batches"} != {k: v for k, v in asdict(spec).items() if k != "batches"}:
            raise SystemExit(f"{directory} holds a different cache ({existing}); use another --out")
        # Growing a cache is allowed (more batches, same content for the existing ones),
        # except that its last, partial shard must then be re-rendered.
        if existing["batches"] > spec.batches:
            spec = CacheSpec(**existing)
    # Written first, so a training can already read the finished shards of a cache that is
    # still being rendered (missing shards are rendered on the fly by `CachedData`).
    manifest.write_text(json.dumps(asdict(spec), indent=2) + "\n")
    todo = [s for s in range(spec.shards()) if not shard_complete(shard_path(directory, s), spec, s)]
    if todo:
        # Interleaved so both workers finish at about the same time.
        chunks = [todo[i::workers] for i in range(workers)]
        chunks = [c for c in chunks if c]
        if len(chunks) == 1:
            _worker((asdict(spec), str(directory), chunks[0]))
        else:
            # One thread per worker for every thread pool (OpenMP, numba) the children
            # start: two workers whose idle pool threads spin-wait took 7.6 s per batch
            # instead of 1.5 s (measured, 2 cores).
            for var in ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "MKL_NUM_THREADS"):
                os.environ.setdefault(var, "1")
            with mp.get_context("spawn").Pool(len(chunks)) as pool:
                pool.map(_worker, [(asdict(spec), str(directory), c) for c in chunks])
    return len(todo)


class CachedData:
    """`SyntheticData`'s `batch(index, people)` read from a cache directory.

    Batches beyond the cache are rendered on the fly by `fallback` (same content, so a
    training is the same with or without the cache). `truth=True` adds the person-level
    ground truth (vertices, dS, dR_0, dR_i) recomputed by `fallback` (for evaluation)."""

    def __init__(self, directory: Path, fallback: SyntheticData | None = None, truth: bool = False):
        self.directory = Path(directory)
        manifest = self.directory / "manifest.json"
        if not manifest.is_file():
            raise FileNotFoundError(f"{manifest} not found; write the cache with `python -m likeness_train.dataset --out {self.directory} ...`")
        self.spec = read_spec(manifest)
        if self.spec.version != LAYOUT_VERSION:
            raise ValueError(f"{self.directory} has cache layout {self.spec.version}, this code reads {LAYOUT_VERSION}; re-render it")
        if self.spec.synthetic_version != SYNTHETIC_VERSION:
            raise ValueError(
                f"{self.directory} holds synthetic people of version {self.spec.synthetic_version}, this code draws version {SYNTHETIC_VERSION}; render a new cache"
            )
        self.fallback = fallback
        self.truth = truth
        if fallback is not None:
            mine = (fallback.seed, fallback.image_size, fallback.frames)
            theirs = (self.spec.seed, self.spec.image_size, self.spec.frames)
            if mine != theirs:
                raise ValueError(f"cache {self.directory} has (seed, image size, frames) {theirs}, the training uses {mine}")
        self.labels = fallback.labels if fallback is not None else 9
        self._shard: tuple[int, dict[str, np.ndarray]] | None = None
        self._warned = False

    def __len__(self) -> int:
        return self.spec.batches

    def _arrays(self, shard: int) -> dict[str, np.ndarray]:
        # Training reads batches in order: keeping the last shard decoded means one
        # decompression per 64 steps.
        if self._shard is None or self._shard[0] != shard:
            path = shard_path(self.directory, shard)
            with np.load(path) as z:
                self._shard = (shard, {key: z[key] for key in z.files})
        return self._shard[1]

    def weights(self, index: int) -> torch.Tensor:
        """Batch `index`'s true w [people x frames, 53] without decoding its images: a
        `batch(...)`'s tensors are views that keep its decoded arrays alive (~8 MB a batch),
        so reading 4,000 batches' w through `batch` fills the machine's memory."""
        shard, offset = divmod(index, self.spec.batches_per_shard)
        if index >= self.spec.batches or not shard_path(self.directory, shard).is_file():
            raise IndexError(f"batch {index} is not in the cache {self.directory} ({self.spec.batches} batches)")
        return torch.from_numpy(np.array(self._arrays(shard)["weights"][offset], dtype=np.float32))

    def batch(self, index: int, people: int) -> Batch:
        if people != self.spec.people_per_batch:
            raise ValueError(f"cache {self.directory} has {self.spec.people_per_batch} people per batch, asked for {people}")
        shard, offset = divmod(index, self.spec.batches_per_shard)
        if index >= self.spec.batches or not shard_path(self.directory, shard).is_file():
            if self.fallback is None:
                raise IndexError(f"batch {index} is not in the cache {self.directory} ({self.spec.batches} batches) and there is no fallback")
            if not self._warned:
                print(f"batch {index} is not in the cache {self.directory} (beyond it or not rendered yet): rendering on the fly", file=sys.stderr, flush=True)
                self._warned = True
            return self.fallback.batch(index, people)
        arrays = self._arrays(shard)
        batch = decode({key: v[offset] for key, v in arrays.items()}, self.labels, people, self.spec.frames, index)
        if self.truth:
            if self.fallback is None:
                raise ValueError("truth=True needs a fallback SyntheticData to recompute the people")
            for key, value in self.fallback.person_truth(index, people, batch.weights).items():
                setattr(batch, key, value)
        return batch


class CacheUnion:
    """Several caches read as one, for the warm-up's extra people (`--extra-data`): batch k
    is batch k // M of member k % M, so every member is read from the first step on, and an
    epoch is M x the shortest member (a longer member's tail is not read)."""

    def __init__(self, members: list[CachedData]):
        if not members:
            raise ValueError("CacheUnion needs at least one cache")
        shapes = {(m.spec.people_per_batch, m.spec.frames, m.spec.image_size) for m in members}
        if len(shapes) != 1:
            raise ValueError(f"caches of different (people per batch, frames, image size) cannot be read as one: {sorted(shapes)}")
        seeds = [m.spec.seed for m in members]
        if len(set(seeds)) != len(seeds):
            raise ValueError(f"two caches hold the same seed's people ({seeds}): the union would repeat them")
        self.members = members
        self.spec = members[0].spec
        self.length = len(members) * min(len(m) for m in members)

    def __len__(self) -> int:
        return self.length

    def batch(self, index: int, people: int) -> Batch:
        member, local = index % len(self.members), index // len(self.members)
        return self.members[member].batch(local, people)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--batches", type=int, required=True)
    parser.add_argument("--people-per-batch", type=int, default=4)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--image-size", type=int, default=128)
    parser.add_argument("--batches-per-shard", type=int, default=64)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    spec = CacheSpec(args.seed, args.batches, args.people_per_batch, args.frames, args.image_size, args.batches_per_shard)
    est = estimate_bytes(spec.people_per_batch, spec.frames, spec.image_size)
    print(f"{spec.batches} batches, {spec.shards()} shards; ~{est['total'] * spec.batches / 1e9:.2f} GB before compression", flush=True)
    t0 = time.time()
    written = write_cache(args.out, spec, workers=args.workers)
    size = sum(p.stat().st_size for p in args.out.glob("shard-*.npz"))
    print(f"wrote {written} shard(s) in {time.time() - t0:.0f} s; {args.out} holds {size / 1e9:.2f} GB", flush=True)


if __name__ == "__main__":
    main()
