"""Image-level cylindrical rectification, shared by the cylindrical baselines.

The official pipelines resample every raw fisheye image onto a cylinder with ``cv2.remap``
(INTER_LINEAR, BORDER_CONSTANT 0) *before* mean/std normalisation, on float32 pixels. Here it is
one bilinear resampling (``grid_sample``'s bilinear, zeros, ``align_corners=True``) with the
constant grid of [`cylindrical_image_grid`][fisheye_infer.geometry.grids.cylindrical_image_grid], which emulates cv2's
1/32-pixel rounding of the maps, run as the grid's taps ``geom.rectify.*`` (`resample`), so
an exported graph takes raw uint8 fisheye images.
Out-of-image taps read 0, as in cv2; after normalisation those pixels are ``-mean / std``.
"""

from __future__ import annotations

from typing import Any

import torch

from fisheye_infer.errors import ConfigError

from .resample import camera_images, sample_rows

__all__ = ["rectify", "check_rig_image_size"]


def rectify(images: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """uint8 (or float) B x N x H x W x 3 fisheye images -> B x N x 3 x Hc x Wc (``size``) raw pixels,
    in the weights' dtype.

    ``index`` / ``weight`` are the cameras' taps on their H x W images, camera-major (each camera its own
    lens): each output pixel of camera n reads four pixels of that camera's three channels in every
    sample, one row of the channels-last images. The weights are float32, or float64 in the export
    check's float64 reference model.
    """
    b, n, h, w, c = images.shape
    x = images.to(weight.dtype)
    rows = torch.cat([x[:, i].permute(1, 2, 0, 3).reshape(h * w, b * c) for i in range(n)])  # NHW x B3
    return camera_images(sample_rows(rows, index, weight), b, size)  # B x N x 3 x Hc x Wc


def check_rig_image_size(rig: Any, height: int, width: int, field: str) -> None:
    """The rectification grids are in the rig cameras' pixels: refuse input images of another size."""
    for cam in rig.cameras:
        if (cam.model.height, cam.model.width) != (height, width):
            raise ConfigError(
                f"{field}: the configuration expects {height}x{width} fisheye images, but camera '{cam.name}' "
                f"is {cam.model.height}x{cam.model.width}"
            )
