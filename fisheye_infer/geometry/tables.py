"""The calibration-dependent constants of an exported graph: their names and layout, defined once.

An exported model holds every table that depends on the rig as a named initializer
(``geom.*``). The PyTorch models are built from these same tables, and ``rebake`` recomputes
them for a new rig with numpy only; both get them from one geometry object per parameter kind
(`lss`, `cyl_lss`, `petr`, `cyl_petr`, `pinhole_lss`, `pinhole_petr`;
[`kinds.tables_for`][fisheye_infer.geometry.kinds.tables_for]). The
parameters that define the tables travel in the model's metadata, so a file carries everything
needed to re-bake it.

Resampling with a constant grid (the feature warp, the image rectification) is stored as its
bilinear taps on the sampled source (``Params.source_size``): GridSample's
(`bilinear_taps`) for the warp, cv2.remap's
(`remap_taps`) for the rectification: the graph gathers four rows of the
channels-last source per output pixel and weighs them with one batched MatMul: GridSample's bilinear,
zero-padded, ``align_corners=True`` result, in less time than ONNX Runtime's GridSample kernel.

Every camera has its own taps (its own lens calibration), camera after camera: the source is laid out
camera-major, one row per pixel of each camera (`n * h * w + pixel`), so one graph serves a rig whose
cameras share a lens and one whose cameras each have their own.

LSS (FisheyeBEVDet), for `N` cameras, an `H x W` angular grid and an `X x Y` BEV grid:

| table | shape | type | holds |
|---|---|---|---|
| `geom.warp.index` | `(N*H*W*4,)` | int64 | flat source pixel of each tap, camera-major |
| `geom.warp.weight` | `(N*H*W, 1, 4)` | float32 | the taps' bilinear weights (0 outside the source) |
| `geom.pool.counts` | `(1, X*Y, 1)` | float32 | points per BEV cell, at least 1 (mean divisor) |
| `geom.pool.cell_rows` | `(X*Y,)` | int64 | row of each cell in the bucket outputs (+ zero row) |
| `geom.pool.points.<b>` | `(K_b, L_b)` | int64 | flat point indices of bucket `b`, padded with `P` |
| `geom.pool.pixels.<b>` | `(K_b, L_b)` | int64 | flat context rows of bucket `b` |

The bucket ladder (`L_b`) is fixed by the parameters and the graph is exported with `K_b`
symbolic, so every rig yields the same graph; only the tables' contents and `K_b` change.

PETR (FisheyePETR): `geom.warp.index` and `geom.warp.weight` as above, and

| table | shape | type | holds |
|---|---|---|---|
| `geom.petr.key_pos` | `(1, N*H*W, C)` | float32 | key position embedding (needs the weights) |
| `geom.petr.key_mask` | `(1, N*H*W)` | bool | keys ignored by attention |

The cylindrical baselines rectify the raw fisheye images instead of their features, so their
graphs take the taps of the image grid (cv2.remap emulation) and no `geom.warp.*`:

| table | shape | type | holds |
|---|---|---|---|
| `geom.rectify.index` | `(N*Hi*Wi*4,)` | int64 | flat raw-image pixel of each tap, camera-major |
| `geom.rectify.weight` | `(N*Hi*Wi, 1, 4)` | float32 | the taps' weights |

Cylindrical LSS (fisheye-bevdet-cyl): `geom.rectify.*` and the `geom.pool.*` tables above.
Cylindrical PETR (fisheye-petr-cyl): `geom.rectify.*`, `geom.petr.key_pos` and `geom.petr.key_mask`
(all False: the official head masks no key).

The pinhole baselines (standard LSS) take raw camera images too; their front end makes the
views the backbone sees (`views`), for `T` views of `Hv x Wv`:

| table | shape | type | holds |
|---|---|---|---|
| `geom.resize.x.index` | `(G, L)` | int64 | PIL bicubic resize and crop: the columns a block of outputs reads |
| `geom.resize.x.high`, `.low` | `(G, S, L)` | float32 | a block's integer weights in two exact halves (`resize`) |
| `geom.resize.y.*` | `(G, S, L)` | | the same for rows |

or `geom.rectify.*` of the perspective views (fisheye input, each camera's views stacked by yaw); then `geom.pool.*`
(pinhole LSS, pinhole-bevdet / fisheye-bevdet-persp) or `geom.petr.key_pos` and `geom.petr.key_mask` (all
False; pinhole PETR, pinhole-petr / fisheye-petr-persp).

A file re-baked onto another rig's cameras also holds `geom.virtual.*`, its front end's resampling
([`virtual`][fisheye_infer.geometry.virtual]).

The cylindrical ranges are used as given: `azimuth_range` / `elevation_range` hold the
official `horizontal_range` / `vertical_range` as the code reads them, in radians, and the
cylinder's heights are their tangents. The released configs write degrees (`[-110, 110]`,
`[-45, 45]`) that their code uses as radians; those numbers reproduce the released geometry.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import BilinearTaps, bilinear_taps, remap_taps
from fisheye_infer.geometry.pooling import PoolingPlan
from fisheye_infer.geometry.resize import ResizeBlocks

__all__ = [
    "PREFIX",
    "WARP",
    "RECTIFY",
    "RESIZE_X",
    "RESIZE_Y",
    "resize_tables",
    "taps_index",
    "taps_weight",
    "POOL_PREFIX",
    "POOL_COUNTS",
    "POOL_CELL_ROWS",
    "POOL_POINTS",
    "POOL_PIXELS",
    "PETR_KEY_POS",
    "PETR_KEY_MASK",
    "DEFAULT_BUCKET_SIZES",
    "pool_points",
    "pool_pixels",
    "pool_tables",
    "camera_taps",
    "sampling_tables",
    "key_tables",
    "key_mask_table",
]

PREFIX = "geom."
WARP = "geom.warp."  # the feature warp's taps: + "index" / "weight"
RECTIFY = "geom.rectify."  # the image rectification's taps (cylinder, perspective views)
RESIZE_X = "geom.resize.x."  # PIL's bicubic resize and crop of pinhole images, columns: + "index" / "high" / "low"
RESIZE_Y = "geom.resize.y."  # the same for rows
POOL_PREFIX = "geom.pool."
POOL_COUNTS = "geom.pool.counts"
POOL_CELL_ROWS = "geom.pool.cell_rows"
POOL_POINTS = "geom.pool.points."  # + bucket index
POOL_PIXELS = "geom.pool.pixels."  # + bucket index
PETR_KEY_POS = "geom.petr.key_pos"
PETR_KEY_MASK = "geom.petr.key_mask"

#: 1, 2, 4, ... 4096 points per BEV cell: room for any rig of the Fisheye3DOD kind (the default
#: rig's fullest cell holds 501), so a re-baked file keeps the graph of the original.
DEFAULT_BUCKET_SIZES = tuple(2**i for i in range(13))


def pool_points(bucket: int) -> str:
    return f"{POOL_POINTS}{bucket}"


def pool_pixels(bucket: int) -> str:
    return f"{POOL_PIXELS}{bucket}"


def taps_index(prefix: str) -> str:
    return f"{prefix}index"


def taps_weight(prefix: str) -> str:
    return f"{prefix}weight"


def camera_taps(grids: np.ndarray, height: int, width: int, prefix: str = WARP) -> BilinearTaps:
    """The taps of each camera's grid, ``grids`` (N, H, W, 2), on its own ``height`` x ``width`` source, stacked
    camera after camera with camera n's source pixels offset by ``n * height * width`` (the camera-major layout).

    ``RECTIFY``: cv2.remap's exact taps of [`remap_grid`][fisheye_infer.geometry.grids.remap_grid] grids (the official
    image rectification); otherwise GridSample's (the official feature warp).
    """
    g = np.asarray(grids)
    if g.ndim != 4 or g.shape[-1] != 2:
        raise ConfigError(f"grids: expected one (H, W, 2) grid per camera, (N, H, W, 2), got {g.shape}")
    taps_of = remap_taps if prefix == RECTIFY else bilinear_taps
    taps = [taps_of(grid, height, width) for grid in g]
    return BilinearTaps(
        index=np.concatenate([t.index + n * height * width for n, t in enumerate(taps)]),
        weight=np.concatenate([t.weight for t in taps]),
    )


def sampling_tables(prefix: str, grids: np.ndarray, source_size: tuple[int, int] | None) -> dict[str, np.ndarray]:
    """The taps of the cameras' ``grids`` (N, H, W, 2) on ``source_size`` (H, W) sources as the tables ``prefix``
    (`camera_taps`)."""
    if source_size is None:
        raise ConfigError(
            "geometry parameters: source_size is missing (files exported before the sampling taps held a "
            "GridSample grid instead); export the checkpoint again to get tables for it"
        )
    taps = camera_taps(grids, *source_size, prefix=prefix)
    return {taps_index(prefix): taps.index, taps_weight(prefix): taps.weight}


def resize_tables(prefix: str, blocks: ResizeBlocks) -> dict[str, np.ndarray]:
    """One axis of PIL's resize ([`ResizeBlocks`][fisheye_infer.geometry.resize.ResizeBlocks]) as the tables
    ``prefix``."""
    return {
        f"{prefix}index": blocks.index.astype(np.int64),
        f"{prefix}high": blocks.high.astype(np.float32),
        f"{prefix}low": blocks.low.astype(np.float32),
    }


def pool_tables(plan: PoolingPlan) -> dict[str, np.ndarray]:
    """The ``geom.pool.*`` tables of a pooling plan, shared by the LSS graphs."""
    tables = {
        POOL_COUNTS: np.maximum(plan.counts, 1.0).astype(np.float32)[None, :, None],
        POOL_CELL_ROWS: plan.cell_rows.astype(np.int64),
    }
    for b, (points, pixels) in enumerate(zip(plan.bucket_points, plan.bucket_pixels)):
        tables[pool_points(b)] = points.astype(np.int64)
        tables[pool_pixels(b)] = pixels.astype(np.int64)
    return tables


def key_tables(key_pos: np.ndarray, key_mask: np.ndarray) -> dict[str, np.ndarray]:
    """PETR's key embedding (1, N*H*W, C) float32 and key mask (N, H, W) bool as their tables."""
    return {PETR_KEY_POS: key_pos, PETR_KEY_MASK: key_mask_table(key_mask)}


def key_mask_table(key_mask: np.ndarray) -> np.ndarray:
    """PETR's key mask (N, H, W) bool as its table (1, N*H*W)."""
    return np.asarray(key_mask, bool).reshape(1, -1).copy()


class Params(BaseModel):
    """What every parameter kind shares: the key/feature grid, its angular ranges and what it samples.

    ``source_size`` is the (H, W) of the tensor the grid resamples: the image features (feature
    warp) or the raw fisheye images (cylindrical rectification). Its taps depend on it.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    feature_size: tuple[int, int]
    azimuth_range: tuple[float, float]
    elevation_range: tuple[float, float]
    source_size: tuple[int, int] | None = None


class CylParams(Params):
    """Cylinder ranges as the official code reads them (radians) and the rectified image size."""

    image_size: tuple[int, int]  # (H, W) of the rectified cylindrical images

    @property
    def height_range(self) -> tuple[float, float]:
        """The cylinder's heights y = tan(elevation) at the two ends of ``elevation_range``."""
        e0, e1 = self.elevation_range
        return (math.tan(e0), math.tan(e1))
