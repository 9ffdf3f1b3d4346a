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

The cylindrical baselines rectify the raw fisheye images instead of their features, so their
graphs take ``geom.image_grid`` and no ``geom.grid``:
    geom.image_grid           (1, Hi, Wi, 2) float32 GridSample coordinates of the raw image
                                                     (cv2.remap emulation, align_corners=True)
Cylindrical LSS (fisheye-bevdet-cyl): geom.image_grid + the geom.pool.* tables above.
Cylindrical PETR (fisheye-petr-cyl): geom.image_grid + geom.petr.key_pos + geom.petr.key_mask
(all False: the official head masks no key).

The cylindrical ranges are used as given: ``azimuth_range`` / ``elevation_range`` hold the
official ``horizontal_range`` / ``vertical_range`` as the code reads them, in radians, and the
cylinder's heights are their tangents. The released configs write degrees (``[-110, 110]``,
``[-45, 45]``) that their code uses as radians; those numbers reproduce the released geometry.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.frustum import cylindrical_frustum, depth_bins, frustum_to_lidar, linspace_depth_bins, spherical_frustum
from fisheye_infer.geometry.grids import cylindrical_directions, cylindrical_image_grid, invalid_mask, spherical_grid
from fisheye_infer.geometry.petr import lid_depths, position_coords, sine_position_encoding
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan
from fisheye_infer.rig import Rig

