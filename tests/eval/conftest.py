"""Shared fixtures: a small rig and a small synthetic Fisheye3DOD folder."""

from __future__ import annotations

import pytest
from eval_cases import SynthSet

from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.scenes.render import resized_rig, synthesize


@pytest.fixture(scope="session")
def small_rig() -> Rig:
    """The shipped rig at 80x80 pixels: the same geometry, a hundredth of the pixels."""
    return resized_rig(default_rig(), 0.1)


@pytest.fixture(scope="session")
def synth_set(tmp_path_factory: pytest.TempPathFactory, small_rig: Rig) -> SynthSet:
    """Two sequences (3 + 2 frames) in the val split, written once per test session."""
    root = tmp_path_factory.mktemp("synth") / "Fisheye3DOD"
    frames = synthesize(small_rig, root, frames=3, seed=7) + synthesize(small_rig, root, frames=2, seed=8)
    return SynthSet(root, frames, small_rig)
