"""Shared pytest fixtures: the template + Rust fixture are loaded once per session (~1 s)."""

import pytest

from likeness_train.face import FaceModel, FixtureError


@pytest.fixture(scope="session")
def face_model() -> FaceModel:
    try:
        return FaceModel.load()
    except (FileNotFoundError, FixtureError) as e:
        # A missing template/fixture is a setup problem, not a code bug: say how to fix it.
        pytest.fail(f"{e}\n(run training/setup.sh)", pytrace=False)


@pytest.fixture(scope="session")
def face_region_model(face_model):
    return face_model.restricted()
