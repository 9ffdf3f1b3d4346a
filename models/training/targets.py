"""Training targets of the TransFusion head: the Gaussian heatmap and the 8-number box code.

Both follow the official head (``TransFusionHead.get_targets_single``, ``TransFusionBBoxCoder.encode``):

- heatmap: one K x X x Y map per frame, rows x (forward), columns y, as the head's dense heatmap.
  Each box draws a Gaussian of radius ``max(min_radius, int(gaussian_radius((w_cells, l_cells),
  gaussian_overlap)))`` (sigma = diameter / 6) at the integer cell of its centre into its class's
  map, keeping the maximum where Gaussians overlap; the peak cell is exactly 1.
- box code: ``(cx, cy)`` in BEV cells, gravity-centre z, ``log l, log w, log h``, ``sin yaw, cos yaw``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..bevdet_config import HeadConfig

__all__ = ["HeadGrid", "gaussian_radius", "gaussian_2d", "draw_gaussian", "heatmap_target", "encode_boxes", "CODE_SIZE"]

CODE_SIZE = 8


@dataclass(frozen=True)
class HeadGrid:
    """Where the head's cells lie: ``bev_size`` (X, Y) cells of ``cell`` (m, m) from ``pc_range`` (x0, y0)."""

    bev_size: tuple[int, int]
    cell: tuple[float, float]
    pc_range: tuple[float, float]

    @classmethod
    def from_head(cls, head: HeadConfig) -> HeadGrid:
        """From a ``HeadConfig``: a cell is out_size_factor x voxel_size metres."""
        osf = float(head.out_size_factor)
        vx, vy = head.voxel_size
        x0, y0 = head.pc_range
        return cls(head.bev_size, (osf * vx, osf * vy), (float(x0), float(y0)))

    @property
    def span(self) -> tuple[float, float]:
        return (self.bev_size[0] * self.cell[0], self.bev_size[1] * self.cell[1])


def gaussian_radius(size: tuple[float, float], min_overlap: float) -> float:
    """CenterNet's radius (mmdet3d variant, roots halved): the smallest of three corner-shift cases
    such that a box shifted by the radius still overlaps the true one by ``min_overlap``."""
    height, width = size
    b1 = height + width
    c1 = width * height * (1 - min_overlap) / (1 + min_overlap)
    r1 = (b1 + math.sqrt(b1**2 - 4 * c1)) / 2
    b2 = 2 * (height + width)
    c2 = (1 - min_overlap) * width * height
    r2 = (b2 + math.sqrt(b2**2 - 16 * c2)) / 2
    a3 = 4 * min_overlap
    b3 = -2 * min_overlap * (height + width)
    c3 = (min_overlap - 1) * width * height
    r3 = (b3 + math.sqrt(b3**2 - 4 * a3 * c3)) / 2
    return min(r1, r2, r3)


def gaussian_2d(radius: int) -> np.ndarray:
    """(2r+1, 2r+1) Gaussian with sigma = (2r+1)/6, peak 1, values below eps * peak set to 0."""
    d = 2 * radius + 1
    sigma = d / 6
    y, x = np.ogrid[-radius : radius + 1, -radius : radius + 1]
    g = np.exp(-(x * x + y * y) / (2 * sigma * sigma))
    g[g < np.finfo(g.dtype).eps * g.max()] = 0
    return g


def draw_gaussian(heatmap: np.ndarray, row: int, col: int, radius: int) -> None:
    """Max-blend a Gaussian of ``radius`` centred at (row, col) into ``heatmap`` (R x C), in place,
    clipped at the border.

    A centre outside the map draws nothing."""
    rows, cols = heatmap.shape
    if not (0 <= row < rows and 0 <= col < cols):
        return
    g = gaussian_2d(radius)
    top, bottom = min(row, radius), min(rows - row, radius + 1)
    left, right = min(col, radius), min(cols - col, radius + 1)
    patch = heatmap[row - top : row + bottom, col - left : col + right]
    np.maximum(patch, g[radius - top : radius + bottom, radius - left : radius + right], out=patch)


def heatmap_target(
    boxes: np.ndarray,
    labels: np.ndarray,
    grid: HeadGrid,
    num_classes: int,
    gaussian_overlap: float = 0.1,
    min_radius: int = 2,
) -> np.ndarray:
    """Runtime boxes (M, 7) and class ids (M,) -> float32 K x X x Y target heatmap.

    A box whose centre lies outside the grid draws nothing (the official pipeline's
    ObjectRangeFilter removes such boxes before this step).
    """
    boxes = np.asarray(boxes, np.float64).reshape(-1, 7)
    labels = np.asarray(labels, np.int64).reshape(-1)
    if len(boxes) != len(labels):
        raise ValueError(f"boxes and labels: {len(boxes)} boxes but {len(labels)} labels")
    if len(labels) and (labels.min() < 0 or labels.max() >= num_classes):
        raise ValueError(f"labels: expected class ids in [0, {num_classes}), got {sorted(set(labels.tolist()))}")
    heat = np.zeros((num_classes, *grid.bev_size), np.float32)
    for box, label in zip(boxes, labels):
        l_cells, w_cells = box[3] / grid.cell[0], box[4] / grid.cell[1]
        if not (l_cells > 0 and w_cells > 0):
            continue
        radius = max(int(min_radius), int(gaussian_radius((w_cells, l_cells), gaussian_overlap)))
        row = int((box[0] - grid.pc_range[0]) / grid.cell[0])  # truncation towards zero, as the official int cast
        col = int((box[1] - grid.pc_range[1]) / grid.cell[1])
        draw_gaussian(heat[label], row, col, radius)
    return heat


def encode_boxes(boxes: np.ndarray, grid: HeadGrid) -> np.ndarray:
    """Runtime boxes (M, 7) -> (M, 8) code: cx, cy (cells), z_gravity, log l, log w, log h, sin yaw, cos yaw."""
    b = np.asarray(boxes, np.float64).reshape(-1, 7)
    if len(b) and not (b[:, 3:6] > 0).all():
        raise ValueError("boxes: sizes l, w, h must be positive to take their logarithm")
    code = np.empty((len(b), CODE_SIZE), np.float32)
    code[:, 0] = (b[:, 0] - grid.pc_range[0]) / grid.cell[0]
    code[:, 1] = (b[:, 1] - grid.pc_range[1]) / grid.cell[1]
    code[:, 2] = b[:, 2] + b[:, 5] / 2
    code[:, 3:6] = np.log(b[:, 3:6])
    code[:, 6], code[:, 7] = np.sin(b[:, 6]), np.cos(b[:, 6])
    return code
