"""The calibration-dependent constants of an exported graph, by their stable names.

An exported model holds every table that depends on the rig as a named initializer
(``geom.*``). The PyTorch models are built from these same tables, and ``rebake`` recomputes
them for a new rig with numpy only. The parameters that define the tables travel in the
model's metadata, so a file carries everything needed to re-bake it.

LSS (FisheyeBEVDet), for N cameras, an H x W angular grid and an X x Y BEV grid:
    geom.grid                 (1, H, W, 2)  float32  grid_sample coordinates, shared by the cameras
    geom.pool.counts          (1, X*Y, 1)   float32  points per BEV cell, at least 1 (mean divisor)
    geom.pool.cell_rows       (X*Y,)        int64    row of each cell in the bucket outputs (+ zero row)
    geom.pool.points.<b>      (K_b, L_b)    int64    flat point indices of bucket b, padded with P
    geom.pool.pixels.<b>      (K_b, L_b)    int64    flat context rows of bucket b
The bucket ladder (L_b) is fixed by the parameters and the graph is exported with K_b
symbolic, so every rig yields the same graph; only the tables' contents and K_b change.

PETR (FisheyePETR):
    geom.grid                 (1, H, W, 2)  float32
    geom.petr.key_pos         (1, N*H*W, C) float32  key position embedding (needs the weights)
    geom.petr.key_mask        (1, N*H*W)    bool     keys ignored by attention
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.geometry.frustum import depth_bins, frustum_to_lidar, spherical_frustum
from fisheye_infer.geometry.grids import invalid_mask, spherical_grid
from fisheye_infer.geometry.petr import lid_depths, position_coords, sine_position_encoding
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.rig import Rig

__all__ = [
    "DEFAULT_BUCKET_SIZES",
    "LSSParams",
    "PETRParams",
    "GeometryParams",
    "lss_plan",
    "lss_tables",
    "lss_tables_from",
    "petr_mask",
    "petr_coords",
    "petr_key_pos",
    "petr_tables",
]

#: 1, 2, 4, ... 4096 points per BEV cell: room for any rig of the Fisheye3DOD kind (the default
#: rig's fullest cell holds 501), so a re-baked file keeps the graph of the original.
DEFAULT_BUCKET_SIZES = tuple(2**i for i in range(13))


class _Params(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    feature_size: tuple[int, int]
    azimuth_range: tuple[float, float]
    elevation_range: tuple[float, float]


class LSSParams(_Params):
    kind: Literal["lss"] = "lss"
    dbound: tuple[float, float, float]
    xbound: tuple[float, float, float]
    ybound: tuple[float, float, float]
    zbound: tuple[float, float, float]
    bucket_sizes: tuple[int, ...] = DEFAULT_BUCKET_SIZES

    @property
    def bev_grid(self) -> BevGrid:
        return BevGrid(self.xbound, self.ybound, self.zbound)


class PETRParams(_Params):
    kind: Literal["petr"] = "petr"
    depth_num: int
    depth_start: float
    position_range: tuple[float, float, float, float, float, float]
    num_feats: int = 128
    temperature: float = 10000.0


GeometryParams = LSSParams | PETRParams


def lss_plan(rig: Rig, params: LSSParams, frustum: np.ndarray | None = None) -> PoolingPlan:
    """The pooling plan of ``rig``; ``frustum`` (D, H, W, 3) overrides the recomputed one."""
    if frustum is None:
        frustum = spherical_frustum(depth_bins(params.dbound), params.feature_size, params.azimuth_range, params.elevation_range)
    return build_pooling_plan(frustum_to_lidar(frustum, rig.cam2lidar()), params.bev_grid, params.bucket_sizes)


def lss_tables(rig: Rig, params: LSSParams, grid: np.ndarray | None = None, frustum: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every ``geom.*`` table of an LSS graph; ``grid``/``frustum`` override the rig's (checkpoint values)."""
    if grid is None:
        grid = spherical_grid(rig.shared_model(), params.feature_size, params.azimuth_range, params.elevation_range)
    return lss_tables_from(grid, lss_plan(rig, params, frustum))


