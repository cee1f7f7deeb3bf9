"""Photometric augmentation of the warm-up's batches (data.photometric_batch): the light
target stays the truth of the augmented image, labels of geometry stay exact, the draw is
reproducible, and strength 0 is the identity."""

import dataclasses

import pytest
import torch

from likeness_train import render as R
from likeness_train.data import Batch, photometric_batch

SIZE = 32


def _batch(images: torch.Tensor, gamma: torch.Tensor) -> Batch:
    n = images.shape[0]
    g = torch.Generator().manual_seed(5)
    return Batch(
        images=images, landmarks=torch.rand(n, 68, 2, generator=g) * SIZE, parsing=torch.rand(n, SIZE, SIZE, 9, generator=g),
        weights=torch.rand(n, 53, generator=g), euler=torch.randn(n, 3, generator=g) * 0.2,
        translation=torch.randn(n, 3, generator=g), gamma=gamma, focal=torch.full((n,), 100.0),
        principal=torch.full((n, 2), SIZE / 2), vertices=None, dS=None, dR0=None, dR=None,
        identity_coeffs=torch.zeros(1, 100), people=1, frames=n,
    )


def _shaded(albedo: torch.Tensor, normals: torch.Tensor, gamma: torch.Tensor) -> torch.Tensor:
    return R.sh_shade(albedo, normals, gamma).permute(0, 3, 1, 2)  # [B, 3, H, W]


def test_the_scaled_light_target_renders_the_augmented_image_up_to_zero_mean_noise_and_blur():
    g = torch.Generator().manual_seed(11)
    n = 64
    normals = torch.nn.functional.normalize(torch.randn(n, SIZE, SIZE, 3, generator=g) + torch.tensor([0.0, 0.0, 2.0]), dim=-1)
    albedo = 0.3 + 0.4 * torch.rand(n, SIZE, SIZE, 3, generator=g)
    gamma = torch.zeros(n, 27)
    gamma[:, [0, 9, 18]] = 0.9  # ambient, plus a little directional light
    gamma += 0.05 * torch.randn(n, 27, generator=g)
    images = _shaded(albedo, normals, gamma).clamp(0, 1)
    assert 0.05 < images.min() and images.max() < 0.95  # no clamping in the reference
    augmented = photometric_batch(_batch(images, gamma), 1.0, torch.Generator().manual_seed(3))
    # The independent expectation: the renderer lit by the augmented light target.
    relit = _shaded(albedo, normals, augmented.gamma).clamp(0, 1)
    residual = (augmented.images - relit).flatten(1)
    # Noise (zero-mean, sd <= 0.03 over 3,072 values: ~0.0005 on the mean) and blur (which
    # keeps the mean) leave each image's mean residual near 0; a wrong gain moves it by
    # ~(gain - 1) x 0.5, ~0.07 at one standard deviation of the gain.
    assert (residual.mean(1).abs() < 0.003).all(), residual.mean(1).abs().max()
    unscaled = (augmented.images - images).flatten(1).mean(1).abs()
    assert (unscaled > 0.02).sum() > n // 2  # the check above could fail
    gains = augmented.gamma[:, [0, 9, 18]] / gamma[:, [0, 9, 18]]
    assert gains.std() > 0.05  # colour gains were drawn


def test_geometry_labels_are_untouched_and_the_draw_is_reproducible():
    g = torch.Generator().manual_seed(2)
    batch = _batch(torch.rand(8, 3, SIZE, SIZE, generator=g), torch.randn(8, 27, generator=g))
    a = photometric_batch(batch, 0.7, torch.Generator().manual_seed(9))
    b = photometric_batch(batch, 0.7, torch.Generator().manual_seed(9))
    c = photometric_batch(batch, 0.7, torch.Generator().manual_seed(10))
    assert torch.equal(a.images, b.images) and torch.equal(a.gamma, b.gamma)
    assert not torch.equal(a.images, c.images)
    assert not torch.equal(a.images, batch.images)
    assert 0.0 <= float(a.images.min()) and float(a.images.max()) <= 1.0
    for name in ("landmarks", "parsing", "weights", "euler", "translation", "focal", "principal"):
        assert getattr(a, name) is getattr(batch, name), name


def test_strength_zero_is_the_identity_and_out_of_range_is_refused():
    batch = _batch(torch.rand(2, 3, SIZE, SIZE), torch.randn(2, 27))
    assert photometric_batch(batch, 0.0, torch.Generator().manual_seed(1)) is batch
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="strength"):
            photometric_batch(batch, bad, torch.Generator().manual_seed(1))


def test_the_training_flag_is_range_checked_by_name(capsys):
    from likeness_train.train import config_from_args

    config, _ = config_from_args(["--out", "x", "--photometric-augment", "0.5"])
    assert config.photometric_augment == 0.5
    assert config_from_args(["--out", "x"])[0].photometric_augment == 0.0
    for bad in ("-0.5", "2", "nan"):
        with pytest.raises(SystemExit):
            config_from_args(["--out", "x", "--photometric-augment", bad])
        assert "--photometric-augment" in capsys.readouterr().err


def test_the_warm_up_trains_on_augmented_images_and_stage_one_on_the_originals(tmp_path):
    from likeness_train.train import TrainConfig, Trainer

    config = TrainConfig(
        people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=1, stage2_steps=0, stage1_track_frozen_steps=0,
        track_width=0.25, model_width=0.25, checkpoint_every_s=1e9, flip_probability=0.0, photometric_augment=1.0,
    )
    trainer = Trainer(config, tmp_path / "run")
    seen = {}
    original_warmup, original_losses = trainer.warmup_step, trainer.losses
    trainer.warmup_step = lambda batch: seen.setdefault("warmup", batch) and original_warmup(batch)
    trainer.losses = lambda batch, *a, **k: seen.setdefault("stage1", batch) and original_losses(batch, *a, **k)
    read = trainer.read_batch()
    trainer.train_step()
    assert not torch.equal(seen["warmup"].images, read.images)
    assert torch.equal(seen["warmup"].weights, read.weights)
    trainer.step, trainer.stage = 1, 1
    read = trainer.read_batch()
    trainer.train_step()
    assert torch.equal(seen["stage1"].images, read.images)