__all__ = [
    "DEFAULT_BUCKET_SIZES",
    "LSSParams",
    "PETRParams",
    "CylLSSParams",
    "CylPETRParams",
    "GeometryParams",
    "lss_plan",
    "lss_tables",
    "lss_tables_from",
    "petr_mask",
    "petr_coords",
    "petr_key_pos",
    "petr_tables",
    "cyl_image_grid",
    "cyl_lss_frustum",
    "cyl_lss_plan",
    "cyl_lss_tables",
    "cyl_lss_tables_from",
    "cyl_petr_directions",
    "cyl_petr_coords",
    "cyl_petr_tables",
    "tables_for",
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


class _CylParams(_Params):
    """Cylinder ranges as the official code reads them (radians) and the rectified image size."""

    image_size: tuple[int, int]  # (H, W) of the rectified cylindrical images

    @property
    def height_range(self) -> tuple[float, float]:
        """The cylinder's heights y = tan(elevation) at the two ends of ``elevation_range``."""
        e0, e1 = self.elevation_range
        return (math.tan(e0), math.tan(e1))


class CylLSSParams(_CylParams):
    """fisheye-bevdet-cyl: image rectification, then LSS on the stride-16 features (no feature warp).

    Depth bins are ``linspace`` over ``dbound`` (see :func:`linspace_depth_bins`) and depth is the
    cylinder radius.
    """

    kind: Literal["cyl_lss"] = "cyl_lss"
    dbound: tuple[float, float, float]
    xbound: tuple[float, float, float]
    ybound: tuple[float, float, float]
    zbound: tuple[float, float, float]
    bucket_sizes: tuple[int, ...] = DEFAULT_BUCKET_SIZES

    @property
    def bev_grid(self) -> BevGrid:
        return BevGrid(self.xbound, self.ybound, self.zbound)


class CylPETRParams(_CylParams):
    """fisheye-petr-cyl: image rectification, PETR keys on the stride-16 features, no key mask.

    The key embedding's rays unpack the ranges swapped, as the official head does (see
    :func:`cyl_petr_directions`).
    """

    kind: Literal["cyl_petr"] = "cyl_petr"
    depth_num: int
    depth_start: float
    position_range: tuple[float, float, float, float, float, float]
    num_feats: int = 128
    temperature: float = 10000.0


GeometryParams = LSSParams | PETRParams | CylLSSParams | CylPETRParams


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
    return {"geom.grid": np.ascontiguousarray(grid, np.float32)[None], **_pool_tables(plan)}


def _pool_tables(plan: PoolingPlan) -> dict[str, np.ndarray]:
    """The ``geom.pool.*`` tables of a pooling plan, shared by the LSS graphs."""
    tables = {
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


def petr_key_pos(coords: np.ndarray, mask: np.ndarray, weights: dict[str, np.ndarray], params: PETRParams | CylPETRParams) -> np.ndarray:
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


def cyl_image_grid(rig: Rig, params: CylLSSParams | CylPETRParams) -> np.ndarray:
    """(Hi, Wi, 2) float32 GridSample grid rectifying the rig's raw fisheye images onto the cylinder."""
    return cylindrical_image_grid(rig.shared_model(), params.image_size, params.azimuth_range, params.height_range)


def cyl_lss_frustum(params: CylLSSParams) -> np.ndarray:
    """(D, H, W, 3) float32 camera-frame points: linspace depths times rays of unit cylinder radius."""
    return cylindrical_frustum(linspace_depth_bins(params.dbound), params.feature_size, params.azimuth_range, params.height_range)


def cyl_lss_plan(rig: Rig, params: CylLSSParams, frustum: np.ndarray | None = None) -> PoolingPlan:
    """The pooling plan of ``rig``; ``frustum`` (D, H, W, 3) overrides the recomputed one."""
    if frustum is None:
        frustum = cyl_lss_frustum(params)
    return build_pooling_plan(frustum_to_lidar(frustum, rig.cam2lidar()), params.bev_grid, params.bucket_sizes)


def cyl_lss_tables(rig: Rig, params: CylLSSParams, image_grid: np.ndarray | None = None, frustum: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every ``geom.*`` table of a cylindrical LSS graph; ``image_grid``/``frustum`` override the rig's."""
    if image_grid is None:
        image_grid = cyl_image_grid(rig, params)
    return cyl_lss_tables_from(image_grid, cyl_lss_plan(rig, params, frustum))


def cyl_lss_tables_from(image_grid: np.ndarray, plan: PoolingPlan) -> dict[str, np.ndarray]:
    """The named tables of an image rectification grid (Hi, Wi, 2) and a pooling plan."""
    return {"geom.image_grid": np.ascontiguousarray(image_grid, np.float32)[None], **_pool_tables(plan)}


def cyl_petr_directions(params: CylPETRParams) -> np.ndarray:
    """(H, W, 3) rays of the cylindrical PETR keys, with the official head's swapped unpacking.

    The official ``CylindricalPETRHead`` reads ``h_max, h_min = horizontal_range`` and
    ``v_max, v_min = vertical_range`` and then linspaces from "min" to "max", so its azimuth runs
    from ``azimuth_range[1]`` to ``azimuth_range[0]`` and its height from
    tan(``elevation_range[1]``) to tan(``elevation_range[0]``): both axes reversed with respect to
    the rectified image (a half turn about the optical axis). The checkpoint was trained with it.
    """
    (a0, a1), (e0, e1) = params.azimuth_range, params.elevation_range
    return cylindrical_directions(params.feature_size, (a1, a0), (math.tan(e1), math.tan(e0)))


def cyl_petr_coords(rig: Rig, params: CylPETRParams) -> np.ndarray:
    """(N, 3 * depth_num, H, W) float32 inputs of the position encoder, on the swapped cylinder rays."""
    depths = lid_depths(params.depth_num, params.depth_start, params.position_range[3])
    return position_coords(rig.cam2lidar(), params.feature_size, depths=depths, position_range=params.position_range,
                           directions=cyl_petr_directions(params))


def cyl_petr_tables(rig: Rig, params: CylPETRParams, weights: dict[str, np.ndarray], image_grid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Every ``geom.*`` table of a cylindrical PETR graph; ``image_grid`` overrides the rig's."""
    if image_grid is None:
        image_grid = cyl_image_grid(rig, params)
    n, (h, w) = len(rig), params.feature_size
    mask = np.zeros((h, w), np.float32)  # the official head masks no key
    return {
        "geom.image_grid": np.ascontiguousarray(image_grid, np.float32)[None],
        "geom.petr.key_pos": petr_key_pos(cyl_petr_coords(rig, params), mask, weights, params),
        "geom.petr.key_mask": np.zeros((1, n * h * w), dtype=bool),
    }


def tables_for(rig: Rig, params: GeometryParams, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """The ``geom.*`` tables of a graph described by ``params``, for ``rig`` (what re-baking computes)."""
    if isinstance(params, LSSParams):
        return lss_tables(rig, params)
    if isinstance(params, PETRParams):
        if weights is None:
            raise ValueError("PETR tables need the position-encoder weights")
        return petr_tables(rig, params, weights)
    if isinstance(params, CylLSSParams):
        return cyl_lss_tables(rig, params)
    if isinstance(params, CylPETRParams):
        if weights is None:
            raise ConfigError("weights: cylindrical PETR tables need the position-encoder and adapt_pos3d weights")
        return cyl_petr_tables(rig, params, weights)
    raise ValueError(f"no geometry tables for parameters of kind {getattr(params, 'kind', type(params).__name__)!r}")
