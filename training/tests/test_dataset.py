"""The pre-rendered cache returns the batches `SyntheticData` renders, resumes, and feeds
the trainer."""

import math

import numpy as np
import pytest
import torch

from likeness_train.data import SyntheticData, concat_batches
from likeness_train.dataset import CacheSpec, CachedData, estimate_bytes, shard_path, write_cache
from likeness_train.train import TrainConfig, Trainer

SPEC = dict(seed=1, batches=3, people_per_batch=1, frames=2, image_size=128, batches_per_shard=2)


@pytest.fixture(scope="module")
def synthetic(face_model, face_region_model):
    return SyntheticData(face_model, face_region_model, seed=1, image_size=128, frames=2)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    directory = tmp_path_factory.mktemp("cache")
    # 3 batches in shards of 2: a full shard and a partial last one.
    assert write_cache(directory, CacheSpec(**SPEC), workers=1) == 2
    return directory


def test_cached_batch_equals_rendered_batch(cache, synthetic):
    data = CachedData(cache, fallback=synthetic, truth=True)
    for index in (0, 2):
        got, want = data.batch(index, 1), synthetic.batch(index, 1)
        assert (got.images - want.images).abs().max() <= 1 / 255 + 1e-6
        assert (got.landmarks - want.landmarks).abs().max() <= 1e-4
        for key in ("weights", "euler", "translation", "gamma", "focal", "principal", "identity_coeffs", "dS", "dR0", "dR"):
            assert torch.allclose(getattr(got, key), getattr(want, key), atol=1e-6), key
        # Recomputed on the face region instead of selected from the full head.
        assert (got.vertices - want.vertices).abs().max() <= 1e-4
        # Parsing: the stored labels are the argmax; coverage is exact and only bilinear
        # label borders (well under 1 % of the pixels) were soft.
        covered = want.parsing.sum(-1) > 0.5
        assert torch.equal(got.parsing.sum(-1) > 0.5, covered)
        assert torch.equal(got.parsing.argmax(-1)[covered], want.parsing.argmax(-1)[covered])
        soft = (got.parsing - want.parsing).abs().amax(-1) > 1e-3
        assert soft.float().mean() < 0.01
    assert (got.index, got.people, got.frames) == (2, 1, 2)


def test_weights_alone_are_the_batches_weights_and_beyond_the_cache_is_an_error(cache, synthetic):
    data = CachedData(cache)
    for index in (0, 1, 2):
        assert torch.equal(data.weights(index), synthetic.batch(index, 1).weights)
    with pytest.raises(IndexError):
        data.weights(3)


def test_cache_resumes_and_falls_back(cache, synthetic, capsys):
    before = shard_path(cache, 0).stat().st_mtime_ns
    shard_path(cache, 1).unlink()
    (cache / ".shard-00001.npz.123.tmp").write_bytes(b"half a shard")  # an interrupted write
    data = CachedData(cache, fallback=synthetic)
    # A missing shard (still rendering, or deleted) is rendered on the fly.
    assert torch.equal(data.batch(2, 1).images, synthetic.batch(2, 1).images)
    assert write_cache(cache, CacheSpec(**SPEC), workers=1) == 1
    assert shard_path(cache, 0).stat().st_mtime_ns == before
    assert data.batch(3, 1).images.shape == (2, 3, 128, 128)  # beyond the cache: rendered
    with pytest.raises(ValueError):
        data.batch(0, 2)  # the cache has 1 person per batch
    with pytest.raises(SystemExit):
        write_cache(cache, CacheSpec(**{**SPEC, "frames": 4}), workers=1)


def test_cache_of_other_synthetic_people_is_refused(cache, synthetic, tmp_path):
    """A cache written before `synthetic_version` existed holds version-1 people: reading
    or growing it with this code would mix two data distributions."""
    import json
    import shutil

    old = tmp_path / "old"
    shutil.copytree(cache, old)
    manifest = json.loads((old / "manifest.json").read_text())
    del manifest["synthetic_version"]
    (old / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="version 1"):
        CachedData(old, fallback=synthetic)
    with pytest.raises(SystemExit):
        write_cache(old, CacheSpec(**SPEC), workers=1)


def test_trainer_reads_the_cache(cache, tmp_path):
    config = TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=0, stage1_steps=1, stage2_steps=0, track_width=0.25, model_width=0.25, data=str(cache))
    trainer = Trainer(config, tmp_path / "run")
    assert isinstance(trainer.data, CachedData)
    values = trainer.train_step()
    assert all(math.isfinite(v) for v in values.values())


def test_disk_estimate():
    est = estimate_bytes(4, 4, 128)
    # 16 images: 3 bytes of colour + 1 byte of parsing label per pixel, ~1 MB per batch.
    assert est["total"] == pytest.approx(1.07e6, rel=0.01)
    assert est["parsing_float16_soft"] / est["parsing_labels"] == 18
    assert np.isclose(est["total"] * 5000 / 1e9, 5.35, rtol=0.01)


