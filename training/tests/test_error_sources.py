"""error_sources.py: the variants change only what they name, and held-out people are refused."""

import dataclasses

import pytest
import torch

from likeness_train import error_sources
from likeness_train.data import SyntheticData
from likeness_train.face import FaceModel


@pytest.fixture(scope="module")
def model():
    return FaceModel.load()


def test_template_person_variant_draws_the_same_frames_without_the_person(model):
    # The frames (w, pose) must be the same in every variant, or the MAEs would compare
    # different expressions; only the person may change.
    drawn = SyntheticData(model, model.restricted(), seed=7, image_size=64, frames=2)
    template = SyntheticData(model, model.restricted(), seed=7, image_size=64, frames=2)
    template.people.config = dataclasses.replace(template.people.config, **error_sources.VARIANTS["template person"])
    a, b = drawn.batch(0, 1), template.batch(0, 1)
    assert torch.equal(a.weights, b.weights)
    assert torch.equal(a.euler, b.euler)
    person = template.people.person(0)
    assert float(person.identity_coeffs.abs().max()) == 0.0
    assert float(person.dS.abs().max()) == 0.0
    assert float(drawn.people.person(0).identity_coeffs.abs().max()) > 0.0


def test_frontal_variant_keeps_the_head_within_five_degrees(model):
    data = SyntheticData(model, model.restricted(), seed=7, image_size=64, frames=4)
    data.people.config = dataclasses.replace(data.people.config, **error_sources.VARIANTS["frontal (+-5 deg)"])
    euler = data.batch(0, 2).euler
    assert float(euler.abs().max()) <= 5.0 * torch.pi / 180 + 1e-6


def test_held_out_seed_is_refused(tmp_path):
    from likeness_train.evaluate import HELD_OUT_SEED

    with pytest.raises(SystemExit):
        error_sources.main(["--checkpoint", str(tmp_path / "none.pt"), "--out", str(tmp_path / "o.json"), "--seed", str(HELD_OUT_SEED)])


def test_people_the_checkpoint_trained_on_are_refused(tmp_path):
    from likeness_train.train import TrainConfig, Trainer

    trainer = Trainer(TrainConfig(people_per_batch=1, frames=2, landmark_warmup_steps=1, stage1_steps=0, stage2_steps=0, track_width=0.25, model_width=0.25, seed=3), tmp_path / "run")
    trainer.save()
    with pytest.raises(SystemExit):
        error_sources.main(["--checkpoint", str(trainer.checkpoint_path), "--out", str(tmp_path / "o.json"), "--seed", "3"])
    assert not (tmp_path / "o.json").exists()
