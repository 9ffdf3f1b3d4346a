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

__all__ = ["rectify", "check_rig_image_size"]


def rectify(images: torch.Tensor, index: torch.Tensor, weight: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """uint8 (or float) B x N x H x W x 3 fisheye images -> B x N x 3 x Hc x Wc (``size``) raw pixels,
    in the weights' dtype.

    ``index`` / ``weight`` are the cameras' taps on their H x W images, camera-major (each camera its own
    lens; [`resample`][fisheye_infer.models.resample]'s layout). Here each channel is one plane of every
    camera's pixels in each sample, each tap is gathered from it (GatherElements), the taps are weighed (Mul) and
    summed (a MatMul by a row of ones); the taps are turned tap-major from the tables, which the runtime does once
    when it loads the graph. With three values a row, the layout ``resample`` uses for features costs ONNX Runtime
    several times as much (a batched MatMul of one 1 x 4 by 4 x 3 product per output pixel). The weights are float32,
    or float64 in the export check's float64 reference model.
    """
    b, n, h, w, c = images.shape
    pixels = weight.shape[0]
    planes = images.to(weight.dtype).reshape(b, n * h * w, c).transpose(1, 2)  # B x 3 x NHW
    tap_major = index.reshape(pixels, 4).transpose(0, 1).reshape(1, 4 * pixels)
    taps = tap_major + index.new_zeros((b, 1))  # B x 4P: an Add, which ONNX Runtime runs on its threads
    tap_weight = weight.reshape(pixels, 4).transpose(0, 1)  # 4 x P
    ones = weight.new_ones(1, 4)
    sums = [
        torch.matmul(ones, torch.gather(planes[:, i], 1, taps).reshape(b, 4, pixels) * tap_weight) for i in range(c)
    ]  # each B x 1 x P
    out = torch.cat(sums, 1).reshape(b, c, n, *size)
    return out.transpose(1, 2)  # B x N x 3 x Hc x Wc


def check_rig_image_size(rig: Any, height: int, width: int, field: str) -> None:
    """The rectification grids are in the rig cameras' pixels: refuse input images of another size."""
    for cam in rig.cameras:
        if (cam.model.height, cam.model.width) != (height, width):
            raise ConfigError(
                f"{field}: the configuration expects {height}x{width} fisheye images, but camera '{cam.name}' "
                f"is {cam.model.height}x{cam.model.width}"
            )
