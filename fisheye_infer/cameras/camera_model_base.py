"""What every camera model shares: the interface, the image size and the checks of the arrays it takes.

Every model works in the OpenCV camera frame (x right, y down, z forward) and in pixel coordinates whose
integer values are pixel centres (the ``cv2.remap`` convention):

    uv, valid = camera.project(points)    # (N, 3) -> (N, 2) float64, (N,) bool
    rays = camera.unproject(uv)           # (N, 2) -> (N, 3) unit vectors

The models are frozen pydantic objects (``CameraModelFields``) so that a rig file can carry them as plain JSON.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from fisheye_infer.errors import CameraModelError

__all__ = [
    "CameraModel",
    "CameraModelFields",
    "as_pixels",
    "as_points",
    "incidence_angle",
    "inside_image",
    "nonzero",
    "within_fov",
]


class CameraModel(Protocol):
    """What every camera model offers: projection of rays to pixels and unprojection of pixels to rays.

    Pixels are (u, v) = (column, row) with integer values at pixel centres; rays are in the OpenCV camera frame
    (x right, y down, z forward). Every model in this package is a frozen pydantic object with these members.

    Attributes:
        width (int): Image width, pixels.
        height (int): Image height, pixels.
    """

    width: int
    height: int

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays, and which of them the camera sees.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity: the ray is
                within the model's field of view and its pixel inside the image.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        ...

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels.

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        ...


def as_points(points: np.ndarray, name: str = "points") -> np.ndarray:
    """``points`` (points or rays) as an (N, 3) float64 array; ``name`` is what an error calls them.

    Raises:
        CameraModelError: not an (N, 3) array.
    """
    return _columns(points, 3, name)


def as_pixels(uv: np.ndarray) -> np.ndarray:
    """``uv`` (pixels) as an (N, 2) float64 array.

    Raises:
        CameraModelError: not an (N, 2) array.
    """
    return _columns(uv, 2, "uv")


def _columns(values: np.ndarray, columns: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != columns:
        raise CameraModelError(f"{name}: expected an (N, {columns}) array, got shape {arr.shape}")
    return arr


def incidence_angle(points: np.ndarray) -> np.ndarray:
    """Angle between each ray and the optical axis (+z), in [0, pi].

    Args:
        points (np.ndarray): (N, 3) rays.

    Returns:
        np.ndarray: (N,) angles, radians.
    """
    p = as_points(points)
    return np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2])


def inside_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Which pixels lie in a ``width`` x ``height`` image: pixel centres run from 0 to size - 1, and anything
    within half a pixel of them is in the image.

    Args:
        uv (np.ndarray): (N, 2) pixels.
        width (int): image width.
        height (int): image height.

    Returns:
        np.ndarray: (N,) bool.
    """
    return (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= height - 0.5)


def nonzero(points: np.ndarray) -> np.ndarray:
    """Which points are not the origin (``points.any(axis=1)``, column by column: several times faster on (N, 3)).

    Args:
        points (np.ndarray): (N, 3) points.

    Returns:
        np.ndarray: (N,) bool.
    """
    return (points[:, 0] != 0) | (points[:, 1] != 0) | (points[:, 2] != 0)


class CameraModelFields(BaseModel):
    """The fields and checks of every camera model: frozen, no unknown fields, finite numbers, the image size."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    width: int = Field(gt=0, description="image width in pixels")
    height: int = Field(gt=0, description="image height in pixels")

    @field_validator("*", mode="after")
    @classmethod
    def _finite(cls, value: object) -> object:
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError("must be finite")
        return value


def within_fov(points: np.ndarray, fov: float) -> np.ndarray:
    """Rays within ``fov`` of the optical axis (the origin is none).

    Args:
        points (np.ndarray): (N, 3) float64 rays.
        fov (float): full field of view, degrees.

    Returns:
        np.ndarray: (N,) bool.
    """
    return (incidence_angle(points) <= math.radians(fov / 2)) & nonzero(points)
