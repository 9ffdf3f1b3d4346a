"""Camera models behind one interface: ray <-> pixel, with validity.

Every model works in the OpenCV camera frame (x right, y down, z forward) and in pixel
coordinates whose integer values are pixel centres (the ``cv2.remap`` convention):

    uv, valid = camera.project(points)    # (N, 3) -> (N, 2) float64, (N,) bool
    rays = camera.unproject(uv)           # (N, 2) -> (N, 3) unit vectors

``OCamModel`` is the Scaramuzza/OCamCalib model the Fisheye3DOD checkpoints were trained with;
it also keeps the exact semantics of the ``ocamcamera`` package the official code calls
(``world2cam`` with its (-1, -1) sentinel and ``valid_area``), because the detectors' sampling
grids are defined by those semantics. ``KannalaBrandt`` is OpenCV's fisheye model (and the
paper's 5-term r(theta)); ``Equidistant`` and ``Pinhole`` complete the set of the paper's models.

The wide-angle models that robot calibration tools (Kalibr, Basalt, ROS) write: ``DoubleSphere``
(Usenko et al., 2018), ``ExtendedUnified`` (EUCM, Khomutenko et al., 2016; the unified model is its
``beta = 1``), ``Omnidirectional`` (Mei and Rives' unified model with radial-tangential distortion,
Kalibr's ``omni-radtan``) and ``DistortedPinhole`` (OpenCV's pinhole with ``plumb_bob``/``radtan`` or
``rational_polynomial`` distortion). Projection and unprojection are in closed form where the model
has one; a pixel outside a model's image of the sphere unprojects to NaN.

The models are frozen pydantic objects so that a rig file can carry them as plain JSON.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal, Protocol

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from fisheye_infer.cameras.text_input import read_text
from fisheye_infer.errors import CameraModelError, RigError

__all__ = [
    "CameraModel",
    "OCamModel",
    "KannalaBrandt",
    "Equidistant",
    "Pinhole",
    "DistortedPinhole",
    "DoubleSphere",
    "ExtendedUnified",
    "Omnidirectional",
    "AnyCameraModel",
    "incidence_angle",
]


class CameraModel(Protocol):
    """What every camera model offers."""

    width: int
    height: int

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...

    def unproject(self, uv: np.ndarray) -> np.ndarray: ...


def _points(points: np.ndarray, name: str = "points") -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise CameraModelError(f"{name}: expected an (N, 3) array, got shape {arr.shape}")
    return arr


def _pixels(uv: np.ndarray) -> np.ndarray:
    arr = np.asarray(uv, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise CameraModelError(f"uv: expected an (N, 2) array, got shape {arr.shape}")
    return arr


def incidence_angle(points: np.ndarray) -> np.ndarray:
    """Angle between each ray and the optical axis (+z), in [0, pi]."""
    p = _points(points)
    return np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2])


def _nonzero(p: np.ndarray) -> np.ndarray:
    """Points other than the origin (``p.any(axis=1)``, column by column: several times faster on (N, 3))."""
    return (p[:, 0] != 0) | (p[:, 1] != 0) | (p[:, 2] != 0)


def _inside_image(uv: np.ndarray, width: int, height: int) -> np.ndarray:
    """Pixel centres run from 0 to size - 1; anything within half a pixel of them is in the image."""
    return (uv[:, 0] >= -0.5) & (uv[:, 0] <= width - 0.5) & (uv[:, 1] >= -0.5) & (uv[:, 1] <= height - 0.5)


class _Frozen(BaseModel):
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


class OCamModel(_Frozen):
    """Scaramuzza's omnidirectional model, in ``ocamcamera``'s OpenCV-axis convention.

    ``center_row``/``center_col`` are the file's xc (row) and yc (column); ``pol`` maps an image
    radius to the ray's z (cam2world), ``invpol`` maps theta = incidence - pi/2 to an image
    radius (world2cam); ``c, d, e`` is the affine stretch. ``fov`` (degrees) is not in the file:
    Fisheye3DOD uses 220 everywhere, so that is the default when reading a file.
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
        """Read an OCamCalib ``calib_results.txt``."""
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
        """Write the model back in the ``calib_results.txt`` layout."""

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
        """
        p = _points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        on_axis = rho_xy == 0
        safe = np.where(on_axis, 1.0, rho_xy)
        theta = np.arctan2(-p[:, 2], safe)  # = -atan(Z / rho_xy)
        rho = self._invpol(theta)
        uv = self._affine(p[:, 0] / safe * rho, p[:, 1] / safe * rho)
        if self.fov < 360:
            uv[(theta > self.theta_max) & ~on_axis] = -1.0
        uv[on_axis] = (self.center_col, self.center_row)
        uv[~_nonzero(p)] = -1.0
        return uv

    def cam2world(self, uv: np.ndarray) -> np.ndarray:
        """Unit rays exactly as ``ocamcamera.cam2world`` defines them (no fov mask)."""
        q = _pixels(uv)
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
        """
        rho_max = float(self._invpol(np.array([self.theta_max]))[0])
        mask = np.zeros((self.height, self.width), dtype=np.uint8)
        box = ((self.center_col, self.center_row), (2.0 * rho_max, 2.0 * self.c * rho_max), 0.0)
        cv2.ellipse(mask, box, 255, -1)
        return mask

    # -- common interface ----------------------------------------------------------------

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixels for rays within the fov; ``valid`` also requires the pixel to lie in the image."""
        p = _points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        safe = np.where(rho_xy == 0, 1.0, rho_xy)
        theta = np.arctan2(-p[:, 2], safe)
        rho = self._invpol(theta)
        uv = self._affine(p[:, 0] / safe * rho, p[:, 1] / safe * rho)
        in_fov = (theta <= self.theta_max) | (rho_xy == 0) & (p[:, 2] > 0)
        valid = in_fov & _nonzero(p) & _inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        return self.cam2world(uv)


class KannalaBrandt(_Frozen):
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
        p = _points(points)
        rho_xy = np.hypot(p[:, 0], p[:, 1])
        theta = np.arctan2(rho_xy, p[:, 2])
        safe = np.where(rho_xy == 0, 1.0, rho_xy)
        r = self.distort(theta)
        uv = np.stack([self.fx * r * p[:, 0] / safe + self.cx, self.fy * r * p[:, 1] / safe + self.cy], axis=-1)
        valid = (theta <= math.radians(self.fov / 2)) & _nonzero(p) & _inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
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


class Pinhole(_Frozen):
    """A distortion-free perspective camera; only rays in front of it (z > 0) project."""

    type: Literal["pinhole"] = "pinhole"
    fx: float = Field(gt=0)
    fy: float = Field(gt=0)
    cx: float
    cy: float

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = _points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        uv = np.stack([self.fx * p[:, 0] / safe + self.cx, self.fy * p[:, 1] / safe + self.cy], axis=-1)
        return uv, (z > 0) & _inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
        rays = np.stack([(q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _within_fov(points: np.ndarray, fov: float) -> np.ndarray:
    """Rays within ``fov`` (degrees, full angle) of the optical axis."""
    return (incidence_angle(points) <= math.radians(fov / 2)) & _nonzero(points)


def _radtan(x: np.ndarray, y: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distortion of normalised coordinates: radial k1, k2[, k3] (rational k4, k5, k6 divide),
    tangential p1, p2; ``d`` in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6]])."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (*d, 0.0, 0.0, 0.0, 0.0)[:8]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (
        x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
        y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
    )


def _undistort_radtan(x: np.ndarray, y: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Invert ``_radtan`` with OpenCV's iterative undistortion (identity camera matrix, 100 iterations)."""
    if not any(d):
        return x, y
    pts = np.stack([x, y], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    coeffs = np.asarray(d, np.float64)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4's name for the overload with a criteria
        out = cv2.undistortPointsIter(pts, np.eye(3), coeffs, None, None, criteria)
    else:
        out = cv2.undistortPoints(pts, np.eye(3), coeffs, criteria=criteria)
    out = out.reshape(-1, 2)
    return out[:, 0], out[:, 1]


class DistortedPinhole(_Frozen):
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
        p = _points(points)
        z = p[:, 2]
        safe = np.where(z > 0, z, 1.0)
        x, y = _radtan(p[:, 0] / safe, p[:, 1] / safe, self.distortion)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        return uv, (z > 0) & _inside_image(uv, self.width, self.height)

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
        x, y = _undistort_radtan((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, self.distortion)
        rays = np.stack([x, y, np.ones(len(q))], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class DoubleSphere(_Frozen):
    """The double sphere model (Usenko, Demmel and Cremers, 2018; Kalibr's and Basalt's ``ds``).

    A ray is projected onto a unit sphere, that point onto a second unit sphere shifted by ``xi``
    along the axis, and that one by a pinhole shifted by ``alpha / (1 - alpha)``:
    ``u = fx x / (alpha d2 + (1 - alpha)(xi d1 + z)) + cx`` with ``d1 = |p|`` and
    ``d2 = |(x, y, xi d1 + z)|``. Rays with ``z <= -w2 d1`` do not project (``w2`` from the paper), nor
    rays beyond ``fov`` (degrees; the importers set it to what the image covers).
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
        p = _points(points)
        x, y, z = p.T
        d1 = np.linalg.norm(p, axis=1)
        k = self.xi * d1 + z
        d2 = np.sqrt(x * x + y * y + k * k)
        den = self.alpha * d2 + (1 - self.alpha) * k
        safe = np.where(den > 0, den, 1.0)
        uv = np.stack([self.fx * x / safe + self.cx, self.fy * y / safe + self.cy], axis=-1)
        valid = (z > -self._w2 * d1) & (den > 0) & _within_fov(p, self.fov) & _inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
        mx, my = (q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy
        r2 = mx * mx + my * my
        a, xi = self.alpha, self.xi
        with np.errstate(invalid="ignore"):
            mz = (1 - a * a * r2) / (a * np.sqrt(1 - (2 * a - 1) * r2) + 1 - a)
            scale = (mz * xi + np.sqrt(mz * mz + (1 - xi * xi) * r2)) / (mz * mz + r2)
        rays = np.stack([scale * mx, scale * my, scale * mz - xi], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class ExtendedUnified(_Frozen):
    """The extended unified camera model (EUCM: Khomutenko, Garcia and Martinet, 2016; Kalibr's and
    Basalt's ``eucm``); ``beta = 1`` is the unified camera model (UCM).

    ``u = fx x / (alpha d + (1 - alpha) z) + cx`` with ``d = sqrt(beta (x^2 + y^2) + z^2)``: a ray meets
    an ellipsoid, then a pinhole. Rays with ``z <= -w d`` (``w`` from ``alpha``) or beyond ``fov`` do
    not project.
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
        p = _points(points)
        x, y, z = p.T
        a = self.alpha
        d = np.sqrt(self.beta * (x * x + y * y) + z * z)
        den = a * d + (1 - a) * z
        safe = np.where(den > 0, den, 1.0)
        uv = np.stack([self.fx * x / safe + self.cx, self.fy * y / safe + self.cy], axis=-1)
        w = a / (1 - a) if a <= 0.5 else (1 - a) / a
        valid = (z > -w * d) & (den > 0) & _within_fov(p, self.fov) & _inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
        mx, my = (q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy
        r2 = mx * mx + my * my
        a, b = self.alpha, self.beta
        with np.errstate(invalid="ignore"):
            mz = (1 - b * a * a * r2) / (a * np.sqrt(1 - (2 * a - 1) * b * r2) + 1 - a)
        rays = np.stack([mx, my, mz], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


class Omnidirectional(_Frozen):
    """Mei and Rives' unified model with radial-tangential distortion (Kalibr's ``omni-radtan``).

    A ray is projected onto the unit sphere, shifted by ``xi`` along the axis, and imaged by an
    OpenCV pinhole with ``distortion`` (k1, k2, p1, p2). Rays with ``z <= -w |p|``, ``w = min(xi,
    1 / xi)``, or beyond ``fov`` do not project.
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
        p = _points(points)
        norm = np.linalg.norm(p, axis=1)
        s = p / np.where(norm > 0, norm, 1.0)[:, None]
        den = s[:, 2] + self.xi
        safe = np.where(den > 0, den, 1.0)
        x, y = _radtan(s[:, 0] / safe, s[:, 1] / safe, self.distortion)
        uv = np.stack([self.fx * x + self.cx, self.fy * y + self.cy], axis=-1)
        w = min(self.xi, 1 / self.xi) if self.xi > 0 else 0.0
        valid = (s[:, 2] > -w) & (den > 0) & _within_fov(p, self.fov) & _inside_image(uv, self.width, self.height)
        return uv, valid

    def unproject(self, uv: np.ndarray) -> np.ndarray:
        q = _pixels(uv)
        mx, my = _undistort_radtan((q[:, 0] - self.cx) / self.fx, (q[:, 1] - self.cy) / self.fy, self.distortion)
        r2 = mx * mx + my * my
        with np.errstate(invalid="ignore"):
            factor = (self.xi + np.sqrt(1 + (1 - self.xi * self.xi) * r2)) / (r2 + 1)
        rays = np.stack([factor * mx, factor * my, factor - self.xi], axis=-1)
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)


AnyCameraModel = Annotated[
    OCamModel
    | KannalaBrandt
    | Equidistant
    | Pinhole
    | DistortedPinhole
    | DoubleSphere
    | ExtendedUnified
    | Omnidirectional,
    Field(discriminator="type"),
]
