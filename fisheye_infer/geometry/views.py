"""Pinhole views: the images the standard LSS transform and PETR head see, and how they were made.

The paper's pinhole baselines (official ``LSSTransform`` and ``PETRHead``) read every image as an
ideal pinhole view: intrinsics ``K``, a pose ``cam2lidar``, and the image transform of the test
pipeline (``img_aug_matrix``: scale, then shift, in the view's pixels). Two pipelines make them:

- ``ResizeCrop`` (``ImageAug3D`` / ``ResizeCropFlipImage`` in test mode): each pinhole camera of the
  rig is one view, resized by ``scale`` and cropped at ``crop`` (left, top);
- ``Perspective`` (``MultiViewFisheyePerspectiveProjection``): each fisheye camera gives one view per
  yaw, ``cam2lidar = fisheye cam2lidar @ R_y(yaw)``, with the ideal ``K`` of a ``fov``-degree view of
  ``size``; the images are rectified from the fisheye with ``cv2.remap`` (`perspective_maps`).

Views are ordered camera by camera, each camera's yaws in order (the official order: front -55°,
front +55°, left -55°, ...). Matrices are float64 holding the official float32 values where the
official code stores float32 (``cam2img``, the image transform).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from fisheye_infer.cameras.camera_models import OCamModel, Pinhole
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import per_camera, remap_grid
from fisheye_infer.geometry.resize import pil_bicubic_taps
from fisheye_infer.geometry.tables import RECTIFY, RESIZE_X, RESIZE_Y, resize_tables, sampling_tables

__all__ = [
    "ResizeCrop",
    "Perspective",
    "ViewSource",
    "Views",
    "views_of",
    "pinhole_views",
    "perspective_views",
    "yaw_rotation",
    "perspective_intrinsics",
    "perspective_maps",
    "perspective_image_grid",
    "front_end_tables",
]


class ResizeCrop(BaseModel):
    """Pinhole cameras, each resized by ``scale`` (PIL bicubic) and cropped at (left, top) ``crop``."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: Literal["resize_crop"] = "resize_crop"
    scale: float = Field(gt=0)
    crop: tuple[int, int] = (0, 0)

    def resized_size(self, width: int, height: int) -> tuple[int, int]:
        """(W, H) after the resize, ``int(W * scale), int(H * scale)`` as the official pipelines compute it."""
        return int(width * self.scale), int(height * self.scale)


class Perspective(BaseModel):
    """Perspective views rectified from fisheye cameras: ``size`` (H, W), ``fov`` degrees, one view per yaw
    (degrees)."""

    model_config = ConfigDict(frozen=True, extra="forbid")
    kind: Literal["perspective"] = "perspective"
    size: tuple[int, int] = (400, 400)
    fov: float = Field(default=110.0, gt=0, lt=180)
    yaws: tuple[float, ...] = Field(default=(-55.0, 55.0), min_length=1)


ViewSource = Annotated[ResizeCrop | Perspective, Field(discriminator="kind")]


@dataclass(frozen=True)
class Views:
    """V pinhole views: K (V, 3, 3), cam2lidar (V, 4, 4), the image transform post (V, 3, 3) and its shift (V, 3)."""

    intrinsics: np.ndarray
    cam2lidar: np.ndarray
    post_rotation: np.ndarray
    post_translation: np.ndarray

    def __len__(self) -> int:
        return len(self.intrinsics)

    def lidar2img(self) -> np.ndarray:
        """(V, 4, 4) float64 ``viewpad(ida @ K) @ lidar2cam``: lidar points to the views' homogeneous input pixels.

        ``ida`` is the image transform as a 3x3 homography ([[s, 0, tx], [0, s, ty], [0, 0, 1]]), as
        ``ResizeCropFlipImage`` folds it into ``cam2img`` and ``PETR.add_lidar2img`` pads it to 4x4.
        """
        n = len(self)
        ida = np.tile(np.eye(3), (n, 1, 1))
        ida[:, :2, :2] = self.post_rotation[:, :2, :2]
        ida[:, :2, 2] = self.post_translation[:, :2]
        pad = np.tile(np.eye(4), (n, 1, 1))
        pad[:, :3, :3] = ida @ self.intrinsics
        return pad @ np.linalg.inv(self.cam2lidar)


def _f32(a: np.ndarray) -> np.ndarray:
    """The float32 value the official code stores, held as float64."""
    return np.asarray(a, np.float32).astype(np.float64)


def pinhole_views(rig: Rig, source: ResizeCrop) -> Views:
    """One view per pinhole camera of ``rig``; K from the rig, the image transform from ``source``."""
    ks = []
    for cam in rig.cameras:
        model = cam.model
        if not isinstance(model, Pinhole):
            raise ConfigError(
                f"camera '{cam.name}': a {model.type} model; the pinhole detectors need pinhole cameras "
                "(the rig file of rig-pinhole6 is one)"
            )
        ks.append([[model.fx, 0.0, model.cx], [0.0, model.fy, model.cy], [0.0, 0.0, 1.0]])
    n = len(rig)
    post = np.tile(np.diag([source.scale, source.scale, 1.0]), (n, 1, 1))
    shift = np.tile([-float(source.crop[0]), -float(source.crop[1]), 0.0], (n, 1))
    return Views(
        intrinsics=_f32(np.array(ks)),
        cam2lidar=np.asarray(rig.cam2lidar(), np.float64),
        post_rotation=_f32(post),
        post_translation=_f32(shift),
    )


