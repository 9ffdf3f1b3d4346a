"""Perspective cameras: the distortion-free pinhole, and OpenCV's pinhole with lens distortion (ROS's
``plumb_bob`` and ``rational_polynomial``, Kalibr's ``pinhole-radtan``)."""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field, field_validator

from fisheye_infer.cameras.camera_model_base import CameraModelFields, as_pixels, as_points, inside_image
from fisheye_infer.cameras.radtan_distortion import radtan_distort, radtan_undistort

__all__ = ["Pinhole", "DistortedPinhole"]


class Pinhole(CameraModelFields):
    """A distortion-free perspective camera; only rays in front of it (z > 0) project."""

    type: Literal["pinhole"] = "pinhole"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = as_points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        uv = np.stack([self.fx * p[:, 0] / safe + self.cx, self.fy * p[:, 1] / safe + self.cy], axis=-1)
        return uv, (z > 0) & inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = as_pixels(uv)
        rays = np.stack([(q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class DistortedPinhole(CameraModelFields):
    """OpenCV's pinhole camera with lens distortion (``cv2.projectPoints``): ROS's ``plumb_bob`` (5
    coefficients) and ``rational_polynomial`` (8), Kalibr's ``pinhole-radtan`` (4: k1, k2, r1 = p1, r2 = p2).

    ``distortion`` in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6]]). Only rays in front of the
    camera project; unprojection inverts the distortion iteratively, as ``cv2.undistortPoints`` does.
    """

    type: Literal["distorted_pinhole"] = "distorted_pinhole"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    distortion: tuple[float, ...] = Field(min_length=4, max_length=8)

    @field_validator("distortion")
    @classmethod
    def _opencv_lengths(cls, value: tuple[float, ...]) -> tuple[float, ...]:
        if len(value) not in (4, 5, 8):
            raise ValueError(f"expected 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]), got {len(value)}")
        return value

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = as_points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        x, y = radtan_distort(p[:, 0] / safe, p[:, 1] / safe, self.distortion)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        return uv, (z > 0) & inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = as_pixels(uv)
        x, y = radtan_undistort((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, self.distortion)
        rays = np.stack([x, y, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)
