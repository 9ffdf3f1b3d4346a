"""Image-level cylindrical rectification, shared by the cylindrical baselines.

The official pipelines resample every raw fisheye image onto a cylinder with ``cv2.remap``
(INTER_LINEAR, BORDER_CONSTANT 0) *before* mean/std normalisation, on float32 pixels. Here it is
one ``grid_sample`` (bilinear, zeros, ``align_corners=True``) with the constant grid
``geom.image_grid`` of :func:`fisheye_infer.geometry.grids.cylindrical_image_grid`, which emulates
cv2's 1/32-pixel rounding of the maps, so an exported graph takes raw uint8 fisheye images.
Out-of-image taps read 0, as in cv2; after normalisation those pixels are ``-mean / std``.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F

from fisheye_infer.errors import ConfigError

__all__ = ["rectify", "check_rig_image_size"]


def rectify(images: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """uint8 (or float) B x N x H x W x 3 fisheye images -> B x N x 3 x Hc x Wc raw pixels, in the grid's dtype.

    ``grid`` is 1 x Hc x Wc x 2, shared by the cameras (one intrinsic model), so the cameras are
    stacked along channels and sampled with one grid per sample: channels are sampled
    independently, the numbers are those of a per-camera GridSample. The grid is float32, or
    float64 in the export check's float64 reference model.
    """
    b, n, h, w, c = images.shape
    x = images.to(grid.dtype).permute(0, 1, 4, 2, 3).reshape(b, n * c, h, w)  # B x 3N x H x W
    out = F.grid_sample(x, grid.expand(b, -1, -1, -1), mode="bilinear", padding_mode="zeros", align_corners=True)
    return out.reshape(b, n, c, grid.shape[1], grid.shape[2])  # B x N x 3 x Hc x Wc


def check_rig_image_size(rig: Any, height: int, width: int, field: str) -> None:
    """The rectification grid is in the rig camera's pixels: refuse input images of another size."""
    camera = rig.shared_model()
    if (camera.height, camera.width) != (height, width):
        raise ConfigError(f"{field}: the configuration expects {height}x{width} fisheye images, but the rig's "
                          f"camera model is {camera.height}x{camera.width}")
