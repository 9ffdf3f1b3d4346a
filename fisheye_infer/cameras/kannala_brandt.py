"""OpenCV's fisheye model (the paper's 5-term r(theta)), and its distortion-free case, the equidistant model."""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field, model_validator

from fisheye_infer.cameras.camera_model_base import CameraModelFields, as_pixels, as_points, inside_image, nonzero
from fisheye_infer.errors import CameraModelError

__all__ = ["KannalaBrandt", "Equidistant"]


class KannalaBrandt(CameraModelFields):
    """OpenCV's fisheye model: theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8).

    Unlike ``cv2.fisheye`` this uses the incidence angle atan2(|xy|, z), so rays beyond 90 degrees
    (a 220-degree lens) project too; in front of the camera both agree. ``fov`` (degrees) bounds
    the rays that are valid.

    Attributes:
        type (Literal["kannala_brandt"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.
        k (tuple[float, float, float, float]): Distortion coefficients k1..k4 (OpenCV's ``cv::fisheye`` D).
        fov (float): Full field of view in degrees, in (0, 360]; rays beyond half of it are not valid.

    Raises:
        pydantic.ValidationError: A field out of range or not finite.

    Examples:
        ```python
        from fisheye_infer.cameras.kannala_brandt import KannalaBrandt

        lens = KannalaBrandt(fx=320.0, fy=320.0, cx=399.5, cy=399.5, k=(0.05, -0.01, 0.0, 0.0),
                             width=800, height=800, fov=200.0)
        uv, valid = lens.project(rays)      # rays: (N, 3) in the camera frame
        ```
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
        """Build from the paper's radius form r(theta) = k0 theta + k1 theta^3 + ... + k4 theta^9 (pixels).

        Args:
            coeffs (tuple[float, float, float, float, float]): k0..k4 of r(theta), pixels; k0 is the focal length.
            cx (float): Principal point column, pixels.
            cy (float): Principal point row, pixels.
            width (int): Image width, pixels.
            height (int): Image height, pixels.
            fov (float): Full field of view, degrees.

        Returns:
            KannalaBrandt: The model with ``fx = fy = k0`` and ``k = (k1, k2, k3, k4) / k0``.

        Raises:
            CameraModelError: k0 is not positive.
            pydantic.ValidationError: Another field out of range.
        """
        k0, *rest = coeffs
        if k0 <= 0:
            raise CameraModelError(f"Kannala-Brandt: k0 (the focal length) must be positive, got {k0}")
        return cls(fx=k0, fy=k0, cx=cx, cy=cy, k=tuple(v / k0 for v in rest), width=width, height=height, fov=fov)

    def distort(self, theta: np.ndarray) -> np.ndarray:
        """theta_d(theta), the normalised image radius.

        Args:
            theta (np.ndarray): Incidence angles, radians, any shape.

        Returns:
            np.ndarray: theta_d of the same shape (image radius divided by the focal length).
        """
        t2 = theta * theta
        k1, k2, k3, k4 = self.k
        return theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))

    def undistort(self, theta_d: np.ndarray, iterations: int = 20) -> np.ndarray:
        """Invert ``distort`` by Newton's method, as ``cv2.fisheye.undistortPoints`` does.

        Args:
            theta_d (np.ndarray): Normalised image radii, any shape.
            iterations (int): Newton steps.

        Returns:
            np.ndarray: Incidence angles theta, radians, float64 of the same shape.
        """
        theta = np.array(theta_d, dtype=np.float64)
        k1, k2, k3, k4 = self.k
        for _ in range(iterations):
            t2 = theta * theta
            f = self.distort(theta) - theta_d
            df = 1.0 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))
            theta = theta - f / np.where(df == 0, 1.0, df)
        return theta

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within ``fov`` and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(rho_xy, p[:, 2])
        safe = np.where(rho_xy == 0, 1.0, rho_xy)
        r = self.distort(theta)
        uv = np.stack([self.fx * r * p[:, 0] / safe + self.cx, self.fy * r * p[:, 1] / safe + self.cy], axis=-1)
        valid = (theta <= math.radians(self.fov / 2)) & nonzero(p) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels (no fov mask).

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        a = (q[:, 0] - self.cx) / self.fx
        b = (q[:, 1] - self.cy) / self.fy
        theta_d = np.hypot(a, b)
        theta = self.undistort(theta_d)
        safe = np.where(theta_d == 0, 1.0, theta_d)
        s = np.sin(theta)
        return np.stack([s * a / safe, s * b / safe, np.cos(theta)], axis=-1)


class Equidistant(KannalaBrandt):
    """The ideal fisheye r = f * theta: Kannala-Brandt with every k zero.

    Attributes:
        type (Literal["equidistant"]): The discriminator a rig file stores; the other fields are
            [`KannalaBrandt`][fisheye_infer.cameras.kannala_brandt.KannalaBrandt]'s, with ``k`` all zero.

    Raises:
        pydantic.ValidationError: A non-zero ``k``, or a field out of range.
    """

    type: Literal["equidistant"] = "equidistant"  # type: ignore[assignment]

    @model_validator(mode="after")
    def _no_distortion(self) -> Equidistant:
        if any(self.k):
            raise ValueError("an equidistant model has no distortion coefficients; use kannala_brandt")
        return self
