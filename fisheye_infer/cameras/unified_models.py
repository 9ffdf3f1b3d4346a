"""The wide-angle models that robot calibration tools (Kalibr, Basalt, ROS) write, each a ray through a sphere
or an ellipsoid, then a pinhole.

``DoubleSphere`` (Usenko et al., 2018), ``ExtendedUnified`` (EUCM, Khomutenko et al., 2016; the unified model is
its ``beta = 1``) and ``Omnidirectional`` (Mei and Rives' unified model with radial-tangential distortion,
Kalibr's ``omni-radtan``). Projection and unprojection are in closed form where the model has one; a pixel
outside a model's image of the sphere unprojects to NaN.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field

from fisheye_infer.cameras.camera_model_base import CameraModelFields, as_pixels, as_points, inside_image, within_fov
from fisheye_infer.cameras.radtan_distortion import radtan_distort, radtan_undistort

__all__ = ["DoubleSphere", "ExtendedUnified", "Omnidirectional"]


class DoubleSphere(CameraModelFields):
    """The double sphere model (Usenko, Demmel and Cremers, 2018; Kalibr's and Basalt's ``ds``).

    A ray is projected onto a unit sphere, that point onto a second unit sphere shifted by ``xi``
    along the axis, and that one by a pinhole shifted by ``alpha / (1 - alpha)``:
    ``u = fx x / (alpha d2 + (1 - alpha)(xi d1 + z)) + cx`` with ``d1 = |p|`` and
    ``d2 = |(x, y, xi d1 + z)|``. Rays with ``z <= -w2 d1`` do not project (``w2`` from the paper), nor
    rays beyond ``fov`` (degrees; the importers set it to what the image covers).

    Attributes:
        type (Literal["double_sphere"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.
        xi (float): Shift of the second sphere along the axis.
        alpha (float): Pinhole shift parameter, in (0, 1].
        fov (float): Full field of view in degrees, in (0, 360].

    Raises:
        pydantic.ValidationError: A field out of range or not finite.
    """

    type: Literal["double_sphere"] = "double_sphere"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    xi: float
    alpha: float = Field(gt=0.0, le=1.0)
    fov: float = Field(default=180.0, gt=0.0, le=360.0)

    @property
    def _w2(self) -> float:
        a, xi = self.alpha, self.xi
        w1 = a / (1 - a) if a <= 0.5 else (1 - a) / a
        return (w1 + xi) / math.sqrt(2 * w1 * xi + xi * xi + 1)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within the model's domain and ``fov`` and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        x, y, z = p.T
        d1 = np.linalg.norm(p, axis=1)
        k = self.xi * d1 + z
        d2 = np.sqrt(x * x + y * y + k * k)
        den = self.alpha * d2 + (1 - self.alpha) * k
        safe = np.where(den > 0, den, 1.0)
        uv = np.stack([self.fx * x / safe + self.cx, self.fy * y / safe + self.cy], axis=-1)
        valid = (z > -self._w2 * d1) & (den > 0) & within_fov(p, self.fov) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels; NaN for a pixel outside the model's image of the sphere.

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        mx, my = (q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy
        r2 = mx * mx + my * my
        a, xi = self.alpha, self.xi
        with np.errstate(invalid="ignore"):
            mz = (1 - a * a * r2) / (a * np.sqrt(1 - (2 * a - 1) * r2) + 1 - a)
            scale = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
        rays = np.stack([scale * mx, scale * my, scale * mz - xi], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class ExtendedUnified(CameraModelFields):
    """The extended unified camera model (EUCM: Khomutenko, Garcia and Martinet, 2016; Kalibr's and
    Basalt's ``eucm``); ``beta = 1`` is the unified camera model (UCM).

    ``u = fx x / (alpha d + (1 - alpha) z) + cx`` with ``d = sqrt(beta (x^2 + y^2) + z^2)``: a ray meets
    an ellipsoid, then a pinhole. Rays with ``z <= -w d`` (``w`` from ``alpha``) or beyond ``fov`` do
    not project.

    Attributes:
        type (Literal["eucm"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.
        alpha (float): Ellipsoid-to-pinhole weight, in [0, 1].
        beta (float): Ellipsoid shape (> 0); 1 is the unified model's sphere.
        fov (float): Full field of view in degrees, in (0, 360].

    Raises:
        pydantic.ValidationError: A field out of range or not finite.
    """

    type: Literal["eucm"] = "eucm"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    alpha: float = Field(ge=0.0, le=1.0)
    beta: float = Field(gt=0.0)
    fov: float = Field(default=180.0, gt=0.0, le=360.0)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within the model's domain and ``fov`` and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        x, y, z = p.T
        a = self.alpha
        d = np.sqrt(self.beta * (x * x + y * y) + z * z)
        den = a * d + (1 - a) * z
        safe = np.where(den > 0, den, 1.0)
        uv = np.stack([self.fx * x / safe + self.cx, self.fy * y / safe + self.cy], axis=-1)
        w = a / (1 - a) if a <= 0.5 else (1 - a) / a
        valid = (z > -w * d) & (den > 0) & within_fov(p, self.fov) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels; NaN for a pixel outside the model's image of the sphere.

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        mx, my = (q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy
        r2 = mx * mx + my * my
        a, b = self.alpha, self.beta
        with np.errstate(invalid="ignore"):
            mz = (1 - b * a * a * r2) / (a * np.sqrt(1 - (2 * a - 1) * b * r2) + 1 - a)
        rays = np.stack([mx, my, mz], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class Omnidirectional(CameraModelFields):
    """Mei and Rives' unified model with radial-tangential distortion (Kalibr's ``omni-radtan``).

    A ray is projected onto the unit sphere, shifted by ``xi`` along the axis, and imaged by an
    OpenCV pinhole with ``distortion`` (k1, k2, p1, p2). Rays with ``z <= -w |p|``, ``w = min(xi,
    1 / xi)``, or beyond ``fov`` do not project.

    Attributes:
        type (Literal["omnidirectional"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        fx (float): Focal length along x, pixels (> 0).
        fy (float): Focal length along y, pixels (> 0).
        cx (float): Principal point column, pixels.
        cy (float): Principal point row, pixels.
        xi (float): Shift of the sphere's centre along the axis (>= 0).
        distortion (tuple[float, float, float, float]): Radial-tangential coefficients (k1, k2, p1, p2).
        fov (float): Full field of view in degrees, in (0, 360].

    Raises:
        pydantic.ValidationError: A field out of range or not finite.
    """

    type: Literal["omnidirectional"] = "omnidirectional"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float
    xi: float = Field(ge=0.0)
    distortion: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    fov: float = Field(default=180.0, gt=0.0, le=360.0)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within the model's domain and ``fov`` and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        norm = np.linalg.norm(p, axis=1)
        s = p / np.where(norm > 0, norm, 1.0)[:, None]
        den = s[:, 2] + self.xi
        safe = np.where(den > 0, den, 1.0)
        x, y = radtan_distort(s[:, 0] / safe, s[:, 1] / safe, self.distortion)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        w = min(self.xi, 1 / self.xi) if self.xi > 0 else 0.0
        valid = (s[:, 2] > -w) & (den > 0) & within_fov(p, self.fov) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels; NaN for a pixel outside the model's image of the sphere.

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        mx, my = radtan_undistort((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, self.distortion)
        r2 = mx * mx + my * my
        with np.errstate(invalid="ignore"):
            factor = (self.xi + np.sqrt(1 + (1 - self.xi * self.xi) * r2)) / (r2 + 1)
        rays = np.stack([factor * mx, factor * my, factor - self.xi], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)
