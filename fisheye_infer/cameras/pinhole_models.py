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
    """A distortion-free perspective camera; only rays in front of it (z > 0) project.

    Attributes:
        type (Literal["pinhole"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.

    Raises:
        pydantic.ValidationError: A field out of range or not finite.
    """

    type: Literal["pinhole"] = "pinhole"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within front of the camera (z > 0) and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        uv = np.stack([self.fx * p[:, 0] / safe + self.cx, self.fy * p[:, 1] / safe + self.cy], axis=-1)
        return uv, (z > 0) & inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels (all with z > 0).

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        rays = np.stack([(q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class DistortedPinhole(CameraModelFields):
    """OpenCV's pinhole camera with lens distortion (``cv2.projectPoints``): ROS's ``plumb_bob`` (5
    coefficients) and ``rational_polynomial`` (8), Kalibr's ``pinhole-radtan`` (4: k1, k2, r1 = p1, r2 = p2).

    ``distortion`` in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6]]). Only rays in front of the
    camera project; unprojection inverts the distortion iteratively, as ``cv2.undistortPoints`` does.

    Attributes:
        type (Literal["distorted_pinhole"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.
        distortion (tuple[float, ...]): 4, 5 or 8 coefficients (k1, k2, p1, p2[, k3[, k4, k5, k6]]).

    Raises:
        pydantic.ValidationError: A field out of range or not finite, or another number of coefficients.
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
        """Pixels of rays; ``valid`` where the ray is within front of the camera (z > 0) and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        x, y = radtan_distort(p[:, 0] / safe, p[:, 1] / safe, self.distortion)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        return uv, (z > 0) & inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels (all with z > 0).

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        x, y = radtan_undistort((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, self.distortion)
        rays = np.stack([x, y, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)
