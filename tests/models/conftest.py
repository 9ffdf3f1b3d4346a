"""Shared fixtures for the model tests: a reduced FisheyeBEVDet configuration and synthetic checkpoints."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from fisheye_infer.models import BEVDetConfig, load_model, make_checkpoint

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session", autouse=True)
def _threads() -> None:
    torch.set_num_threads(min(2, torch.get_num_threads()))


@pytest.fixture(scope="session")
def small_config(small_bevdet_config: BEVDetConfig) -> BEVDetConfig:
    return small_bevdet_config


@pytest.fixture(scope="session")
def small_checkpoint(small_config: BEVDetConfig) -> dict:
    return make_checkpoint("fisheye-bevdet", seed=1, config=small_config)


@pytest.fixture()
def small_state_dict(small_checkpoint: dict) -> dict[str, torch.Tensor]:
    """A fresh shallow copy that a test may edit."""
    return dict(small_checkpoint["state_dict"])


@pytest.fixture(scope="session")
def small_model(small_config: BEVDetConfig, small_checkpoint: dict):
    model, _ = load_model("fisheye-bevdet", small_checkpoint, config=small_config)
    return model


@pytest.fixture(scope="session")
def full_checkpoint() -> dict:
    return make_checkpoint("fisheye-bevdet", seed=0)


@pytest.fixture(scope="session")
def full_model(full_checkpoint: dict):
    """(model, geometry report) for the official configuration and the default rig."""
    return load_model("fisheye-bevdet", full_checkpoint)