def lss_tables_from(grid: np.ndarray, plan: PoolingPlan) -> dict[str, np.ndarray]:
    """The named tables of a sampling grid (H, W, 2) and a pooling plan: the one definition of their layout."""
    tables = {
        "geom.grid": np.ascontiguousarray(grid, np.float32)[None],
        "geom.pool.counts": np.maximum(plan.counts, 1.0).astype(np.float32)[None, :, None],
        "geom.pool.cell_rows": plan.cell_rows.astype(np.int64),
    }
    for b, (points, pixels) in enumerate(zip(plan.bucket_points, plan.bucket_pixels)):
        tables[f"geom.pool.points.{b}"] = points.astype(np.int64)
        tables[f"geom.pool.pixels.{b}"] = pixels.astype(np.int64)
    return tables


def petr_mask(rig: Rig, params: PETRParams, grid: np.ndarray | None = None) -> np.ndarray:
    """(H, W) float32 ``unvalid_area``: a key is ignored where it is not exactly 0."""
    camera = rig.shared_model()
    if grid is None:
        grid = spherical_grid(camera, params.feature_size, params.azimuth_range, params.elevation_range)
    return invalid_mask(camera, grid)


def petr_coords(rig: Rig, params: PETRParams) -> np.ndarray:
    """(N, 3 * depth_num, H, W) float32 inputs of the position encoder."""
    depths = lid_depths(params.depth_num, params.depth_start, params.position_range[3])
    return position_coords(rig.cam2lidar(), params.feature_size, params.azimuth_range, params.elevation_range, depths, params.position_range)


def _conv_mlp(x: np.ndarray, w1: np.ndarray, b1: np.ndarray, w2: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Conv1x1 -> ReLU -> Conv1x1 over (N, Cin, H, W), in float64, as matrix products."""
    hidden = np.maximum(np.einsum("oc,nchw->nohw", w1.reshape(w1.shape[0], -1), x) + b1[None, :, None, None], 0.0)
    return np.einsum("oc,nchw->nohw", w2.reshape(w2.shape[0], -1), hidden) + b2[None, :, None, None]


def petr_key_pos(coords: np.ndarray, mask: np.ndarray, weights: dict[str, np.ndarray], params: PETRParams) -> np.ndarray:
    """(1, N*H*W, C) key embedding: position_encoder(coords) + adapt_pos3d(sine(mask)).

    ``weights`` holds ``position_encoder.{0,2}.{weight,bias}`` and ``adapt_pos3d.{0,2}.{weight,bias}``.
    """
    n = coords.shape[0]
    key_mask = np.broadcast_to(np.asarray(mask) != 0, (n, *mask.shape[-2:]))
    sine = sine_position_encoding(key_mask, params.num_feats, params.temperature)
    w = {k: np.asarray(v, np.float64) for k, v in weights.items()}
    pe = _conv_mlp(coords.astype(np.float64), w["position_encoder.0.weight"], w["position_encoder.0.bias"], w["position_encoder.2.weight"], w["position_encoder.2.bias"])
    pe = pe + _conv_mlp(sine.astype(np.float64), w["adapt_pos3d.0.weight"], w["adapt_pos3d.0.bias"], w["adapt_pos3d.2.weight"], w["adapt_pos3d.2.bias"])
    return pe.transpose(0, 2, 3, 1).reshape(1, -1, pe.shape[1]).astype(np.float32)


def petr_tables(rig: Rig, params: PETRParams, weights: dict[str, np.ndarray], grid: np.ndarray | None = None, mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every ``geom.*`` table of a PETR graph; ``grid``/``mask`` override the rig's (checkpoint values)."""
    if grid is None:
        grid = spherical_grid(rig.shared_model(), params.feature_size, params.azimuth_range, params.elevation_range)
    if mask is None:
        mask = petr_mask(rig, params, grid)
    mask = np.asarray(mask, np.float32).reshape(params.feature_size)
    n = len(rig)
    return {
        "geom.grid": np.ascontiguousarray(grid, np.float32)[None],
        "geom.petr.key_pos": petr_key_pos(petr_coords(rig, params), mask, weights, params),
        "geom.petr.key_mask": np.broadcast_to(mask != 0, (n, *params.feature_size)).reshape(1, -1).copy(),
    }