def test_warmup_reads_several_batches_per_step_and_wraps_around_the_cache(cache, tmp_path):
    """--warmup-batches-per-step 2 on a 3-batch cache: step 0 reads batches 0, 1; step 1
    reads 2, then 0 again (the next pass); the step's batch is both joined in order."""
    config = TrainConfig(
        people_per_batch=1, frames=2, landmark_warmup_steps=4, stage1_steps=0, stage2_steps=0, track_width=0.25,
        model_width=0.25, data=str(cache), warmup_batches_per_step=2, flip_probability=0.0,
    )
    trainer = Trainer(config, tmp_path / "run")
    assert trainer.warmup_indices() == [0, 1]
    values = trainer.train_step()
    assert all(math.isfinite(v) for v in values.values())
    assert trainer.warmup_indices() == [2, 0]
    joined = trainer.read_batch()
    two, zero = trainer.data.batch(2, 1), trainer.data.batch(0, 1)
    assert (joined.people, joined.frames) == (2, 2)
    assert torch.equal(joined.images, torch.cat([two.images, zero.images]))
    assert torch.equal(joined.weights, torch.cat([two.weights, zero.weights]))
    with pytest.raises(ValueError):
        concat_batches([])


@pytest.fixture(scope="module")
def cache_seed2(tmp_path_factory):
    directory = tmp_path_factory.mktemp("cache2")
    assert write_cache(directory, CacheSpec(**{**SPEC, "seed": 2, "batches": 2}), workers=1) == 1
    return directory


def test_warmup_reads_the_extra_caches_interleaved(cache, cache_seed2, face_model, face_region_model, tmp_path):
    """--extra-data: union batch k is batch k // 2 of cache k % 2, so a 2-batch step reads
    seed 1's batch 0 and seed 2's batch 0; an epoch is 2 x the shorter cache (2 batches)."""
    config = TrainConfig(
        people_per_batch=1, frames=2, landmark_warmup_steps=4, stage1_steps=0, stage2_steps=0, track_width=0.25,
        model_width=0.25, data=str(cache), extra_data=[str(cache_seed2)], warmup_batches_per_step=2, flip_probability=0.0,
    )
    trainer = Trainer(config, tmp_path / "run")
    assert len(trainer.warmup_data) == 4
    assert trainer.warmup_indices() == [0, 1]
    seed2 = SyntheticData(face_model, face_region_model, seed=2, image_size=128, frames=2).batch(0, 1)
    joined = trainer.read_batch()
    assert torch.equal(joined.images[:2], trainer.data.batch(0, 1).images)
    assert (joined.images[2:] - seed2.images).abs().max() <= 1 / 255 + 1e-6
    assert torch.allclose(joined.weights[2:], seed2.weights)
    assert not torch.equal(joined.weights[:2], joined.weights[2:])
    values = trainer.train_step()
    assert all(math.isfinite(v) for v in values.values())
    trainer.step = 2  # the next pass starts again with both caches' first batches
    assert trainer.warmup_indices() == [0, 1]


def test_extra_caches_that_would_repeat_or_leak_people_are_refused(cache, cache_seed2, tmp_path):
    import json
    import shutil

    from likeness_train.dataset import CacheUnion
    from likeness_train.evaluate import HELD_OUT_SEED
    from likeness_train.train import config_from_args

    base = dict(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25, data=str(cache))
    with pytest.raises(ValueError, match="training's own"):
        Trainer(TrainConfig(**base, extra_data=[str(cache)]), tmp_path / "a")
    held = tmp_path / "held"
    shutil.copytree(cache_seed2, held)
    manifest = json.loads((held / "manifest.json").read_text())
    (held / "manifest.json").write_text(json.dumps({**manifest, "seed": HELD_OUT_SEED}))
    with pytest.raises(ValueError, match="held-out evaluation"):
        Trainer(TrainConfig(**base, extra_data=[str(held)]), tmp_path / "b")
    with pytest.raises(ValueError, match="needs data"):
        Trainer(TrainConfig(**{**base, "data": None}, extra_data=[str(cache_seed2)]), tmp_path / "c")
    with pytest.raises(SystemExit):
        config_from_args(["--out", str(tmp_path / "d"), "--extra-data", str(cache_seed2)])
    other = tmp_path / "other"
    write_cache(other, CacheSpec(**{**SPEC, "seed": 3, "batches": 1, "frames": 4}), workers=1)
    with pytest.raises(ValueError, match="cannot be read as one"):
        CacheUnion([CachedData(cache), CachedData(other)])
    with pytest.raises(ValueError, match="same seed"):
        CacheUnion([CachedData(cache), CachedData(cache)])
