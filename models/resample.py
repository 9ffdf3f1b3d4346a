"""Bilinear resampling with constant grids, one per camera, as the graph runs it: gathers and one batched MatMul.

The tables are [`camera_taps`][fisheye_infer.geometry.tables.camera_taps] of the cameras' grids (``geom.warp.*``,
``geom.rectify.*``): four source pixels and four weights per output pixel of every camera. The source is
laid out camera-major and channels-last, one row per pixel of each camera (``n * h * w + pixel``) holding
that camera's channels of every sample, so each tap gathers one contiguous row and every camera reads its
own lens's taps; the weighted sum of the four rows is a (1 x 4) @ (4 x K) product per output pixel. The
result is GridSample's (bilinear, zero padding, ``align_corners=True``) per camera up to float rounding,
and ONNX Runtime runs these gathers, transposes and MatMul in less time than its GridSample kernel on the
models' feature warps. The rectification of raw images reads the same tables by channel planes instead
([`rectify`][fisheye_infer.models.cylindrical.rectify]): with three values a row, this layout's MatMul is one tiny
product per output pixel.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from fisheye_infer.geometry.tables import camera_taps, taps_index, taps_weight

__all__ = ["sample_rows", "camera_rows", "camera_images", "resample", "taps_for"]


def sample_rows(rows: torch.Tensor, index: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """(S, K) source rows -> (P, K): row p is ``sum_k weight[p, 0, k] * rows[index[4 p + k]]``."""
    taps = torch.index_select(rows, 0, index).reshape(weight.shape[0], 4, rows.shape[1])  # P x 4 x K
    return torch.matmul(weight.to(rows.dtype), taps).reshape(weight.shape[0], rows.shape[1])


def camera_rows(x: torch.Tensor) -> torch.Tensor:
    """B x N x C x h x w -> (N h w) x (B C): each camera's pixels as rows of its channels in every sample, camera
    after camera.

    One two-dimensional transpose per camera: ONNX Runtime runs these several times faster than one
    transpose of the whole tensor to the same layout.
    """
    b, n, c, h, w = x.shape
    return torch.cat([x[:, i].reshape(b * c, h * w).transpose(0, 1) for i in range(n)])


def camera_images(rows: torch.Tensor, batch: int, size: tuple[int, int]) -> torch.Tensor:
    """(N H W) x (B C) camera-major rows (``camera_rows``' layout) -> B x N x C x H x W (``size``)."""
    per_camera = rows.reshape(-1, size[0] * size[1], rows.shape[1])  # N x HW x BC
    channels = rows.shape[1] // batch
    return torch.stack([cam.transpose(0, 1).reshape(batch, channels, *size) for cam in per_camera.unbind(0)], 1)


def resample(x: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """B x N x C x h x w -> B x N x C x H x W (``size``): each camera's channels with that camera's taps."""
    return camera_images(sample_rows(camera_rows(x), index, weight), x.shape[0], size)


def taps_for(
    tables: Mapping[str, torch.Tensor],
    prefix: str,
    grids: np.ndarray,
    source_size: tuple[int, int] | None,
    source_hw: tuple[int, ...] | torch.Size,
    device: torch.device,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The taps (index, weight) that resample the cameras' ``source_hw`` sources with their ``grids`` (N, H, W, 2).

    The tables (``prefix`` + index / weight) are built for ``source_size``, the configured input;
    sources of another size (eager use on smaller frames, as the synthetic checkpoints' BatchNorm
    calibration does) get GridSample's taps of the same grids for their own size, which is what
    GridSample's normalised coordinates would sample.
    """
    if tuple(source_hw) == tuple(source_size or ()):
        return tables[taps_index(prefix)], tables[taps_weight(prefix)]
    taps = camera_taps(grids, *source_hw)
    return torch.from_numpy(taps.index).to(device), torch.from_numpy(taps.weight).to(device)
