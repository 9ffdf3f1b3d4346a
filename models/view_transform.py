"""Fisheye LSS view transform: warp to an angular grid, predict depth and context, pool into BEV.

All geometry comes from [`fisheye_infer.geometry`][fisheye_infer.geometry] (numpy, one source of truth: an
``LSSGeometry``; for the baselines without a feature warp a ``CylLSSGeometry`` or a
``PinholeLSSGeometry``); this module only holds
its tables as non-persistent buffers and does the tensor work:

1. ``warp``: the official ``grid_sample`` of the stride-16 features with the constant
   equirectangular grid (bilinear, zeros, ``align_corners=True`` although the grid is normalised
   with divisor W, as the official model does), run as the grid's precomputed bilinear taps
   ([`resample`][fisheye_infer.models.resample]);
2. ``depth_context``: a 1x1 ``depthnet``; softmax over the first D channels, raw context after;
3. ``pool``: mean pooling of depth x context into the BEV cells with the precomputed bucketed
   plan (Gather + batched MatMul; no scatter, no sort, no boolean indexing).

The official checkpoint's geometry keys (``frustum``, ``sphere_grid_3d``, ``sphere_grid_2d``,
``valid_fov_mask``, ``dx``, ``bx``, ``nx``) are not parameters here; the checkpoint loader compares
them with the recomputation and installs the chosen tables through `FisheyeLSS.set_geometry`.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.cyl_lss import CylLSSGeometry
from fisheye_infer.geometry.frustum import frustum_to_lidar
from fisheye_infer.geometry.lss import LSSGeometry
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry
from fisheye_infer.geometry.pooling import BevGrid, voxelise
from fisheye_infer.geometry.tables import POOL_CELL_ROWS, POOL_COUNTS, WARP, pool_pixels, pool_points

from .bevdet_config import ViewTransformConfig
from .resample import resample, taps_for
from .table_buffers import install_tables, installed_tables

#: The geometry objects an LSS view transform installs.
AnyLSSGeometry = LSSGeometry | CylLSSGeometry | PinholeLSSGeometry

__all__ = ["AnyLSSGeometry", "FisheyeLSS", "RectifiedLSS", "CylindricalLSS", "pool_reference_torch"]


def pool_reference_torch(
    depth: torch.Tensor, ctx: torch.Tensor, points_lidar: np.ndarray, bev_grid: BevGrid
) -> torch.Tensor:
    """Plain definition of mean pooling for one sample with ``index_add_`` (tests, dynamic rigs).

    depth: N x D x H x W, ctx: N x H x W x C, points_lidar: N x D x H x W x 3 -> C x X x Y.
    """
    cells, kept = voxelise(points_lidar, bev_grid)
    nx, ny, _ = bev_grid.nx
    channels = ctx.shape[-1]
    lifted = (depth.unsqueeze(-1) * ctx.unsqueeze(1)).reshape(-1, channels)  # P x C
    idx = torch.from_numpy(np.flatnonzero(kept)).to(depth.device)
    cell = torch.from_numpy(cells[kept]).to(depth.device)
    total = torch.zeros(nx * ny, channels, dtype=lifted.dtype, device=lifted.device)
    total.index_add_(0, cell, lifted.index_select(0, idx))
    counts = torch.zeros(nx * ny, dtype=lifted.dtype, device=lifted.device)
    counts.index_add_(0, cell, torch.ones_like(cell, dtype=lifted.dtype))
    bev = total / counts.clamp(min=1.0).unsqueeze(1)
    return bev.reshape(nx, ny, channels).permute(2, 0, 1)


class FisheyeLSS(nn.Module):
    """Lift-splat with a constant equirectangular grid and a constant pooling plan."""

    def __init__(self, cfg: ViewTransformConfig, geometry: AnyLSSGeometry) -> None:
        super().__init__()
        self.cfg = cfg
        self.in_channels, self.out_channels = cfg.in_channels, cfg.out_channels
        self.num_depth = cfg.num_depth_bins
        self.depthnet = nn.Conv2d(cfg.in_channels, self.num_depth + cfg.out_channels, 1)
        self._table_names: tuple[str, ...] = ()
        self._num_buckets = 0
        self.set_geometry(geometry)

    # -- geometry -----------------------------------------------------------------------

    def set_geometry(self, geometry: AnyLSSGeometry) -> None:
        """Install geometry tables as non-persistent buffers (they are not checkpoint keys of this model)."""
        self._check_geometry(geometry)
        if tuple(geometry.plan.grid_xy) != self.cfg.bev_shape:
            raise ConfigError(
                f"pooling plan grid {geometry.plan.grid_xy} differs from the configuration's {self.cfg.bev_shape}"
            )
        self._table_names = install_tables(self, geometry.tables(), self._table_names)
        self._num_buckets = len(geometry.plan.bucket_points)
        self.geometry = geometry

    def _check_geometry(self, geometry: AnyLSSGeometry) -> None:
        """Refuse tables whose shapes do not fit the configuration, naming the table."""
        h, w = self.cfg.feature_size
        d = self.num_depth
        if not isinstance(geometry, LSSGeometry) or geometry.grid.shape != (len(geometry.cam2lidar), h, w, 2):
            raise ConfigError(
                f"view transform grid is {getattr(geometry, 'grid', np.empty(0)).shape}, configuration needs "
                f"(cameras, {h}, {w}, 2): one grid per camera"
            )
        if geometry.frustum.shape != (d, h, w, 3):
            raise ConfigError(
                f"view transform frustum is {geometry.frustum.shape}, configuration needs ({d}, {h}, {w}, 3)"
            )

    def tables(self) -> dict[str, torch.Tensor]:
        """The installed ``geom.*`` tables as tensors (the buffers), by their graph names."""
        return installed_tables(self, self._table_names)

    @property
    def num_cameras(self) -> int:
        return self.geometry.plan.lift_shape[0]

    # -- stages -------------------------------------------------------------------------

    def warp(self, feat: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """B x N x C x Hf x Wf -> B x N x C x H x W with each camera's bilinear taps (``geom.warp.*``; see
        [`resample`][fisheye_infer.models.resample])."""
        g = self.geometry
        assert isinstance(g, LSSGeometry)  # _check_geometry installs nothing else; RectifiedLSS has no warp
        index, weight = taps_for(
            tables or self.tables(), WARP, g.grid, g.params.source_size, feat.shape[-2:], feat.device
        )
        return resample(feat, index, weight, self.cfg.feature_size)

    def depth_context(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """M x Cin x H x W -> depth probabilities M x D x H x W and context M x C x H x W."""
        y = self.depthnet(x)
        depth = torch.softmax(y[:, : self.num_depth], dim=1)
        ctx = y[:, self.num_depth : self.num_depth + self.out_channels]
        return depth, ctx

    def pool(
        self, depth: torch.Tensor, ctx: torch.Tensor, tables: dict[str, torch.Tensor] | None = None
    ) -> torch.Tensor:
        """Mean-pool depth (B x N x D x H x W) times ctx (B x N x H x W x C) into B x C x X x Y.

        Only Gather, MatMul and Concat; bucket sizes K_b come from the tables' shapes, so the same
        graph serves any rig (the exporter traces it with K_b symbolic). Gathers go through
        ``index_select`` on flattened indices: advanced indexing (``x[:, idx]``) would export as
        GatherND between Transposes of the lifted tensor, which cost more than the gathers.
        """
        tables = tables or self.tables()
        b, c = depth.shape[0], ctx.shape[-1]
        x_cells, y_cells = self.geometry.plan.grid_xy
        depth_flat = torch.cat([depth.reshape(b, -1), depth.new_zeros(b, 1)], dim=1)  # B x (P + 1)
        ctx_flat = ctx.reshape(b, -1, c)  # B x NHW x C
        rows = []
        for i in range(self._num_buckets):
            pts = tables[pool_points(i)]  # K x L
            pix = tables[pool_pixels(i)]  # K x L
            k, l = pts.shape
            w = depth_flat.index_select(1, pts.reshape(-1)).reshape(b, k, 1, l)
            f = ctx_flat.index_select(1, pix.reshape(-1)).reshape(b, k, l, c)
            rows.append(torch.matmul(w, f).reshape(b, k, c))
        rows.append(ctx_flat.new_zeros(b, 1, c))  # row for empty cells
        table = torch.cat(rows, dim=1)  # B x (sum K + 1) x C
        bev = table.index_select(1, tables[POOL_CELL_ROWS]) / tables[POOL_COUNTS]  # B x XY x C, counts >= 1
        return bev.reshape(b, x_cells, y_cells, c).permute(0, 3, 1, 2)

    def lift(
        self, feat: torch.Tensor, camera_valid: torch.Tensor | None, tables: dict[str, torch.Tensor] | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """B x N x Cin x Hf x Wf -> depth B x N x D x H x W and ctx B x N x H x W x C (masked cameras zeroed)."""
        b, n = feat.shape[0], feat.shape[1]
        x = self.warp(feat, tables)
        depth, ctx = self.depth_context(x.flatten(0, 1))
        h, w = depth.shape[-2:]
        depth = depth.reshape(b, n, self.num_depth, h, w)
        ctx = ctx.reshape(b, n, self.out_channels, h, w).permute(0, 1, 3, 4, 2)
        if camera_valid is not None:
            # A missing camera contributes zero features; cell counts stay those of the full rig,
            # so cells it shared with other cameras are diluted exactly as if it had seen nothing.
            ctx = ctx * camera_valid.to(ctx.dtype).reshape(b, n, 1, 1, 1)
        return depth, ctx

    def forward(
        self,
        feat: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """B x N x Cin x Hf x Wf image features -> B x C x X x Y BEV (rows x forward, columns y left).

        ``tables`` replaces the installed geometry tables (the exporter passes them as graph inputs).
        """
        if feat.shape[1] != self.num_cameras:
            raise ConfigError(f"view transform built for {self.num_cameras} cameras, got {feat.shape[1]}")
        tables = tables or self.tables()
        depth, ctx = self.lift(feat, camera_valid, tables)
        return self.pool(depth, ctx, tables)

    def forward_dynamic(
        self, feat: torch.Tensor, cam2lidar: torch.Tensor | np.ndarray, camera_valid: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Same as ``forward`` with per-sample extrinsics cam2lidar (B x N x 4 x 4); reference speed.

        The points are transformed by [`frustum_to_lidar`][fisheye_infer.geometry.frustum.frustum_to_lidar] and
        pooled with ``index_add_`` per sample; grid and frustum stay those of this module.
        """
        mats = cam2lidar.detach().cpu().numpy() if isinstance(cam2lidar, torch.Tensor) else np.asarray(cam2lidar)
        if mats.shape != (feat.shape[0], feat.shape[1], 4, 4):
            raise ConfigError(f"cam2lidar must be ({feat.shape[0]}, {feat.shape[1]}, 4, 4), got {mats.shape}")
        depth, ctx = self.lift(feat, camera_valid)
        out = []
        for i in range(feat.shape[0]):
            points = frustum_to_lidar(self.geometry.frustum, mats[i].astype(np.float64))
            out.append(pool_reference_torch(depth[i], ctx[i], points, self.geometry.bev_grid))
        return torch.stack(out)


