"""Lens-centre jitter: every training step sees its cameras as other units of the same lens design would.

A network trained on one rig's pictures learns where its lens sits in the frame: the compact
FisheyeBEVDet, re-baked exactly for its rig with every lens centre moved by 1 px, loses a third of its
FDS (the Camera rigs guide, "What re-baking does not change"). Two units of one fisheye lens differ
in their calibrated centres by pixels, so a model meant for a fleet has to be trained for that.

With jitter, step ``s`` draws each camera's centre offset (rows, cols) uniformly within
``pixels`` (seeded by the run's seed and the step, so a resumed run draws what the uninterrupted
one would), renders the step's frames through the moved lenses and gives the model those lenses'
tables (``lens_tables``): FisheyeBEVDet its warp taps and the depth targets their masks, FisheyePETR
its warp taps, its key mask and the key embedding of that mask. The geometry stays exact; only the
picture's place in the frame varies. Validation frames keep the rig's own lenses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError

__all__ = ["LensGeometry", "LensJitter", "StepLenses", "centres_moved"]

#: Seed-sequence word that keeps the jitter's draws apart from every other stream of a run.
_JITTER_STREAM = 0x1E75


def centres_moved(rig: Rig, shifts: np.ndarray) -> Rig:
    """``rig`` with camera n's OCam lens centre moved by ``shifts[n]`` = (rows, cols) pixels; all else kept."""
    offsets = np.asarray(shifts, np.float64)
    if offsets.shape != (len(rig), 2):
        raise ConfigError(f"shifts: expected one (rows, cols) offset per camera, ({len(rig)}, 2), got {offsets.shape}")
    cameras = []
    for cam, (rows, cols) in zip(rig.cameras, offsets):
        if not isinstance(cam.model, OCamModel):
            raise ConfigError(f"camera '{cam.name}': a {cam.model.type} model; lens-centre jitter moves OCam centres")
        lens = cam.model.model_copy(
            update={"center_row": cam.model.center_row + rows, "center_col": cam.model.center_col + cols}
        )
        cameras.append(cam.model_copy(update={"model": lens}))
    return rig.model_copy(update={"cameras": tuple(cameras)})


class LensGeometry(Protocol):
    """A fisheye geometry that moves with its lenses (``LSSGeometry``, ``PETRGeometry``)."""

    def with_lenses(self, rig: Rig) -> LensGeometry:
        """The same poses with ``rig``'s lens models."""

    def lens_tables(self) -> dict[str, np.ndarray]:
        """The graph tables that depend on the lenses, by name."""

    @property
    def inside_lens(self) -> np.ndarray:
        """(N, H, W) bool: each camera's cells inside its lens."""


@dataclass(frozen=True)
class StepLenses:
    """One step's moved lenses: the rig its frames are rendered through, the tables of those lenses that
    replace the model's (``lens_tables``) and each camera's cells inside its lens (N, H, W): FisheyeBEVDet's
    depth targets and FisheyePETR's unmasked keys."""

    rig: Rig
    tables: dict[str, np.ndarray]
    inside_lens: np.ndarray


class LensJitter:
    """Draws each step's lens centres within ``pixels`` of ``geometry``'s rig and computes their tables.

    jitter = LensJitter(model.view_transform.geometry, rig, pixels=4.0, seed=0)
    lenses = jitter(step)          # lenses.rig, lenses.tables, lenses.inside_lens
    """

    def __init__(self, geometry: LensGeometry, rig: Rig, pixels: float, seed: int) -> None:
        if not pixels > 0:
            raise ConfigError(f"--lens-jitter: expected a positive number of pixels, got {pixels}")
        self.geometry, self.rig, self.pixels, self.seed = geometry, rig, float(pixels), int(seed)

    def shifts(self, step: int) -> np.ndarray:
        """(N, 2) float64 (rows, cols) offsets of step ``step``'s lens centres."""
        rng = np.random.default_rng([_JITTER_STREAM, self.seed, int(step)])
        return rng.uniform(-self.pixels, self.pixels, size=(len(self.rig), 2))

    def __call__(self, step: int) -> StepLenses:
        rig = centres_moved(self.rig, self.shifts(step))
        moved = self.geometry.with_lenses(rig)
        return StepLenses(rig, moved.lens_tables(), moved.inside_lens)
