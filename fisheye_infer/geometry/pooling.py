"""BEV pooling plan: which frustum points fall in which BEV cell, for a fixed rig.

For a fixed rig every frustum point's BEV cell is a constant, so the data-dependent part of
LSS pooling (voxelise, drop, sort, segment-sum) can be computed once, here, and baked into the
model as index tables. The layout is the *bucketed gather* form: non-empty cells are grouped by
their point count rounded up to a bucket size; each bucket is a (cells x L) table of point
indices padded with a zero slot. Pooling is then only Gather and a batched MatMul, which runs
deterministically in ONNX Runtime at any thread count (ScatterND with add-reduction does not).

Voxelisation follows the official code: ``index = trunc((p - lower) / dx)``, so values in
(-1, 0) land in cell 0, and the z range kept is (-15, 5) for zbound (-5, 5, 10). Pooling is a
mean over the points of a cell.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["BevGrid", "PoolingPlan", "voxelise", "build_pooling_plan", "pool_bev", "pool_bev_reference"]


@dataclass(frozen=True)
class BevGrid:
    """A BEV grid from (lower, upper, step) bounds per axis, as mmdet3d configs give them."""

    xbound: tuple[float, float, float] = (-48.0, 48.0, 0.3)
    ybound: tuple[float, float, float] = (-48.0, 48.0, 0.3)
    zbound: tuple[float, float, float] = (-5.0, 5.0, 10.0)

    @property
    def dx(self) -> np.ndarray:
        """Cell size per axis, float32."""
        return np.array([b[2] for b in (self.xbound, self.ybound, self.zbound)], dtype=np.float32)

    @property
    def bx(self) -> np.ndarray:
        """Centre of the first cell per axis, float32."""
        return np.array([b[0] + b[2] / 2.0 for b in (self.xbound, self.ybound, self.zbound)], dtype=np.float32)

    @property
    def nx(self) -> tuple[int, int, int]:
        """Cell count per axis: int((upper - lower) / step), as the official ``gen_dx_bx``."""
        return tuple(int((b[1] - b[0]) / b[2]) for b in (self.xbound, self.ybound, self.zbound))  # type: ignore[return-value]

    @property
    def lower(self) -> np.ndarray:
        """Lower corner bx - dx / 2, float32."""
        return self.bx - self.dx / np.float32(2.0)


@dataclass(frozen=True)
class PoolingPlan:
    """Index tables for mean pooling of lifted features into a BEV grid.

    ``bucket_points[b]`` (K_b, L_b) holds flat point indices p = ((n*D + k)*H + h)*W + w, padded
    with ``num_points`` (a zero depth slot appended after the last point); ``bucket_pixels[b]``
    holds the matching context rows (n*H + h)*W + w. Concatenating the bucket outputs and one
    trailing zero row gives a table that ``cell_rows`` (X*Y,) indexes, cell i*Y + j.
    """

    lift_shape: tuple[int, int, int, int]  # N, D, H, W
    grid_xy: tuple[int, int]  # X, Y
    counts: np.ndarray  # (X*Y,) float32
    bucket_points: list[np.ndarray]
    bucket_pixels: list[np.ndarray]
    cell_rows: np.ndarray  # (X*Y,) int64
    bucket_sizes: tuple[int, ...] = field(default=())

    @property
    def num_points(self) -> int:
        n, d, h, w = self.lift_shape
        return n * d * h * w

    @property
    def num_kept(self) -> int:
        return int(self.counts.sum())

    @property
    def num_rows(self) -> int:
        return sum(len(b) for b in self.bucket_points)


def voxelise(points: np.ndarray, grid: BevGrid) -> tuple[np.ndarray, np.ndarray]:
    """Flat BEV cell (i*Y + j) of every point and whether it is kept, with trunc semantics.

    Returns ``cells`` (P,) int64 (meaningless where not kept) and ``kept`` (P,) bool.
    """
    p = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    v = (p - grid.lower) / grid.dx  # float32, as the official code divides
    n = np.array(grid.nx)
    kept = np.all((v > -1) & (v < n), axis=1)  # trunc toward zero == floor(max(v, 0)) for v > -1
    idx = np.floor(np.maximum(v, 0)).astype(np.int64)
    return idx[:, 0] * n[1] + idx[:, 1], kept


def _ladder(max_count: int) -> tuple[int, ...]:
    sizes, size = [], 1
    while True:
        sizes.append(size)
        if size >= max_count:
            return tuple(sizes)
        size *= 2


def build_pooling_plan(
    points_lidar: np.ndarray, grid: BevGrid, bucket_sizes: tuple[int, ...] | None = None
) -> PoolingPlan:
    """Plan for frustum points (N, D, H, W, 3) in the lidar frame.

    ``bucket_sizes`` fixes the bucket ladder (so that two rigs give tables of the same structure);
    by default it is 1, 2, 4, ... up to the largest cell's count. Every bucket is present, even
    when no cell falls in it: it then holds one row of padding that no cell reads (a bucket of
    zero rows would put zero-size tensors in the exported graph, which OpenVINO cannot shape).
    """
    pts = np.asarray(points_lidar)
    if pts.ndim != 5 or pts.shape[-1] != 3:
        raise ValueError(f"points_lidar: expected (N, D, H, W, 3), got {pts.shape}")
    if grid.nx[2] != 1:
        raise ValueError(f"BEV pooling supports one z cell, the grid has {grid.nx[2]} (zbound {grid.zbound})")
    n_cam, depth, height, width, _ = pts.shape
    num_points = n_cam * depth * height * width
    nx, ny, _ = grid.nx
    cells, kept = voxelise(pts, grid)
    point_ids = np.flatnonzero(kept)
    order = np.argsort(cells[point_ids], kind="stable")  # by cell, then ascending point index
    sorted_points = point_ids[order]
    counts = np.bincount(cells[point_ids], minlength=nx * ny)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])

    ladder = _ladder(int(counts.max(initial=1))) if bucket_sizes is None else tuple(sorted(bucket_sizes))
    if counts.max(initial=0) > ladder[-1]:
        raise ValueError(f"a BEV cell holds {counts.max()} points, more than the largest bucket ({ladder[-1]})")
    bucket_of_cell = np.searchsorted(np.asarray(ladder), counts)  # smallest L >= count

    bucket_points, bucket_pixels = [], []
    cell_rows = np.full(nx * ny, -1, dtype=np.int64)
    row = 0
    pixels_per_cam = height * width
    for b, size in enumerate(ladder):
        cells_b = np.flatnonzero((bucket_of_cell == b) & (counts > 0))
        slot = np.arange(size)
        filled = slot[None, :] < counts[cells_b, None]
        gather = np.where(filled, starts[cells_b, None] + slot[None, :], 0)
        pts_b = np.where(filled, sorted_points[gather] if len(sorted_points) else 0, num_points).astype(np.int64)
        pix_b = np.where(filled, (pts_b // (depth * pixels_per_cam)) * pixels_per_cam + pts_b % pixels_per_cam, 0)
        if len(cells_b) == 0:  # one all-padding row that no cell reads: no zero-size tensor in the graph
            pts_b, pix_b = np.full((1, size), num_points, np.int64), np.zeros((1, size), np.int64)
        bucket_points.append(pts_b)
        bucket_pixels.append(pix_b.astype(np.int64))
        cell_rows[cells_b] = row + np.arange(len(cells_b))
        row += len(pts_b)
    cell_rows[cell_rows < 0] = row  # the trailing zero row
    return PoolingPlan(
        lift_shape=(n_cam, depth, height, width),
        grid_xy=(nx, ny),
        counts=counts.astype(np.float32),
        bucket_points=bucket_points,
        bucket_pixels=bucket_pixels,
        cell_rows=cell_rows,
        bucket_sizes=ladder,
    )


def _check_features(depth: np.ndarray, ctx: np.ndarray, lift_shape: tuple[int, ...]) -> None:
    if depth.shape != tuple(lift_shape):
        raise ValueError(f"depth: expected {tuple(lift_shape)} (N, D, H, W), got {depth.shape}")
    n, _, h, w = lift_shape
    if ctx.ndim != 4 or ctx.shape[:3] != (n, h, w):
        raise ValueError(f"ctx: expected ({n}, {h}, {w}, C), got {ctx.shape}")


def pool_bev(depth: np.ndarray, ctx: np.ndarray, plan: PoolingPlan) -> np.ndarray:
    """Mean-pool the outer product depth x ctx into BEV (C, X, Y) with the bucketed plan.

    ``depth`` (N, D, H, W) are depth probabilities, ``ctx`` (N, H, W, C) context features.
    The (N, D, H, W, C) outer product is never formed.
    """
    _check_features(depth, ctx, plan.lift_shape)
    channels = ctx.shape[-1]
    weights = np.append(np.asarray(depth, dtype=np.float32).ravel(), np.float32(0.0))
    features = np.asarray(ctx, dtype=np.float32).reshape(-1, channels)
    rows = [
        np.einsum("kl,klc->kc", weights[pts], features[pix]) for pts, pix in zip(plan.bucket_points, plan.bucket_pixels)
    ]
    table = np.concatenate(rows + [np.zeros((1, channels), np.float32)])
    bev = table[plan.cell_rows] / np.maximum(plan.counts, 1.0)[:, None]
    return bev.reshape(*plan.grid_xy, channels).transpose(2, 0, 1)


def pool_bev_reference(depth: np.ndarray, ctx: np.ndarray, points_lidar: np.ndarray, grid: BevGrid) -> np.ndarray:
    """The straightforward definition: voxelise every point, ``np.add.at`` in float64, divide by counts."""
    n, d, h, w = depth.shape
    _check_features(depth, ctx, (n, d, h, w))
    cells, kept = voxelise(points_lidar, grid)
    lifted = (np.asarray(depth, np.float64)[..., None] * np.asarray(ctx, np.float64)[:, None]).reshape(
        -1, ctx.shape[-1]
    )
    nx, ny, _ = grid.nx
    total = np.zeros((nx * ny, ctx.shape[-1]))
    np.add.at(total, cells[kept], lifted[kept])
    counts = np.bincount(cells[kept], minlength=nx * ny)
    bev = total / np.maximum(counts, 1)[:, None]
    return bev.reshape(nx, ny, -1).transpose(2, 0, 1).astype(np.float32)
