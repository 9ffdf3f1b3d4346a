"""Fit an OCam model to a Kannala-Brandt (OpenCV fisheye) calibration.

The Fisheye3DOD checkpoints were trained with OCam sampling grids. A user whose lenses are
calibrated with OpenCV's fisheye model (or the paper's r(theta) polynomial) gets the OCam
model of the same lens from ``fit_ocam_from_kb``, and with it the geometry tables the
detectors expect. The fit reports its own reprojection error, so the user can judge it.

With fx = fy = f and no skew: invpol is a least-squares polynomial of rho(theta) =
r_KB(theta + pi/2) over theta in [-pi/2, fov/2 - pi/2]; pol is a polynomial (with a1 = 0, as
OCamCalib fixes it) of -rho / tan(alpha(rho)), the z of the ray through image radius rho.
fx != fy is carried by the affine c = fy / fx.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fisheye_infer.cameras.camera_models import KannalaBrandt, OCamModel

__all__ = ["OCamFit", "fit_ocam_from_kb"]


@dataclass(frozen=True)
class OCamFit:
    """The fitted model and its errors in pixels over the lens's field of view."""

    model: OCamModel
    max_project_error_px: float  # |OCam.project(ray) - KB.project(ray)|
    max_unproject_error_px: float  # |KB.project(OCam.unproject(uv)) - uv|

    @property
    def max_reprojection_error_px(self) -> float:
        return max(self.max_project_error_px, self.max_unproject_error_px)


def _lstsq_poly(x: np.ndarray, y: np.ndarray, powers: list[int], scale: float) -> np.ndarray:
    """Least squares in the scaled variable x / scale, returned as coefficients of x^0..x^max."""
    xs = x / scale
    basis = np.stack([xs**p for p in powers], axis=1)
    coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
    full = np.zeros(max(powers) + 1)
    for p, c in zip(powers, coef):
        full[p] = c / scale**p
    return full


def fit_ocam_from_kb(kb: KannalaBrandt, invpol_degree: int = 12, pol_degree: int = 10, samples: int = 2000) -> OCamFit:
    """OCam model of a Kannala-Brandt lens over its ``fov``, with the fit's max reprojection error."""
    alpha_max = math.radians(kb.fov / 2.0)
    f = kb.fx
    # invpol: image radius (in fx pixels) as a function of theta = alpha - pi/2.
    alpha = np.linspace(0.0, alpha_max, samples)
    theta = alpha - math.pi / 2
    rho = f * kb.distort(alpha)
    invpol = _lstsq_poly(theta, rho, list(range(invpol_degree + 1)), scale=1.0)
    # pol: z(rho) = -pol(rho) with z = rho / tan(alpha); at rho -> 0 this tends to f.
    rho_max = float(rho[-1])
    radius = np.linspace(0.0, rho_max, samples)
    alpha_of_rho = kb.undistort(radius / f)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(radius > 0, radius * np.cos(alpha_of_rho) / np.sin(alpha_of_rho), f)
    pol = _lstsq_poly(radius, -z, [0] + list(range(2, pol_degree + 1)), scale=rho_max)
    model = OCamModel(
        pol=tuple(pol.tolist()),
        invpol=tuple(invpol.tolist()),
        center_row=kb.cy,
        center_col=kb.cx,
        c=kb.fy / kb.fx,
        d=0.0,
        e=0.0,
        width=kb.width,
        height=kb.height,
        fov=kb.fov,
    )
    # Errors over rays/pixels spread across the whole fov, at several azimuths.
    a = np.linspace(0.0, alpha_max, 200)
    b = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    a, b = np.meshgrid(a, b)
    rays = np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1).reshape(-1, 3)
    kb_uv, _ = kb.project(rays)
    ocam_uv, _ = model.project(rays)
    project_err = float(np.abs(ocam_uv - kb_uv).max())
    back, _ = kb.project(model.unproject(kb_uv))
    unproject_err = float(np.abs(back - kb_uv).max())
    return OCamFit(model=model, max_project_error_px=project_err, max_unproject_error_px=unproject_err)
