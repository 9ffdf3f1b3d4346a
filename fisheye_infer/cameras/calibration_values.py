"""The values a calibration file holds, checked as they are read: numbers, matrices, camera models, poses.

Shared by the readers of ``calibration_files`` and ``kalibr_camchain``. Each check names the file,
camera and field (``label``) and says what was expected; values quoted go through ``short``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from pydantic import ValidationError

from fisheye_infer.cameras.camera_models import DistortedPinhole, KannalaBrandt, Pinhole
from fisheye_infer.cameras.field_of_view import image_fov
from fisheye_infer.cameras.rig_files import error_message
from fisheye_infer.cameras.text_input import short
from fisheye_infer.errors import RigError

__all__ = [
    "POSE_TOLERANCE_MM",
    "POSE_TOLERANCE_DEG",
    "CalibratedCamera",
    "pose_difference",
    "build",
    "wide",
    "k_and_d",
    "floats",
    "matrix",
]

#: Two poses of one camera (from two sources) agree within this distance and angle.
POSE_TOLERANCE_MM: Final = 1.0
POSE_TOLERANCE_DEG: Final = 0.06


@dataclass(frozen=True)
class CalibratedCamera:
    """One camera of a calibration file: its name, model and, where the file chains cameras (Kalibr),
    its pose in the first camera's frame (4x4, camera to first camera); None where the file has none.

    Attributes:
        name (str): The camera's name (the file's, or its file name where the format has none).
        model (Any): Its camera model (a [`KannalaBrandt`][fisheye_infer.cameras.kannala_brandt.KannalaBrandt],
            [`DistortedPinhole`][fisheye_infer.cameras.pinhole_models.DistortedPinhole],
            [`OCamModel`][fisheye_infer.cameras.ocam_model.OCamModel], ...).
        cam2first (np.ndarray | None): (4, 4) float64 transform from this camera's frame to the file's first
            camera's, metres; None where the file does not chain cameras.
    """

    name: str
    model: Any
    cam2first: np.ndarray | None = None


def pose_difference(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """How far apart two 4x4 poses of one frame are: (millimetres, degrees)."""
    delta = np.linalg.inv(a) @ b
    cos = (np.trace(delta[:3, :3]) - 1) / 2
    return float(np.linalg.norm(delta[:3, 3])) * 1000, math.degrees(math.acos(max(-1.0, min(1.0, cos))))


def build(cls: type, label: str, **fields: Any) -> Any:
    """``cls(**fields)``, its validation errors as one ``RigError`` naming each field."""
    try:
        return cls(**fields)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {error_message(e)}" for e in exc.errors())
        raise RigError(f"{label}: {problems}") from None


def wide(cls: type, label: str, **fields: Any) -> Any:
    """A wide-angle model with the field of view its image shows."""
    model = build(cls, label, **{**fields, "fov": 360.0})
    return build(cls, label, **{**fields, "fov": image_fov(model)})


def k_and_d(k: np.ndarray, d: list[float], model: str, label: str, size: dict[str, int]) -> Any:
    """A model from a camera matrix and OpenCV-ordered coefficients: ``plumb_bob``, ``rational_polynomial``,
    ``opencv`` (4, 5 or 8) and ``equidistant``/``fisheye`` (4)."""
    if not np.isfinite(k).all():
        raise RigError(f"{label} (camera_matrix): not finite (got {short(k.tolist())})")
    if not all(math.isfinite(v) for v in d):
        raise RigError(f"{label} (distortion_coefficients): not finite (got {short(d)})")
    if k[0, 1] != 0 or k[1, 0] != 0 or not np.allclose(k[2], (0, 0, 1)):
        raise RigError(f"{label} (camera_matrix): expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}")
    intrinsics = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], **size}
    if model in ("equidistant", "fisheye"):
        if len(d) != 4:
            raise RigError(f"{label}: the {model} model takes 4 coefficients (k1..k4), got {len(d)}")
        return wide(KannalaBrandt, label, k=tuple(d), **intrinsics)
    expected = {"plumb_bob": (5,), "rational_polynomial": (8,), "opencv": (4, 5, 8)}.get(model)
    if expected is None:
        raise RigError(
            f"{label} (distortion_model): {short(model)} cannot be represented "
            "(supported: plumb_bob, rational_polynomial, equidistant)"
        )
    if len(d) not in expected:
        raise RigError(f"{label}: {model} takes {' or '.join(map(str, expected))} coefficients, got {len(d)}")
    if not any(d):
        return build(Pinhole, label, **intrinsics)
    return build(DistortedPinhole, label, distortion=tuple(d), **intrinsics)


def floats(value: Any, count: int | None, label: str) -> list[float]:
    """``value`` as a list of finite numbers (``count`` of them, where given)."""
    try:
        values = [float(v) for v in value]
    except (TypeError, ValueError):
        raise RigError(f"{label}: expected a list of numbers, got {short(value)}") from None
    if count is not None and len(values) != count:
        raise RigError(f"{label}: expected {count} numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise RigError(f"{label}: not finite (got {short(values)})")
    return values


def matrix(value: Any, shape: tuple[int, int], label: str) -> np.ndarray:
    """``value`` (nested or flat) as a finite float64 matrix of ``shape``."""
    try:
        flat = np.asarray(value, dtype=object).ravel() if value is not None else None
    except ValueError:  # rows of different lengths
        flat = None
    if flat is None:
        raise RigError(f"{label}: expected a {shape[0]}x{shape[1]} matrix, got {short(value)}")
    values = floats(flat, shape[0] * shape[1], label)
    return np.asarray(values, dtype=np.float64).reshape(shape)
