"""Builders for the small hand-made situations the metric tests are written in."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.runtime.records import CLASSES, boxes_to_records
from fisheye_infer.scenes.render import SynthFrame

SIZES = {
    "Car": (4.0, 2.0, 1.5),
    "Van": (5.0, 2.0, 2.0),
    "Truck": (8.0, 2.5, 3.0),
    "Bus": (11.0, 3.0, 3.3),
    "Pedestrian": (0.7, 0.7, 1.8),
    "Cyclist": (1.8, 0.7, 1.7),
}


def record(
    x: float,
    y: float,
    cls: str = "Car",
    yaw: float = 0.0,
    score: float | None = None,
    size: tuple[float, float, float] | None = None,
    z: float = 0.0,
) -> dict:
    """One evaluation record for a box with its bottom at ``z``; ``score=None`` makes it ground truth."""
    length, width, height = size or SIZES[cls]
    boxes = np.array([[x, y, z, length, width, height, yaw]])
    return boxes_to_records(boxes, None if score is None else np.array([score]), np.array([CLASSES.index(cls)]))[0]


def one_of_each(score: float | None = None, shift: float = 0.0, yaw: float = 0.0) -> list[dict]:
    """One box of every class, 60 degrees apart on a 20 m ring; ``shift`` moves them all along x."""
    out = []
    for i, cls in enumerate(CLASSES):
        angle = i * np.pi / 3
        out.append(record(20 * np.cos(angle) + shift, 20 * np.sin(angle), cls, yaw=yaw, score=score))
    return out


@dataclass(frozen=True)
class SynthSet:
    """A synthetic Fisheye3DOD folder and what was written into it."""

    root: Path
    frames: list[SynthFrame]
    rig: Rig
