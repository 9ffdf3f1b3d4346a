"""Fit an OCam model to a lens calibrated with another model (Kannala-Brandt, double sphere, EUCM, Mei).

The Fisheye3DOD checkpoints were trained with OCam sampling grids. A user whose lenses are
calibrated with OpenCV's fisheye model (or the paper's r(theta) polynomial), or with Kalibr's
and Basalt's wide-angle models, gets the OCam model of the same lens from ``fit_ocam``, and with
it the geometry tables the detectors expect. The fit reports its own reprojection error (a model with
tangential distortion is not radially symmetric, and shows it there); ``fit_rig_ocam`` refuses a fit
whose error is above ``MAX_FIT_ERROR_PX`` unless forced, and a fit that fails (a lens whose projection
is undefined somewhere in its field of view gives no finite polynomial) is refused by camera.

In units of fx pixels along the image's x axis: invpol is a least-squares polynomial of the image
radius rho(theta) of a ray at incidence theta + pi/2, over the lens's ``fov``; pol is a polynomial
(with a1 = 0, as OCamCalib fixes it) of -rho / tan(alpha(rho)), the z of the ray through image
radius rho. fx != fy is carried by the affine c = fy / fx.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from fisheye_infer.cameras.camera_models import DoubleSphere, ExtendedUnified, KannalaBrandt, OCamModel, Omnidirectional
from fisheye_infer.cameras.field_of_view import domain_fov
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import RigError

#: The models ``fit_rig_ocam`` replaces by their OCam fit.
_FITTED = (KannalaBrandt, DoubleSphere, ExtendedUnified, Omnidirectional)
#: The largest max reprojection error (pixels) of a fit ``fit_rig_ocam`` accepts unless forced.
MAX_FIT_ERROR_PX: Final = 1.0

__all__ = ["MAX_FIT_ERROR_PX", "OCamFit", "fit_ocam", "fit_ocam_from_kb", "fit_rig_ocam"]


@dataclass(frozen=True)
class OCamFit:
    """The fitted model and its errors in pixels over the lens's field of view.

    Attributes:
        model (OCamModel): The fitted OCam model, with the lens's image size, centre and ``fov``.
        max_project_error_px (float): Largest ``|ocam.project(ray) - lens.project(ray)|`` over rays in the fov,
            pixels.
        max_unproject_error_px (float): Largest ``|lens.project(ocam.unproject(uv)) - uv|`` over the lens's
            pixels of those rays, pixels.
    """

    model: OCamModel
    max_project_error_px: float
    max_unproject_error_px: float

    @property
    def max_reprojection_error_px(self) -> float:
        """The larger of the two errors, pixels."""
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


def fit_ocam(lens: Any, invpol_degree: int = 12, pol_degree: int = 10, samples: int = 2000) -> OCamFit:
    """OCam model of a lens over its ``fov`` (within what the model projects), with the fit's max reprojection
    error.

    Args:
        lens (Any): A model with ``fx``, ``fy``, ``cx``, ``cy``, ``fov`` and ``project``/``unproject``:
            [`KannalaBrandt`][fisheye_infer.cameras.kannala_brandt.KannalaBrandt],
            [`DoubleSphere`][fisheye_infer.cameras.unified_models.DoubleSphere],
            [`ExtendedUnified`][fisheye_infer.cameras.unified_models.ExtendedUnified] or
            [`Omnidirectional`][fisheye_infer.cameras.unified_models.Omnidirectional].
        invpol_degree (int): Degree of the inverse polynomial (world to image).
        pol_degree (int): Degree of the direct polynomial (image to world).
        samples (int): Sample points along the radius for each least-squares fit.

    Returns:
        OCamFit: The model and its errors in pixels.

    Raises:
        RigError: The fit gives no finite model or error (a lens whose projection is undefined somewhere in
            its field of view).

    Examples:
        ```python
        from fisheye_infer.cameras.kannala_brandt import KannalaBrandt
        from fisheye_infer.cameras.ocam_fit import fit_ocam

        lens = KannalaBrandt(fx=320.0, fy=320.0, cx=399.5, cy=399.5, k=(0.05, -0.01, 0.0, 0.0),
                             width=800, height=800, fov=200.0)
        fit = fit_ocam(lens)
        fit.model.to_text(), fit.max_reprojection_error_px     # a calib_results.txt, pixels
        ```
    """
    fov = min(float(lens.fov), domain_fov(lens))
    alpha_max = math.radians(fov / 2.0)
    f = lens.fx
    along_x = lens.model_copy(update={"width": 1 << 20, "height": 1 << 20, "cx": 0.0, "cy": 0.0})  # no image edge
    # invpol: image radius (in fx pixels) as a function of theta = alpha - pi/2.
    alpha = np.linspace(0.0, alpha_max, samples)
    theta = alpha - math.pi / 2
    rho = along_x.project(np.stack([np.sin(alpha), np.zeros_like(alpha), np.cos(alpha)], axis=-1))[0][:, 0]
    invpol = _lstsq_poly(theta, rho, list(range(invpol_degree + 1)), scale=1.0)
    # pol: z(rho) = -pol(rho) with z = rho / tan(alpha); at rho -> 0 this tends to f.
    rho_max = float(rho[-1])
    radius = np.linspace(0.0, rho_max, samples)
    rays = along_x.unproject(np.stack([radius, np.zeros_like(radius)], axis=-1))
    alpha_of_rho = np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2])
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(radius > 0, radius * np.cos(alpha_of_rho) / np.sin(alpha_of_rho), f)
    with np.errstate(invalid="ignore"):
        pol = _lstsq_poly(radius, -z, [0] + list(range(2, pol_degree + 1)), scale=rho_max)
    if not (np.isfinite(pol).all() and np.isfinite(invpol).all()):
        raise RigError(
            f"the OCam fit of its {type(lens).__name__} lens failed: the lens gives no finite ray or image point "
            f"somewhere in its {fov:g}-degree field of view"
        )
    model = OCamModel(
        pol=tuple(pol.tolist()),
        invpol=tuple(invpol.tolist()),
        center_row=lens.cy,
        center_col=lens.cx,
        c=lens.fy / lens.fx,
        d=0.0,
        e=0.0,
        width=lens.width,
        height=lens.height,
        fov=fov,
    )
    # Errors over rays/pixels spread across the whole fov, at several azimuths.
    a = np.linspace(0.0, alpha_max, 200)
    b = np.linspace(-math.pi, math.pi, 36, endpoint=False)
    a, b = np.meshgrid(a, b)
    rays = np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1).reshape(-1, 3)
    lens_uv, _ = lens.project(rays)
    ocam_uv, _ = model.project(rays)
    project_err = float(np.abs(ocam_uv - lens_uv).max())
    back, _ = lens.project(model.unproject(lens_uv))
    unproject_err = float(np.abs(back - lens_uv).max())
    if not (math.isfinite(project_err) and math.isfinite(unproject_err)):
        raise RigError(f"the OCam fit of its {type(lens).__name__} lens failed: its error is not finite")
    return OCamFit(model=model, max_project_error_px=project_err, max_unproject_error_px=unproject_err)


def fit_ocam_from_kb(kb: KannalaBrandt, invpol_degree: int = 12, pol_degree: int = 10, samples: int = 2000) -> OCamFit:
    """[`fit_ocam`][fisheye_infer.cameras.ocam_fit.fit_ocam] of a Kannala-Brandt lens.

    Args:
        kb (KannalaBrandt): The lens.
        invpol_degree (int): Degree of the inverse polynomial (world to image).
        pol_degree (int): Degree of the direct polynomial (image to world).
        samples (int): Sample points along the radius for each least-squares fit.

    Returns:
        OCamFit: The model and its errors in pixels.

    Raises:
        RigError: The fit gives no finite model or error.
    """
    return fit_ocam(kb, invpol_degree, pol_degree, samples)


def fit_rig_ocam(
    rig: Rig, max_error_px: float = MAX_FIT_ERROR_PX, force: bool = False
) -> tuple[Rig, dict[str, OCamFit]]:
    """``rig`` with every wide-angle camera (Kannala-Brandt, double sphere, EUCM, Mei) replaced by its
    ``fit_ocam`` model: the form the fisheye detectors' geometry takes.

    Args:
        rig (Rig): The rig to fit.
        max_error_px (float): The largest max reprojection error (pixels) accepted.
        force (bool): Accept fits above ``max_error_px`` too (their errors are still returned).

    Returns:
        tuple[Rig, dict[str, OCamFit]]: The fitted rig (same names, order and poses), and the fits by camera
            name.

    Raises:
        RigError: A fit that fails, or one above ``max_error_px`` unless ``force``, naming the camera and its
            error.
    """
    fits = {}
    for cam in rig.cameras:
        if isinstance(cam.model, _FITTED):
            try:
                fits[cam.name] = fit_ocam(cam.model)
            except RigError as exc:
                raise RigError(f"camera '{cam.name}': {exc}") from None
    above = {name: fit.max_reprojection_error_px for name, fit in fits.items()}
    above = {name: error for name, error in above.items() if error > max_error_px}
    if above and not force:
        errors = ", ".join(f"camera '{name}' {error:.3g} px" for name, error in above.items())
        raise RigError(
            f"OCam fit: max reprojection error above the {max_error_px:g} px bound ({errors}); the OCam model does not "
            "represent the lens there. Keep the lens's own model (no --ocam), or accept the fit with --force-fit "
            "(force=True in Python)"
        )
    models = {cam.name: fits[cam.name].model if cam.name in fits else cam.model for cam in rig.cameras}
    return Rig.from_cameras(models, dict(zip(rig.names, rig.cam2lidar(), strict=True)), name=rig.name), fits