class RectifiedLSS(FisheyeLSS):
    """Lift-splat on features that need no warp, with a constant pooling plan (``geom.pool.*``).

    `FisheyeLSS` with the warp removed: the images were resampled (onto a cylinder, into
    perspective views, or resized and cropped) before the backbone, so the stride-16 features
    already sit on the frustum's grid. It keeps the image front end's tables (``geom.rectify.*``
    or ``geom.resize.*``) among its own, read by the model before the backbone, so the model's
    ``geometry_tables()`` is this module's ``tables()``, as for FisheyeBEVDet.
    """

    def _check_geometry(self, geometry: AnyLSSGeometry) -> None:
        h, w = self.cfg.feature_size
        d = self.num_depth
        if geometry.frustum.shape != (d, h, w, 3):
            raise ConfigError(
                f"view transform frustum is {geometry.frustum.shape}, configuration needs ({d}, {h}, {w}, 3)"
            )

    def warp(self, feat: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """No feature warp: B x N x C x H x W features of the resampled images are already on the frustum's grid."""
        h, w = self.cfg.feature_size
        if tuple(feat.shape[-2:]) != (h, w):
            raise ConfigError(
                f"image features are {tuple(feat.shape[-2:])}, the frustum needs ({h}, {w}): "
                "the resampled images do not have the configured size"
            )
        return feat


class CylindricalLSS(RectifiedLSS):
    """`RectifiedLSS` on cylinder-rectified images (``CylindricalLSS(cfg: CylViewTransformConfig,
    geometry: CylLSSGeometry)``)."""

    def _check_geometry(self, geometry: AnyLSSGeometry) -> None:
        super()._check_geometry(geometry)
        if (
            not isinstance(geometry, CylLSSGeometry)
            or geometry.image_grid.ndim != 4
            or geometry.image_grid.shape[::3] != (len(geometry.cam2lidar), 2)
        ):
            raise ConfigError(
                f"image rectification grid is {getattr(geometry, 'image_grid', np.empty(0)).shape}, expected "
                "(cameras, H, W, 2): one grid per camera"
            )
