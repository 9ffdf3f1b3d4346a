"""fisheye-bevdet-cyl's geometry: the image rectification grid, the cylindrical frustum, the pooling plan.

The cylindrical baseline rectifies the raw fisheye images onto a cylinder before the backbone
(``geom.rectify.*``), so its stride-16 features already sit on the cylinder grid: no feature
warp, and the frustum lies on cylinders whose radius is the depth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.frustum import cylindrical_frustum, frustum_to_lidar, linspace_depth_bins
from fisheye_infer.geometry.grids import cells_inside_lens, cylindrical_image_grid, fisheye_lenses, per_camera
from fisheye_infer.geometry.lss import LSSParams
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.geometry.tables import RECTIFY, CylParams, pool_tables, sampling_tables

__all__ = ["CylLSSParams", "CylLSSGeometry", "cyl_image_grid"]


class CylLSSParams(LSSParams, CylParams):
    """fisheye-bevdet-cyl: image rectification, then LSS on the stride-16 features (no feature warp).

    LSS's parameters and the cylinder's; depth bins are ``linspace`` over ``dbound`` (see
    `linspace_depth_bins`) and depth is the cylinder radius.
    """

    kind: Literal["cyl_lss"] = "cyl_lss"  # type: ignore[assignment]

    def frustum(self) -> np.ndarray:
        """(D, H, W, 3) float32 camera-frame points: linspace depths times rays of unit cylinder radius."""
        return cylindrical_frustum(
            linspace_depth_bins(self.dbound), self.feature_size, self.azimuth_range, self.height_range
        )


def cyl_image_grid(rig: Rig, params: CylParams) -> np.ndarray:
    """(N, Hi, Wi, 2) float32 GridSample grids rectifying each camera's raw fisheye images onto the cylinder."""
    return per_camera(
        rig, lambda lens: cylindrical_image_grid(lens, params.image_size, params.azimuth_range, params.height_range)
    )


@dataclass(frozen=True)
class CylLSSGeometry:
    """Geometry tables of the cylindrical LSS model for one rig and configuration."""

    params: CylLSSParams
    image_grid: np.ndarray  # N x Hc x Wc x 2 float32, GridSample coordinates of each camera's raw fisheye image
    frustum: np.ndarray  # D x H x W x 3 float32, camera frame, depth = cylinder radius
    cam2lidar: np.ndarray  # N x 4 x 4 float64
    plan: PoolingPlan
    source: str = "rig"  # where the frustum came from: "rig" or "checkpoint"
    #: (N, H, W) bool, each camera's cylindrical feature cells that show its fisheye lens (``cells_inside_lens``).
    inside_lens: np.ndarray | None = None

    @classmethod
    def from_rig(cls, rig: Rig, params: CylLSSParams) -> CylLSSGeometry:
        """The rig's tables (each camera's lens model and extrinsics)."""
        frustum = np.ascontiguousarray(params.frustum(), dtype=np.float32)
        cam2lidar = np.asarray(rig.cam2lidar(), dtype=np.float64)
        plan = build_pooling_plan(frustum_to_lidar(frustum, cam2lidar), params.bev_grid, params.bucket_sizes)
        grid = cyl_image_grid(rig, params)
        inside = np.concatenate(
            [cells_inside_lens(lens, g, 1, params.feature_size) for lens, g in zip(fisheye_lenses(rig), grid)]
        )
        return cls(params=params, image_grid=grid, frustum=frustum, cam2lidar=cam2lidar, plan=plan, inside_lens=inside)

    @property
    def bev_grid(self) -> BevGrid:
        return self.params.bev_grid

    def with_tables(self, *, frustum: np.ndarray | None = None, source: str = "checkpoint") -> CylLSSGeometry:
        """Same rig with another frustum (e.g. the checkpoint's); the plan is rebuilt only if it changed."""
        new = self.frustum if frustum is None else np.ascontiguousarray(frustum, dtype=np.float32)
        plan = self.plan
        if not np.array_equal(new, self.frustum):
            plan = build_pooling_plan(frustum_to_lidar(new, self.cam2lidar), self.bev_grid, self.plan.bucket_sizes)
        return replace(self, frustum=new, plan=plan, source=source)

    def sampling_tables(self) -> dict[str, np.ndarray]:
        """The image rectification's taps (``geom.rectify.*``) on the ``source_size`` raw images."""
        return sampling_tables(RECTIFY, self.image_grid, self.params.source_size)

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The named ``geom.*`` tables of the graph (no weights needed)."""
        return {**self.sampling_tables(), **pool_tables(self.plan)}
