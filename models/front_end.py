"""The image front ends of the pinhole baselines: what turns raw camera images into the views the backbone sees.

Both run on raw pixel values, before normalisation, as the official pipelines do:

- `resized_views`: PIL's bicubic resize and the crop of pinhole images (``geom.resize.*``,
  exact to Pillow's uint8 output, [`resize`][fisheye_infer.models.resize]);
- `perspective_views`: cv2.remap's perspective rectification of fisheye images
  (``geom.rectify.*``, exact to cv2's output), ``len(yaws)`` views per camera, truncated to uint8
  where the official pipeline casts them.

Frames of another size than the configured one (the synthetic checkpoints' BatchNorm calibration
runs smaller ones) are resampled to the configured views all the same: the resize straight to the
view size, the rectification with GridSample's taps of the same grid.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from fisheye_infer.geometry.resize import pil_bicubic_taps
from fisheye_infer.geometry.tables import RECTIFY, RESIZE_X, RESIZE_Y

from .cylindrical import rectify
from .resample import taps_for
from .resize import Tables, pil_resize

__all__ = ["resized_views", "perspective_views"]


def _tables(tables: Mapping[str, torch.Tensor], prefix: str) -> Tables:
    return tables[f"{prefix}index"], tables[f"{prefix}high"], tables[f"{prefix}low"]


def _computed(in_size: int, out_size: int, device: torch.device) -> Tables:
    blocks = pil_bicubic_taps(in_size, out_size).blocks()
    arrays = (blocks.index, blocks.high, blocks.low)
    index, high, low = (torch.from_numpy(np.ascontiguousarray(a)).to(device) for a in arrays)
    return index, high, low


def resized_views(
    images: torch.Tensor, tables: Mapping[str, torch.Tensor], source_hw: tuple[int, int], view_hw: tuple[int, int]
) -> torch.Tensor:
    """uint8 B x N x H x W x 3 -> float32 B x N x h x w x 3 (uint8 values): PIL's resize and the crop, one
    view per camera."""
    h, w = images.shape[2], images.shape[3]
    if (h, w) == tuple(source_hw):
        horizontal, vertical = _tables(tables, RESIZE_X), _tables(tables, RESIZE_Y)
    else:
        horizontal, vertical = _computed(w, view_hw[1], images.device), _computed(h, view_hw[0], images.device)
    return pil_resize(images, horizontal, vertical, view_hw)


def perspective_views(
    images: torch.Tensor,
    tables: Mapping[str, torch.Tensor],
    image_grid: np.ndarray,
    source_hw: tuple[int, int],
    yaws: int,
    view_hw: tuple[int, int],
    truncate: bool,
) -> torch.Tensor:
    """uint8 B x N x H x W x 3 -> float32 B x N x Y x 3 x h x w: cv2.remap's views, camera by camera, yaw by yaw.

    ``image_grid`` holds each camera's (Y * h, w, 2) remap grid of its stacked yaws; ``truncate`` floors the
    views (the official ``ImageAug3D``'s uint8 cast).
    """
    b, n = images.shape[0], images.shape[1]
    h, w = view_hw
    index, weight = taps_for(tables, RECTIFY, image_grid, source_hw, images.shape[2:4], images.device)
    x = rectify(images, index, weight, (yaws * h, w))  # B x N x 3 x (Y h) x w
    x = x.reshape(b, n, 3, yaws, h, w).transpose(2, 3)
    return torch.floor(x) if truncate else x
