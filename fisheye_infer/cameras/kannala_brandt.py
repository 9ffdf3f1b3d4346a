"""OpenCV's fisheye model (the paper's 5-term r(theta)), and its distortion-free case, the equidistant model."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from fisheye_infer.cameras.camera_model_base import CameraModelFields, as_pixels, as_points, inside_image
from fisheye_infer.errors import CameraModelError

__all__ = ["KannalaBrandt", "Equidistant"]


class KannalaBrandt(CameraModelFields):
    """OpenCV's fisheye model: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).

    Unlike ``cv2.fisheye`` this uses the incidence angle atan2(|xy|, z), so rays beyond 90 degrees
    (a 220-degree lens) project too; in front of the camera both agree. ``fov`` (degrees) bounds
    the rays that are valid.
    """

    type: Literal["kannala_brandt"] = "kannala_brandt"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    k: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    fov: float = Field(default=220.0, gt=0.0, le=360.0)

    @classmethod
    def from_polynomial(
        cls,
        coeffs: tuple[float, float, float, float, float],
        cx: float,
        cy: float,
        width: int,
        height: int,
        fov: float = 220.0,
    ) -> KannalaBrandt:
        """Build from the paper's radius form r(theta) = k0 theta + k1 theta^3 + ... + k4 theta^9 (pixels)."""
        k0, *rest = coeffs
        if k0 <= 0:
            raise CameraModelError(f"Kannala-Brandt: k0 (the focal length) must be positive, got {k0}")
        return cls(fx=k0, fy=k0, cx=cx, cy=cy, k=tuple(v / k0 for v in rest), width=width, height=height, fov=fov)

    def distort(self, theta: np.ndarray) -> np.ndarray:
        """theta_d(theta), the normalised image radius."""
        t2 = theta * theta
        k1, k2, k3, k4 = self.k
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def undistort(self, theta_d: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Invert ``distort`` by Newton's method, as ``cv2.fisheye.undistortPoints`` does."""
        theta = np.array(theta_d, dtype=np.float64)
        k1, k2, k3, k4 = self.k
        for _ in range(iterations):
            t2 = theta * theta
            f = self.distort(theta) - theta_d
            df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - f / np.where(df == 0, 1.0, df)
        return theta

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = as_points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(rho_xy, p[:, 2])
        safe = np.where(rho_xy == 0, 1.0, rho_xy)
        r = self.distort(theta)
        uv = np.stack([self.fx * r * p[:, 0] / safe + self.cx, self.fy * r * p[:, 1] / safe + self.cy], axis=-1)
        valid = (theta <= math.radians(self.fov / 2)) & p.any(axis=1) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = as_pixels(uv)
        a = (q[:, 0] - self.cx) / self.fx
        b = (q[:, 1] - self.cy) / self.fy
        theta_d = np.hypot(a, b)
        theta = self.undistort(theta_d)
        safe = np.where(theta_d == 0, 1.0, theta_d)
        s = np.sin(theta)
        return np.stack([s * a / safe, s * b / safe, np.cos(theta)], axis=-1)


class Equidistant(KannalaBrandt):
    """The ideal fisheye r = f * theta: Kannala-Brandt with every k zero."""

    type: Literal["equidistant"] = "equidistant"  # type: ignore[assignment]

    @model_validator(mode="after")
    def _no_distortion(self) -> Equidistant:
        if any(self.k):
            raise ValueError("an equidistant model has no distortion coefficients; use kannala_brandt")
        return self
