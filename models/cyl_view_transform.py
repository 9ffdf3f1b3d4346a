"""Cylindrical LSS view transform: no feature warp, depth and context on P3, the same BEV mean pool.

``CylindricalLSS`` is :class:`~.view_transform.FisheyeLSS` with the warp removed: the images were
rectified onto the cylinder before the backbone, so the stride-16 features already sit on the
cylinder grid. Its geometry (``CylLSSGeometry``) holds every table of the graph, computed by
:mod:`fisheye_infer.geometry.tables`: the image rectification grid ``geom.image_grid`` (read by the
model before the backbone) and the pooling plan ``geom.pool.*`` of the cylindrical frustum.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.frustum import frustum_to_lidar
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.geometry.tables import CylLSSParams, cyl_image_grid, cyl_lss_frustum, cyl_lss_plan, cyl_lss_tables_from

from .view_transform import FisheyeLSS, _buffer_name

__all__ = ["CylLSSGeometry", "CylindricalLSS"]


@dataclass(frozen=True)
class CylLSSGeometry:
    """Geometry tables of the cylindrical LSS model for one rig and configuration."""

    params: CylLSSParams
    image_grid: np.ndarray  # Hc x Wc x 2 float32, GridSample coordinates of the raw fisheye image
    frustum: np.ndarray  # D x H x W x 3 float32, camera frame, depth = cylinder radius
    cam2lidar: np.ndarray  # N x 4 x 4 float64
    plan: PoolingPlan
    source: str = "rig"  # where the frustum came from: "rig" or "checkpoint"

    @classmethod
    def from_rig(cls, rig: Any, params: CylLSSParams, *, frustum: np.ndarray | None = None,
                 source: str = "rig") -> "CylLSSGeometry":
        """The rig's tables (shared camera model + extrinsics); ``frustum`` overrides the recomputed one."""
        frustum = np.ascontiguousarray(cyl_lss_frustum(params) if frustum is None else frustum, dtype=np.float32)
        return cls(params=params, image_grid=cyl_image_grid(rig, params), frustum=frustum,
                   cam2lidar=np.asarray(rig.cam2lidar(), dtype=np.float64),
                   plan=cyl_lss_plan(rig, params, frustum), source=source)

    @property
    def bev_grid(self) -> BevGrid:
        return self.params.bev_grid

    def with_tables(self, *, frustum: np.ndarray | None = None, source: str = "checkpoint") -> "CylLSSGeometry":
        """Same rig with another frustum (e.g. the checkpoint's); the plan is rebuilt only if it changed."""
        new = self.frustum if frustum is None else np.ascontiguousarray(frustum, dtype=np.float32)
        plan = self.plan
        if not np.array_equal(new, self.frustum):
            plan = build_pooling_plan(frustum_to_lidar(new, self.cam2lidar), self.bev_grid, self.plan.bucket_sizes)
        return replace(self, frustum=new, plan=plan, source=source)

    def tables(self) -> dict[str, np.ndarray]:
        """The named ``geom.*`` tables of the graph (layout: fisheye_infer.geometry.tables)."""
        return cyl_lss_tables_from(self.image_grid, self.plan)


class CylindricalLSS(FisheyeLSS):
    """Lift-splat on cylinder-aligned features with a constant pooling plan (``geom.pool.*``).

    Built as ``CylindricalLSS(cfg: CylViewTransformConfig, geometry: CylLSSGeometry)``. It also
    keeps ``geom.image_grid`` among its tables, so the model's ``geometry_tables()`` is this
    module's ``tables()``, as for FisheyeBEVDet.
    """

    def set_geometry(self, geometry: CylLSSGeometry) -> None:  # type: ignore[override]
        """Install the tables as non-persistent buffers (they are not checkpoint keys of this model)."""
        h, w = self.cfg.feature_size
        d = self.num_depth
        if geometry.frustum.shape != (d, h, w, 3):
            raise ConfigError(f"view transform frustum is {geometry.frustum.shape}, configuration needs ({d}, {h}, {w}, 3)")
        if tuple(geometry.plan.grid_xy) != self.cfg.bev_shape:
            raise ConfigError(f"pooling plan grid {geometry.plan.grid_xy} differs from the configuration's {self.cfg.bev_shape}")
        if geometry.image_grid.ndim != 3 or geometry.image_grid.shape[-1] != 2:
            raise ConfigError(f"image rectification grid is {geometry.image_grid.shape}, expected (H, W, 2)")
        for name in self._table_names:
            delattr(self, _buffer_name(name))
        tables = geometry.tables()
        for name, value in tables.items():
            self.register_buffer(_buffer_name(name), torch.from_numpy(np.ascontiguousarray(value)), persistent=False)
        self._table_names = tuple(tables)
        self._num_buckets = len(geometry.plan.bucket_points)
        self.geometry = geometry  # type: ignore[assignment]

    def warp(self, feat: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """No feature warp: M x C x H x W features of the rectified images are already on the cylinder."""
        h, w = self.cfg.feature_size
        if tuple(feat.shape[-2:]) != (h, w):
            raise ConfigError(f"image features are {tuple(feat.shape[-2:])}, the cylindrical frustum needs ({h}, {w}): "
                              "the rectified images do not have the configured cylinder size")
        return feat
