"""The Scaramuzza/OCamCalib model the Fisheye3DOD checkpoints were trained with.

``OCamModel`` also keeps the exact semantics of the ``ocamcamera`` package the official code calls
(``world2cam`` with its (-1, -1) sentinel and ``valid_area``), because the detectors' sampling grids are
defined by those semantics; it reads and writes OCamCalib's ``calib_results.txt``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
from pydantic import Field, model_validator

from fisheye_infer.cameras.camera_model_base import CameraModelFields, as_pixels, as_points, inside_image, nonzero
from fisheye_infer.cameras.text_input import read_text
from fisheye_infer.errors import CameraModelError, RigError

__all__ = ["OCamModel"]


class OCamModel(CameraModelFields):
    """Scaramuzza's omnidirectional model, in ``ocamcamera``'s OpenCV-axis convention.

    ``center_row``/``center_col`` are the file's xc (row) and yc (column); ``pol`` maps an image
    radius to the ray's z (cam2world), ``invpol`` maps theta = incidence - pi/2 to an image
    radius (world2cam); ``c, d, e`` is the affine stretch. ``fov`` (degrees) is not in the file:
    Fisheye3DOD uses 220 everywhere, so that is the default when reading a file.

    Attributes:
        type (Literal["ocam"]): The discriminator a rig file stores.
        width (int): Image width, pixels (> 0).
        height (int): Image height, pixels (> 0).
        pol (tuple[float, ...]): Coefficients (lowest power first) of the direct polynomial: image radius
            (pixels) to the ray's -z.
        invpol (tuple[float, ...]): Coefficients (lowest power first) of the inverse polynomial: theta
            (radians, incidence - pi/2) to image radius (pixels).
        center_row (float): Row of the distortion centre, pixels (the file's xc).
        center_col (float): Column of the distortion centre, pixels (the file's yc).
        c (float): Affine stretch, 1 for square pixels; ``c - d * e`` must be non-zero.
        d (float): Affine skew term.
        e (float): Affine skew term.
        fov (float): Full field of view in degrees, in (0, 360]; rays beyond half of it do not project.

    Raises:
        pydantic.ValidationError: A field out of range or not finite, or ``c - d * e`` zero.

    Examples:
        ```python
        import numpy as np
        from fisheye_infer.cameras.ocam_model import OCamModel

        camera = OCamModel.from_file("calib_results.txt")         # fov: 220 degrees
        rays = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])       # forward, and 90 degrees to the right
        uv, valid = camera.project(rays)                           # (2, 2) pixels, (2,) bool
        back = camera.unproject(uv[valid])                         # (n, 3) unit rays
        assert np.allclose(back, rays[valid], atol=1e-5)
        ```
    """

    type: Literal["ocam"] = "ocam"
    pol: tuple[float, ...] = Field(min_length=1)
    invpol: tuple[float, ...] = Field(min_length=1)
    center_row: float
    center_col: float
    c: float = 1.0
    d: float = 0.0
    e: float = 0.0
    fov: float = Field(default=220.0, gt=0.0, le=360.0, description="full field of view, degrees")

    @model_validator(mode="after")
    def _affine_invertible(self) -> OCamModel:
        if abs(self.c - self.d * self.e) < 1e-9:
            raise ValueError(f"affine c - d*e must be non-zero, got c={self.c}, d={self.d}, e={self.e}")
        return self

    # -- file format -------------------------------------------------------------------

    @classmethod
    def from_file(cls, path: str | Path, fov: float = 220.0) -> OCamModel:
        """Read an OCamCalib ``calib_results.txt``.

        Args:
            path (str | Path): The file.
            fov (float): Full field of view in degrees, which the file does not hold.

        Returns:
            OCamModel: The model.

        Raises:
            CameraModelError: The file is missing, not text, too large or not a valid ``calib_results.txt``.
        """
        path = Path(path)
        try:
            text = read_text(path, "an OCam calib_results.txt")
        except RigError as exc:
            raise CameraModelError(f"OCam file {exc}") from None
        return cls.parse(text, fov=fov, source=str(path))

    @classmethod
    def parse(cls, text: str, fov: float = 220.0, source: str = "<text>") -> OCamModel:
        """Parse the text of a ``calib_results.txt``.

        Blank lines (including CRLF and whitespace-only ones) and ``#`` comments are skipped, so the
        five data rows cannot shift the way they do in ``ocamcamera``'s reader.

        Args:
            text (str): The file's content.
            fov (float): Full field of view in degrees, which the file does not hold.
            source (str): What error messages call the text (a file name).

        Returns:
            OCamModel: The model.

        Raises:
            CameraModelError: A row that is not numbers or not finite, fewer than five data rows, a
                polynomial whose leading count does not match, or a field out of range.
        """
        rows: list[list[float]] = []
        for lineno, line in enumerate(text.splitlines(), start=1):
            stripped = line.strip()
            if not stripped or stripped.startswith("#"):
                continue
            try:
                rows.append([float(tok) for tok in stripped.split()])
            except ValueError as exc:
                quoted = stripped if len(stripped) <= 80 else stripped[:77] + "..."
                raise CameraModelError(f"OCam file {source}, line {lineno}: not a row of numbers: {quoted!r}") from exc
            if not all(math.isfinite(v) for v in rows[-1]):
                raise CameraModelError(f"OCam file {source}, line {lineno}: not finite (NaN or infinity)")
            if len(rows) == 5:
                break
        fields = [
            "direct polynomial",
            "inverse polynomial",
            "centre (row, column)",
            "affine (c, d, e)",
            "image size (height, width)",
        ]
        if len(rows) < 5:
            raise CameraModelError(f"OCam file {source}: expected 5 data rows ({', '.join(fields)}), found {len(rows)}")
        for row, field, count in zip(rows[:5], fields[:5], (None, None, 2, 3, 2)):
            if count is None:
                if len(row) < 2 or int(row[0]) != len(row) - 1:
                    raise CameraModelError(
                        f"OCam file {source}: {field}: the leading count {row[0]:g} does not match the "
                        f"{len(row) - 1} coefficients that follow"
                    )
            elif len(row) != count:
                raise CameraModelError(f"OCam file {source}: {field}: expected {count} numbers, got {len(row)}")
        height, width = rows[4]
        if height != int(height) or width != int(width) or height <= 0 or width <= 0:
            raise CameraModelError(f"OCam file {source}: image size must be two positive integers, got {rows[4]}")
        try:
            return cls(
                pol=tuple(rows[0][1:]),
                invpol=tuple(rows[1][1:]),
                center_row=rows[2][0],
                center_col=rows[2][1],
                c=rows[3][0],
                d=rows[3][1],
                e=rows[3][2],
                height=int(height),
                width=int(width),
                fov=fov,
            )
        except ValueError as exc:
            raise CameraModelError(f"OCam file {source}: {exc}") from exc

    def to_text(self) -> str:
        """Write the model back in the ``calib_results.txt`` layout.

        Returns:
            str: The file's text; [`parse`][fisheye_infer.cameras.ocam_model.OCamModel.parse] reads it back
                to an equal model (``fov`` aside).
        """

        def row(values: tuple[float, ...]) -> str:
            return " ".join(repr(float(v)) for v in values)

        return (
            "#polynomial coefficients for the DIRECT mapping function (ocam_model.ss in MATLAB). "
            "These are used by cam2world\n\n"
            f"{len(self.pol)} {row(self.pol)}\n\n"
            "#polynomial coefficients for the inverse mapping function (ocam_model.invpol in MATLAB). "
            "These are used by world2cam\n\n"
            f"{len(self.invpol)} {row(self.invpol)}\n\n"
            '#center: "row" and "column", starting from 0 (C convention)\n\n'
            f"{self.center_row!r} {self.center_col!r}\n\n"
            '#affine parameters "c", "d", "e"\n\n'
            f"{self.c!r} {self.d!r} {self.e!r}\n\n"
            '#image size: "height" and "width"\n\n'
            f"{self.height} {self.width}\n"
        )

    # -- ocamcamera semantics ---------------------------------------------------------

    @property
    def theta_max(self) -> float:
        """Largest theta (= incidence - pi/2) that projects; rays beyond it are outside the fov."""
        return math.radians(self.fov / 2.0) - math.pi / 2.0

    def _invpol(self, theta: np.ndarray) -> np.ndarray:
        return np.polynomial.polynomial.polyval(theta, np.asarray(self.invpol))

    def _affine(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        u = a + self.e * b + self.center_col
        v = self.d * a + self.c * b + self.center_row
        return np.stack([u, v], axis=-1)

    def world2cam(self, points: np.ndarray) -> np.ndarray:
        """Pixels exactly as ``ocamcamera.world2cam`` defines them, float64.

        Rays beyond the fov and the origin map to the sentinel (-1, -1); a ray on the optical
        axis, in front or behind, maps to the centre without a fov test.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame.

        Returns:
            np.ndarray: (N, 2) float64 pixels (u, v), (-1, -1) where none.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        on_axis = rho_xy == 0
        safe = np.where(on_axis, 1.0, rho_xy)
        theta = np.arctan2(-p[:, 2], safe)  # = -atan(Z / rho_xy)
        rho = self._invpol(theta)
        uv = self._affine(p[:, 0] / safe * rho, p[:, 1] / safe * rho)
        if self.fov < 360:
            uv[(theta > self.theta_max) & ~on_axis] = -1.0
        uv[on_axis] = (self.center_col, self.center_row)
        uv[~nonzero(p)] = -1.0
        return uv

    def cam2world(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays exactly as ``ocamcamera.cam2world`` defines them (no fov mask).

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        q = as_pixels(uv)
        det = self.c - self.d * self.e
        du = q[:, 0] - self.center_col
        dv = q[:, 1] - self.center_row
        b = (dv - self.d * du) / det
        a = (self.c * du - self.e * dv) / det
        r = np.hypot(a, b)
        z = -np.polynomial.polynomial.polyval(r, np.asarray(self.pol))
        rays = np.stack([a, b, z], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def valid_area(self) -> np.ndarray:
        """The uint8 fov mask of ``ocamcamera``: a filled axis-aligned ellipse, 255 inside.

        Semi-axes are rho_max horizontally and c * rho_max vertically; the skew d, e is ignored,
        as in the reference implementation.

        Returns:
            np.ndarray: (height, width) uint8, 255 inside the field of view and 0 outside.
        """
        rho_max = float(self._invpol(np.array([self.theta_max]))[0])
        mask = np.zeros((self.height, self.width), dtype=np.uint8)
        box = ((self.center_col, self.center_row), (2.0 * rho_max, 2.0 * self.c * rho_max), 0.0)
        cv2.ellipse(mask, box, 255, -1)
        return mask

    # -- common interface ----------------------------------------------------------------

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels of rays; ``valid`` where the ray is within the fov and its pixel in the image.

        Args:
            points (np.ndarray): (N, 3) points or rays in the camera frame; only their direction counts.

        Returns:
            tuple[np.ndarray, np.ndarray]: (N, 2) float64 pixels (u, v) and (N,) bool validity.

        Raises:
            CameraModelError: `points` is not an (N, 3) array.
        """
        p = as_points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        safe = np.where(rho_xy == 0, 1.0, rho_xy)
        theta = np.arctan2(-p[:, 2], safe)
        rho = self._invpol(theta)
        uv = self._affine(p[:, 0] / safe * rho, p[:, 1] / safe * rho)
        in_fov = (theta <= self.theta_max) | (rho_xy == 0) & (p[:, 2] > 0)
        valid = in_fov & nonzero(p) & inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays of pixels (``cam2world``; no fov mask).

        Args:
            uv (np.ndarray): (N, 2) pixels (u, v).

        Returns:
            np.ndarray: (N, 3) float64 unit rays in the camera frame.

        Raises:
            CameraModelError: `uv` is not an (N, 2) array.
        """
        return self.cam2world(uv)
