"""Shared fixtures: the real calibration files and the official geometry tables."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fisheye_infer.camera import OCamModel
from fisheye_infer.rig import Rig, default_rig

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def official() -> dict[str, np.ndarray]:
    """Tables the official constructors compute for the shipped rig (see tests/data)."""
    with np.load(DATA / "official_geometry.npz") as npz:
        return {k: npz[k] for k in npz.files}


@pytest.fixture(scope="session")
def rig() -> Rig:
    return default_rig()


@pytest.fixture(scope="session")
def ocam800(rig: Rig) -> OCamModel:
    return rig.shared_model()


@pytest.fixture(scope="session")
def ocam1600() -> OCamModel:
    return OCamModel.from_file(DATA / "ocam_sample_1600.txt", fov=360)
