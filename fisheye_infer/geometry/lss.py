"""FisheyeBEVDet's geometry: the equirectangular warp grid, the frustum and the BEV pooling plan.

params = LSSParams(feature_size=(25, 100), azimuth_range=..., elevation_range=..., dbound=..., xbound=..., ...)
geometry = LSSGeometry.from_rig(rig, params)          # the rig's tables
geometry.with_tables(grid=stored_grid)                 # a checkpoint's stored grid (its first camera's lens)
geometry.with_lenses(recalibrated_rig)                 # the same poses, other lens models
geometry.tables()                                      # {"geom.warp.*": ..., "geom.pool.*": ...}
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.frustum import depth_bins, frustum_to_lidar, spherical_frustum
from fisheye_infer.geometry.grids import require_poses, spherical_lens_grids, stored_for_first_lens
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.geometry.tables import DEFAULT_BUCKET_SIZES, WARP, Params, pool_tables, sampling_tables

__all__ = ["LSSParams", "LSSGeometry"]


class LSSParams(Params):
    kind: Literal["lss"] = "lss"
    dbound: tuple[float, float, float]
    xbound: tuple[float, float, float]
    ybound: tuple[float, float, float]
    zbound: tuple[float, float, float]
    bucket_sizes: tuple[int, ...] = DEFAULT_BUCKET_SIZES

    @property
    def bev_grid(self) -> BevGrid:
        return BevGrid(self.xbound, self.ybound, self.zbound)

    def frustum(self) -> np.ndarray:
        """(D, H, W, 3) float32 camera-frame points: the ``arange`` depths along the equirectangular rays."""
        return spherical_frustum(depth_bins(self.dbound), self.feature_size, self.azimuth_range, self.elevation_range)


@dataclass(frozen=True)
class LSSGeometry:
    """Geometry tables of the fisheye LSS transform for one rig and configuration."""

    params: LSSParams
    grid: np.ndarray  # N x H x W x 2 float32, each camera's grid_sample coordinates
    frustum: np.ndarray  # D x H x W x 3 float32, camera frame, radial depth
    cam2lidar: np.ndarray  # N x 4 x 4 float64
    plan: PoolingPlan
    valid_fov_mask: np.ndarray  # N x 1 x H x W float32, each lens's sampled validity (unused by the forward)
    source: str = "rig"  # where grid/frustum came from: "rig" or "checkpoint"

    @classmethod
    def from_rig(cls, rig: Rig, params: LSSParams) -> LSSGeometry:
        """The rig's tables: each camera's lens model and its extrinsics, in rig order."""
        grid, valid = cls._lens_tables(rig, params)
        frustum = np.ascontiguousarray(params.frustum(), np.float32)
        cam2lidar = np.asarray(rig.cam2lidar(), dtype=np.float64)
        plan = build_pooling_plan(frustum_to_lidar(frustum, cam2lidar), params.bev_grid, params.bucket_sizes)
        return cls(params=params, grid=grid, frustum=frustum, cam2lidar=cam2lidar, plan=plan, valid_fov_mask=valid)

    @staticmethod
    def _lens_tables(rig: Rig, params: LSSParams) -> tuple[np.ndarray, np.ndarray]:
        grid, outside = spherical_lens_grids(rig, params.feature_size, params.azimuth_range, params.elevation_range)
        return grid, (1.0 - outside)[:, None]

    def with_lenses(self, rig: Rig) -> LSSGeometry:
        """The same extrinsics, frustum and pooling plan with ``rig``'s lens models: the grid and mask of cameras
        calibrated anew (a lens centre moved), without rebuilding the plan the lenses do not change."""
        require_poses(rig, self.cam2lidar, "LSSGeometry.from_rig, with the pooling plan of those poses,")
        grid, valid = self._lens_tables(rig, self.params)
        return replace(self, grid=grid, valid_fov_mask=valid, source="rig")

    def lens_tables(self) -> dict[str, np.ndarray]:
        """The tables a change of lens calibration replaces (a training step's moved lenses): the warp's taps."""
        return self.sampling_tables()

    @property
    def bev_grid(self) -> BevGrid:
        return self.params.bev_grid

    @property
    def inside_lens(self) -> np.ndarray:
        """(N, H, W) bool: each camera's cells that mostly sample its lens's field of view (``valid_fov_mask``)."""
        return self.valid_fov_mask[:, 0] > 0.5

    def with_tables(
        self, *, grid: np.ndarray | None = None, frustum: np.ndarray | None = None, source: str = "checkpoint"
    ) -> LSSGeometry:
        """Same rig with a checkpoint's grid (H, W, 2) (`stored_for_first_lens`) and/or frustum; the pooling
        plan is rebuilt only if the frustum changed."""
        new_grid = self.grid if grid is None else stored_for_first_lens(self.grid, grid)
        new_frustum = self.frustum if frustum is None else np.ascontiguousarray(frustum, dtype=np.float32)
        plan = self.plan
        if not np.array_equal(new_frustum, self.frustum):
            plan = build_pooling_plan(
                frustum_to_lidar(new_frustum, self.cam2lidar), self.bev_grid, self.plan.bucket_sizes
            )
        return replace(self, grid=new_grid, frustum=new_frustum, plan=plan, source=source)

    def sampling_tables(self) -> dict[str, np.ndarray]:
        """The feature warp's taps (``geom.warp.*``) on the ``source_size`` image features."""
        return sampling_tables(WARP, self.grid, self.params.source_size)

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """The named ``geom.*`` tables of the graph (no weights needed)."""
        return {**self.sampling_tables(), **pool_tables(self.plan)}
