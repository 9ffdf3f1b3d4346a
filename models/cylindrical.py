"""Image-level cylindrical rectification, shared by the cylindrical baselines.

The official pipelines resample every raw fisheye image onto a cylinder with ``cv2.remap``
(INTER_LINEAR, BORDER_CONSTANT 0) *before* mean/std normalisation, on float32 pixels. Here it is
one bilinear resampling (``grid_sample``'s bilinear, zeros, ``align_corners=True``) with the
constant grid of :func:`fisheye_infer.geometry.grids.cylindrical_image_grid`, which emulates cv2's
1/32-pixel rounding of the maps, run as the grid's taps ``geom.rectify.*`` (:mod:`.resample`), so
an exported graph takes raw uint8 fisheye images.
Out-of-image taps read 0, as in cv2; after normalisation those pixels are ``-mean / std``.
"""

from __future__ import annotations

from typing import Any

import torch

from fisheye_infer.errors import ConfigError

from .resample import sample_rows

__all__ = ["rectify", "check_rig_image_size"]


def rectify(images: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """uint8 (or float) B x N x H x W x 3 fisheye images -> B x N x 3 x Hc x Wc (``size``) raw pixels,
    in the weights' dtype.

    ``index`` / ``weight`` are the taps of the grid on an H x W image, shared by the cameras (one
    intrinsic model): each output pixel reads the same four pixels of every camera's three
    channels, one row of the channels-last images. The weights are float32, or float64 in the
    export check's float64 reference model.
    """
    b, n, h, w, c = images.shape
    rows = images.to(weight.dtype).permute(2, 3, 0, 1, 4).reshape(h * w, b * n * c)  # HW x 3BN
    out = sample_rows(rows, index, weight)  # HcWc x 3BN
    return out.reshape(*size, b, n, c).permute(2, 3, 4, 0, 1)  # B x N x 3 x Hc x Wc


def check_rig_image_size(rig: Any, height: int, width: int, field: str) -> None:
    """The rectification grid is in the rig camera's pixels: refuse input images of another size."""
    camera = rig.shared_model()
    if (camera.height, camera.width) != (height, width):
        raise ConfigError(
            f"{field}: the configuration expects {height}x{width} fisheye images, but the rig's "
            f"camera model is {camera.height}x{camera.width}"
        )
