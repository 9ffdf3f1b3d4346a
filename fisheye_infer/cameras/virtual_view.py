"""A robot camera seen as the training camera: where each training pixel's ray lands in the robot's image.

    view = virtual_view(training_camera, robot_camera)        # rotation compensated, translation not
    view.map_x, view.map_y                                    # cv2.remap maps into the robot's image
    view.seen, view.inside_lens                               # which training pixels it can show

For every pixel of the training camera's image, its ray through the training lens is known; turned
from the training mount into the robot mount (``cam2lidar`` rotations) and projected through the robot
lens, it lands on a robot pixel. Resampling the robot's raw image at those pixels gives the picture the
training camera would have taken from its own mount, through its own lens: the network and its geometry
tables stay as trained. Rotation between the mounts is compensated exactly. Translation is parallax and
cannot be: with ``depth=None`` it is ignored (every point at infinity); with a depth in metres every
training ray is taken to end on a sphere of that radius around the training camera, which is exact for
points at that distance.

Training pixels outside the training lens's field stay black, as in the training images
(`pixel_rays`' ``inside``); pixels inside it whose ray the robot camera does not see are
``unseen`` and are filled with ``UNSEEN_FILL``: a constant mid-grey reads to the detectors as
featureless, where black reads as a dark, empty region.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fisheye_infer.cameras.camera_models import incidence_angle
from fisheye_infer.cameras.rig import RigCamera

__all__ = ["UNSEEN_FILL", "OUTSIDE", "VirtualView", "pixel_rays", "virtual_view", "rotation_angle_deg"]

#: The grey level of training pixels whose ray the robot camera does not see.
UNSEEN_FILL = 128.0
#: The map value of a training pixel that samples nothing (outside the lens, or unseen).
OUTSIDE = -1.0


def pixel_rays(model: object) -> tuple[np.ndarray, np.ndarray]:
    """Every pixel's unit ray (H * W, 3) float64 in the camera frame, row-major, and which lie inside the lens's field.

    Args:
        model: A camera model (``unproject``, ``width``, ``height``; ``fov`` in degrees where it has one).

    Returns:
        tuple[np.ndarray, np.ndarray]: The rays, and (H * W,) bool: the incidence angle within half of ``fov``
        and the ray finite (all True for a model without ``fov``).
    """
    width, height = model.width, model.height  # type: ignore[attr-defined]
    v, u = np.mgrid[0:height, 0:width]
    rays = model.unproject(np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64))  # type: ignore[attr-defined]
    finite = np.isfinite(rays).all(axis=1)
    fov = getattr(model, "fov", None)
    with np.errstate(invalid="ignore"):
        inside = finite & (incidence_angle(rays) <= math.radians(fov / 2) if fov is not None else finite)
    return rays, inside


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """The angle of a 3x3 rotation, degrees.

    Args:
        rotation: A rotation matrix.

    Returns:
        float: Its rotation angle in [0, 180].
    """
    cos = (float(np.trace(rotation)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


@dataclass(frozen=True)
class VirtualView:
    """The training camera's image as resampled from a robot camera's.

    Attributes:
        map_x (np.ndarray): (H, W) float32 robot column of each training pixel (cv2.remap's map); ``OUTSIDE``
            (-1) where it samples nothing.
        map_y (np.ndarray): (H, W) float32 robot row, likewise.
        inside_lens (np.ndarray): (H, W) bool, training pixels inside the training lens's field.
        seen (np.ndarray): (H, W) bool, those whose ray the robot camera sees.
        rotation_deg (float): The rotation between the two mounts that the resampling compensates, degrees.
        translation_mm (float): The distance between the two camera centres, which it does not (unless a depth
            is given), millimetres.
        sampling_scale (float): Median robot pixels per training pixel (square root of the map's Jacobian
            determinant) over the seen pixels; below 1 the robot camera resolves less than the network was
            trained on.

    Examples:
        ```python
        import cv2
        from fisheye_infer.cameras.virtual_view import virtual_view

        view = virtual_view(training_rig.camera("fisheye_camera_front"), robot_rig.camera("cam0"))
        image = cv2.remap(robot_image, view.map_x, view.map_y, cv2.INTER_LINEAR)
        image[view.unseen] = 128
        ```
    """

    map_x: np.ndarray
    map_y: np.ndarray
    inside_lens: np.ndarray
    seen: np.ndarray
    rotation_deg: float
    translation_mm: float
    sampling_scale: float

    @property
    def coverage(self) -> float:
        """The share of the training lens's field that the robot camera sees."""
        return float(self.seen.sum() / max(1, self.inside_lens.sum()))

    @property
    def unseen(self) -> np.ndarray:
        """(H, W) bool: inside the training lens, not seen by the robot camera (filled with ``UNSEEN_FILL``)."""
        return self.inside_lens & ~self.seen

    def fill(self) -> np.ndarray:
        """The fill for pixels the robot camera does not see.

        Returns:
            np.ndarray: (H, W) float32, ``UNSEEN_FILL`` (128) on unseen pixels, 0 elsewhere.
        """
        return np.where(self.unseen, np.float32(UNSEEN_FILL), np.float32(0.0)).astype(np.float32)


def virtual_view(training: RigCamera, robot: RigCamera, depth: float | None = None) -> VirtualView:
    """Where each pixel of ``training``'s image lands in ``robot``'s image.

    Args:
        training (RigCamera): The camera a model was trained with (lens and mount).
        robot (RigCamera): The camera that stands in for it.
        depth (float | None): None to compensate rotation only (points at infinity); else the distance in metres
            at which the training rays are taken to end, so that the camera centres' offset is compensated at
            that distance.

    Returns:
        VirtualView: The remap maps (the training camera's image size) and what they cover.
    """
    model = training.model
    height, width = model.height, model.width
    rays, inside = pixel_rays(model)
    rays = np.where(inside[:, None], rays, 0.0)
    t2l, r2l = training.matrix, robot.matrix
    if depth is None:
        points = rays @ (r2l[:3, :3].T @ t2l[:3, :3]).T
    else:
        in_lidar = rays * depth @ t2l[:3, :3].T + t2l[:3, 3]
        points = (in_lidar - r2l[:3, 3]) @ r2l[:3, :3]
    uv, valid = robot.model.project(points)
    seen = inside & valid
    uv = np.where(seen[:, None], uv, OUTSIDE).astype(np.float32)
    map_x, map_y = uv[:, 0].reshape(height, width), uv[:, 1].reshape(height, width)
    return VirtualView(
        map_x=map_x,
        map_y=map_y,
        inside_lens=inside.reshape(height, width),
        seen=seen.reshape(height, width),
        rotation_deg=rotation_angle_deg(r2l[:3, :3].T @ t2l[:3, :3]),
        translation_mm=float(np.linalg.norm(r2l[:3, 3] - t2l[:3, 3]) * 1000.0),
        sampling_scale=_sampling_scale(map_x, map_y, seen.reshape(height, width)),
    )


def _sampling_scale(map_x: np.ndarray, map_y: np.ndarray, seen: np.ndarray) -> float:
    """Median sqrt|det J| of the map over pixels whose right and lower neighbours are seen too."""
    both = seen[:-1, :-1] & seen[1:, :-1] & seen[:-1, 1:]
    if not both.any():
        return 0.0
    mx, my = map_x.astype(np.float64), map_y.astype(np.float64)
    dxu, dyu = (mx[:-1, 1:] - mx[:-1, :-1]), (my[:-1, 1:] - my[:-1, :-1])
    dxv, dyv = (mx[1:, :-1] - mx[:-1, :-1]), (my[1:, :-1] - my[:-1, :-1])
    det = np.abs(dxu * dyv - dyu * dxv)[both]
    return float(np.median(np.sqrt(det)))