def yaw_rotation(yaw_deg: float) -> np.ndarray:
    """(3, 3) rotation about the camera's y axis (pointing down) by ``yaw_deg``, as
    ``scipy.spatial.transform.Rotation.from_euler('y', yaw_deg, degrees=True).as_matrix()`` computes it
    (from the unit quaternion (0, sin(a/2), 0, cos(a/2))). Positive yaw turns the view to the right."""
    half = math.radians(yaw_deg) / 2.0
    y, w = math.sin(half), math.cos(half)
    c, s = w * w - y * y, 2.0 * (y * w)
    return np.array([[c, 0.0, s], [0.0, y * y + w * w, 0.0], [-s, 0.0, c]])


def perspective_intrinsics(size: tuple[int, int], fov: float) -> np.ndarray:
    """(3, 3) float32-valued ideal K of a ``fov``-degree view of ``size`` (H, W): the official
    ``get_camera_intrinsics``."""
    h, w = size
    f = np.float32(w / (2.0 * np.tan(fov * np.pi / 360.0)))
    return _f32(np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]]))


def perspective_views(rig: Rig, source: Perspective) -> Views:
    """``len(yaws)`` views per camera of ``rig``, camera by camera."""
    c2l = np.asarray(rig.cam2lidar(), np.float64)
    mats = []
    for m in c2l:
        for yaw in source.yaws:
            r = np.eye(4)
            r[:3, :3] = yaw_rotation(yaw)
            mats.append(m @ r)
    n = len(mats)
    return Views(
        intrinsics=np.tile(perspective_intrinsics(source.size, source.fov), (n, 1, 1)),
        cam2lidar=np.stack(mats),
        post_rotation=np.tile(np.eye(3), (n, 1, 1)),
        post_translation=np.zeros((n, 3)),
    )


def perspective_maps(camera: object, source: Perspective) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap pixel maps (map_x, map_y), each (Y * H, W) float32: the yaws' views stacked vertically.

    The official ``generate_perspective_map``: rays (x, y, f) with x = linspace(-W/2, W/2 - 1, W),
    y likewise, f = (W / 2) / tan(fov / 2), turned by the yaw (``rays @ R.T``) and projected with the
    fisheye's OCam ``world2cam``.
    """
    h, w = source.size
    f = (w / 2) / np.tan(np.radians(source.fov) / 2)
    xs, ys = np.meshgrid(np.linspace(-w / 2, w / 2 - 1, w), np.linspace(-h / 2, h / 2 - 1, h))
    rays = np.stack([xs, ys, np.full_like(xs, f)], axis=-1)
    maps = []
    for yaw in source.yaws:
        turned = rays @ yaw_rotation(yaw).T
        maps.append(camera.world2cam(turned.reshape(-1, 3)).reshape(h, w, 2).astype(np.float32))  # type: ignore[attr-defined]
    uv = np.concatenate(maps, axis=0)
    return uv[..., 0].copy(), uv[..., 1].copy()


def perspective_image_grid(rig: Rig, source: Perspective) -> np.ndarray:
    """(N, Y * H, W, 2) float32 `remap_grid` of each camera's fisheye lens: its views, stacked by yaw."""

    def grid_of(lens: OCamModel) -> np.ndarray:
        map_x, map_y = perspective_maps(lens, source)
        return remap_grid(map_x, map_y, lens.width, lens.height)

    return per_camera(rig, grid_of)


def views_of(rig: Rig, source: ResizeCrop | Perspective) -> Views:
    """The views ``source`` makes of ``rig``'s cameras."""
    return perspective_views(rig, source) if isinstance(source, Perspective) else pinhole_views(rig, source)


def front_end_tables(
    source: ResizeCrop | Perspective,
    source_size: tuple[int, int],
    image_size: tuple[int, int],
    image_grid: np.ndarray | None,
) -> dict[str, np.ndarray]:
    """The tables that make the views from the raw (H, W) ``source_size`` images: cv2.remap's taps of the
    cameras' perspective ``image_grid`` (N, Y * H, W, 2) (``geom.rectify.*``), or PIL's resize and the crop
    to ``image_size`` (``geom.resize.*``)."""
    if isinstance(source, Perspective):
        if image_grid is None:
            raise ConfigError("perspective views: the rectification grid is missing")
        return sampling_tables(RECTIFY, image_grid, source_size)
    (sh, sw), (ih, iw) = source_size, image_size
    rw, rh = source.resized_size(sw, sh)
    left, top = source.crop
    return {
        **resize_tables(RESIZE_X, pil_bicubic_taps(sw, rw, left, iw).blocks()),
        **resize_tables(RESIZE_Y, pil_bicubic_taps(sh, rh, top, ih).blocks()),
    }
