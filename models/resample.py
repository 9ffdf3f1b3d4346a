"""Bilinear resampling with a constant grid, as the graph runs it: gathers and one batched MatMul.

The tables are :func:`fisheye_infer.geometry.grids.bilinear_taps` of the grid (``geom.warp.*``,
``geom.rectify.*``): four source pixels and four weights per output pixel. The source is laid
out channels-last, one row per source pixel, so each tap gathers one contiguous row of all
cameras' channels; the weighted sum of the four rows is a (1 x 4) @ (4 x K) product per output
pixel. The result is GridSample's (bilinear, zero padding, ``align_corners=True``) up to float
rounding, and ONNX Runtime runs these gathers, transposes and MatMul in less time than its
GridSample kernel on the models' warps.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import torch

from fisheye_infer.geometry.grids import bilinear_taps
from fisheye_infer.geometry.tables import taps_index, taps_weight

__all__ = ["sample_rows", "resample", "taps_for"]


def sample_rows(rows: torch.Tensor, index: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """(S, K) source rows -> (P, K): row p is ``sum_k weight[p, 0, k] * rows[index[4 p + k]]``."""
    taps = torch.index_select(rows, 0, index).reshape(weight.shape[0], 4, rows.shape[1])  # P x 4 x K
    return torch.matmul(weight.to(rows.dtype), taps).reshape(weight.shape[0], rows.shape[1])


def resample(x: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """M x C x h x w -> M x C x H x W (``size``), every channel of every sample with the same taps."""
    m, c, h, w = x.shape
    rows = x.reshape(m * c, h * w).transpose(0, 1)  # hw x MC
    return sample_rows(rows, index, weight).transpose(0, 1).reshape(m, c, *size)


def taps_for(
    tables: Mapping[str, torch.Tensor],
    prefix: str,
    grid: np.ndarray,
    source_size: tuple[int, int] | None,
    source_hw: Sequence[int],
    device: torch.device,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The taps (index, weight) that resample a ``source_hw`` source with ``grid``.

    The tables (``prefix`` + index / weight) are built for ``source_size``, the configured input;
    a source of another size (eager use on smaller frames, as the synthetic checkpoints' BatchNorm
    calibration does) gets :func:`bilinear_taps` of the same grid for its own size, which is what
    GridSample's normalised coordinates would sample.
    """
    if tuple(source_hw) == tuple(source_size or ()):
        return tables[taps_index(prefix)], tables[taps_weight(prefix)]
    taps = bilinear_taps(grid, *source_hw)
    return torch.from_numpy(taps.index).to(device), torch.from_numpy(taps.weight).to(device)
