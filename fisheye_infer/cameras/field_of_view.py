"""Fields of view of the wide-angle camera models: what an image shows, and what a model can project at all.

``domain_fov`` is the full angle of the rays a model projects whatever its ``fov``: the double sphere
projects rays with ``z > -w2 |p|``, EUCM those with ``z > -w d``, Mei's model those with ``z > -w |p|``
(each model's docstring), Kannala-Brandt and OCam any direction. ``image_fov`` is the angle the image
shows, within that domain; ``reported_fov`` is the one a rig reports for a camera, never more than its
model can project.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from fisheye_infer.cameras.camera_models import DoubleSphere, ExtendedUnified, Omnidirectional, incidence_angle
from fisheye_infer.errors import RigError

__all__ = ["domain_fov", "image_fov", "reported_fov"]


def domain_fov(model: Any) -> float:
    """The full angle (degrees) of the directions ``model`` projects, its ``fov`` aside: 360 where every
    direction does, 180 for a pinhole."""
    if isinstance(model, DoubleSphere):
        a, xi = model.alpha, model.xi
        w1 = a / (1 - a) if a <= 0.5 else (1 - a) / a
        w2 = (w1 + xi) / math.sqrt(2 * w1 * xi + xi * xi + 1)
        return 2 * math.degrees(math.acos(max(-1.0, min(1.0, -w2))))
    if isinstance(model, ExtendedUnified):
        a = model.alpha
        w = a / (1 - a) if a <= 0.5 else (1 - a) / a
        if w >= 1:
            return 360.0
        if w <= 0:
            return 180.0
        # z > -w sqrt(beta r^2 + z^2) holds up to |tan(theta)| = sqrt((1 - w^2) / (w^2 beta)) behind the camera
        return 2 * math.degrees(math.pi - math.atan(math.sqrt((1 - w * w) / (w * w * model.beta))))
    if isinstance(model, Omnidirectional):
        w = min(model.xi, 1 / model.xi) if model.xi > 0 else 0.0
        return 2 * math.degrees(math.acos(-w))
    return 360.0 if hasattr(model, "fov") else 180.0


def reported_fov(model: Any) -> float | None:
    """The field of view (degrees) a camera with ``model`` covers: its ``fov`` within ``domain_fov``,
    None for a model without one (a pinhole's is set by its image)."""
    fov = getattr(model, "fov", None)
    return None if fov is None else round(min(float(fov), domain_fov(model)), 3)


def image_fov(model: Any, directions: int = 72, steps: int = 400) -> float:
    """The full field of view (degrees) that ``model``'s image shows: twice the largest incidence angle of the
    rays through its pixels, sampled from the principal point out to the image border in ``directions``
    directions. A pixel that is not the image of a ray the model projects (outside a circular fisheye's image
    circle, where a distortion polynomial has turned back, or whose unprojection lies outside the model's
    domain) is left out: its ray does not project back onto it."""
    w, h = model.width, model.height
    angle = np.linspace(0.0, 2 * math.pi, directions, endpoint=False)
    dx, dy = np.cos(angle), np.sin(angle)
    with np.errstate(divide="ignore"):  # the distance to the border along each direction
        reach = np.minimum(
            np.where(dx > 0, (w - 1 - model.cx) / dx, np.where(dx < 0, -model.cx / dx, np.inf)),
            np.where(dy > 0, (h - 1 - model.cy) / dy, np.where(dy < 0, -model.cy / dy, np.inf)),
        )
    t = np.linspace(0.0, 1.0, steps)[None, :] * reach[:, None]
    pixels = np.stack([model.cx + t * dx[:, None], model.cy + t * dy[:, None]], axis=-1).reshape(-1, 2)
    rays = model.unproject(pixels)
    everywhere = model.model_copy(update={"fov": 360.0}) if hasattr(model, "fov") else model
    with np.errstate(invalid="ignore"):
        back, projects = everywhere.project(np.nan_to_num(rays))
    on_sphere = np.isfinite(rays).all(axis=1) & projects & (np.abs(back - pixels).max(axis=1) < 0.01)
    if not on_sphere.any():
        raise RigError(f"{type(model).__name__}: no pixel of the image is the image of a ray")
    fov = 2 * math.degrees(float(incidence_angle(rays[on_sphere]).max()))
    return round(min(fov, domain_fov(model)), 3)
