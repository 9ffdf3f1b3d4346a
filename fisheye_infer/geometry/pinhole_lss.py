"""The standard LSS transform's geometry (pinhole BEVDet baselines): image front end, frustum, pooling plan.

The official ``LSSTransform`` lifts each cell of a view's stride-16 features along the pinhole ray
of its pixel: the frustum holds image coordinates (x over ``linspace(0, W - 1, fW)``, y likewise,
depth ``arange(*dbound)``), and ``get_geometry`` undoes the image transform, multiplies x, y by the
depth, applies ``cam2lidar @ inv(K)`` and adds the camera position (`view_points`). The views
are `views`' (pinhole cameras resized and cropped, or perspective views of fisheye cameras).

The front end that makes the views from the raw camera images is part of the geometry, as the
cylindrical rectification is: PIL's bicubic resize and the crop (``geom.resize.*``, which depend on
the image sizes only), or cv2.remap's perspective rectification (``geom.rectify.*``, which depends
on the fisheye calibration).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.frustum import depth_bins
from fisheye_infer.geometry.grids import cells_inside_lens, fisheye_lenses
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.geometry.tables import DEFAULT_BUCKET_SIZES, pool_tables
from fisheye_infer.geometry.views import (
    Perspective,
    Views,
    ViewSource,
    front_end_tables,
    perspective_image_grid,
    views_of,
)

__all__ = ["PinholeLSSParams", "PinholeLSSGeometry", "image_frustum", "view_points"]


class PinholeLSSParams(BaseModel):
    """What the tables of a pinhole BEVDet graph are computed from (besides the rig).

    ``source_size`` (H, W) of the raw camera images the graph takes, ``image_size`` (H, W) of the
    views the backbone sees, ``feature_size`` (H, W) of their stride-16 features; ``views`` says how
    the views are made; the bounds are LSS's.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["pinhole_lss"] = "pinhole_lss"
    feature_size: tuple[int, int]
    image_size: tuple[int, int]
    source_size: tuple[int, int]
    views: ViewSource
    dbound: tuple[float, float, float]
    xbound: tuple[float, float, float]
    ybound: tuple[float, float, float]
    zbound: tuple[float, float, float]
    bucket_sizes: tuple[int, ...] = DEFAULT_BUCKET_SIZES

    @property
    def bev_grid(self) -> BevGrid:
        return BevGrid(self.xbound, self.ybound, self.zbound)

    @property
    def views_per_camera(self) -> int:
        return len(self.views.yaws) if isinstance(self.views, Perspective) else 1

    def frustum(self) -> np.ndarray:
        """(D, H, W, 3) float32 image coordinates and depth: the official ``create_frustum``."""
        return image_frustum(self.image_size, self.feature_size, self.dbound)


def image_frustum(
    image_size: tuple[int, int], feature_size: tuple[int, int], dbound: tuple[float, float, float]
) -> np.ndarray:
    """(D, fH, fW, 3) float32 (x, y, depth): x = linspace(0, W - 1, fW), y = linspace(0, H - 1, fH),
    depth = arange(*dbound)."""
    (ih, iw), (fh, fw) = image_size, feature_size
    ds = depth_bins(dbound).astype(np.float64)
    xs, ys = np.linspace(0, iw - 1, fw), np.linspace(0, ih - 1, fh)
    d, y, x = np.meshgrid(ds, ys, xs, indexing="ij")
    return np.stack([x, y, d], axis=-1).astype(np.float32)


def _round32(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, np.float32).astype(np.float64)


def view_points(frustum: np.ndarray, views: Views) -> np.ndarray:
    """(V, D, H, W, 3) float32 lidar-frame points of the frustum in every view: the official ``get_geometry``.

    Steps, each rounded to float32 where the official float32 tensors are: subtract the image
    shift, apply ``inv(post)``, scale x and y by the depth, apply ``cam2lidar[:3, :3] @ inv(K)``, add
    the camera position.
    """
    f = np.asarray(frustum, np.float64)
    post_inv = _round32(np.linalg.inv(_round32(views.post_rotation)))
    combine = _round32(_round32(views.cam2lidar[:, :3, :3]) @ _round32(np.linalg.inv(_round32(views.intrinsics))))
    shift = _round32(views.post_translation)[:, None, None, None, :]
    p = _round32(f[None] - shift)
    p = _round32(np.einsum("vij,vdhwj->vdhwi", post_inv, p))
    p = _round32(np.concatenate([p[..., :2] * p[..., 2:3], p[..., 2:3]], axis=-1))
    p = _round32(np.einsum("vij,vdhwj->vdhwi", combine, p))
    return (p + _round32(views.cam2lidar[:, :3, 3])[:, None, None, None, :]).astype(np.float32)


@dataclass(frozen=True)
class PinholeLSSGeometry:
    """Geometry tables of the pinhole LSS transform for one rig and configuration."""

    params: PinholeLSSParams
    views: Views
    frustum: np.ndarray  # D x H x W x 3 float32, image coordinates and depth
    plan: PoolingPlan
    image_grid: np.ndarray | None  # (N, Y * Hv, Wv, 2) remap grids of each camera's views; None for pinhole cameras
    source: str = "rig"  # where the frustum came from: "rig" or "checkpoint"
    #: (N * Y, H, W) bool, each view's feature cells that show its camera's fisheye lens (``cells_inside_lens``),
    #: camera by camera; None for pinhole cameras.
    inside_lens: np.ndarray | None = None

    @classmethod
    def from_rig(cls, rig: Rig, params: PinholeLSSParams) -> PinholeLSSGeometry:
        views = views_of(rig, params.views)
        frustum = params.frustum()
        plan = build_pooling_plan(view_points(frustum, views), params.bev_grid, params.bucket_sizes)
        if not isinstance(params.views, Perspective):
            return cls(params=params, views=views, frustum=frustum, plan=plan, image_grid=None)
        grid = perspective_image_grid(rig, params.views)
        yaws = len(params.views.yaws)
        inside = np.concatenate(
            [cells_inside_lens(lens, g, yaws, params.feature_size) for lens, g in zip(fisheye_lenses(rig), grid)]
        )
        return cls(params=params, views=views, frustum=frustum, plan=plan, image_grid=grid, inside_lens=inside)

    @property
    def bev_grid(self) -> BevGrid:
        return self.params.bev_grid

    def with_tables(self, *, frustum: np.ndarray | None = None, source: str = "checkpoint") -> PinholeLSSGeometry:
        """Same rig with another frustum (e.g. the checkpoint's); the plan is rebuilt only if it changed."""
        new = self.frustum if frustum is None else np.ascontiguousarray(frustum, dtype=np.float32)
        plan = self.plan
        if not np.array_equal(new, self.frustum):
            plan = build_pooling_plan(view_points(new, self.views), self.bev_grid, self.plan.bucket_sizes)
        return replace(self, frustum=new, plan=plan, source=source)

    def front_end_tables(self) -> dict[str, np.ndarray]:
        """The taps that make the views from the raw images (`front_end_tables`)."""
        p = self.params
        return front_end_tables(p.views, p.source_size, p.image_size, self.image_grid)

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The named ``geom.*`` tables of the graph (no weights needed)."""
        return {**self.front_end_tables(), **pool_tables(self.plan)}
