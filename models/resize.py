"""Pillow's BICUBIC resize of uint8 images inside the graph, equal to Pillow bit for bit.

The arithmetic is [`apply_blocks_float32`][fisheye_infer.geometry.resize.apply_blocks_float32]: each
block of ``S`` outputs of an axis reads one window of ``L`` inputs, gathered as whole rows, and
multiplies it by the block's two coefficient matrices (Pillow's 22-bit integer coefficients split
into an 11-bit high and low part, divided by 2048), so that every product and partial sum is exact
in float32; the rounding offset and Pillow's arithmetic shift follow as exact Floor, Add, Mul, Add and
Floor, then Clip. A pass is one Gather, two batched MatMuls and six elementwise ops over its output: float32
throughout, no float64 and no integer MatMul, so TensorRT runs it as written. The tables come from
[`ResizeTaps.blocks`][fisheye_infer.geometry.resize.ResizeTaps.blocks].

The horizontal pass reads the columns as rows: each camera's image (H, W 3) is transposed to
(W 3, H), read as (W, 3 H), and its result back to (H, W' 3), so both passes gather contiguous rows
and run their MatMuls over long ones; camera by camera, each transpose stays within one image.
"""

from __future__ import annotations

import torch

__all__ = ["Tables", "resize_pass", "pil_resize"]

_OFFSET = 1024.0  # Pillow's rounding offset 2**21, in units of the low part's 2048
_UNIT = 1.0 / 2048.0  # coefficient = high * 2048 + low

Tables = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


def resize_pass(x: torch.Tensor, index: torch.Tensor, high: torch.Tensor, low: torch.Tensor, size: int) -> torch.Tensor:
    """One Pillow 8-bit pass along the second-to-last axis of ``x`` (float32 of uint8 values).

    Args:
        x: (..., in, R) float32.
        index: (G, L) int64 window of each block.
        high: (G, S, L) float32 high parts / 2048.
        low: (G, S, L) float32 low parts / 2048.
        size: The number of outputs (the last block may be padded).

    Returns:
        torch.Tensor: (..., size, R) float32, ``clip(floor(H + (floor(L) + 1024) / 2048), 0, 255)``.
    """
    axis = x.dim() - 2
    windows = x.index_select(axis, index.flatten()).unflatten(axis, index.shape)  # (..., G, L, R)
    h, l = torch.matmul(high, windows), torch.matmul(low, windows)  # (..., G, S, R)
    q = torch.clamp(torch.floor(h + (torch.floor(l) + _OFFSET) * _UNIT), 0.0, 255.0).flatten(axis, axis + 1)
    return q if q.shape[axis] == size else q.narrow(axis, 0, size)


def pil_resize(images: torch.Tensor, horizontal: Tables, vertical: Tables, size: tuple[int, int]) -> torch.Tensor:
    """B x N x H x W x 3 (uint8 values) -> float32 B x N x h x w x 3, Pillow's BICUBIC resize.

    ``horizontal`` and ``vertical`` are the (index, high, low) tables of the two axes; a crop is
    the vertical tables of the kept rows only. The horizontal pass runs first and its result is
    rounded as Pillow rounds its uint8 intermediate image, which is part of the output. That is
    Pillow's order before version 13, and Pillow 13's wherever
    [`pil_horizontal_first`][fisheye_infer.geometry.resize.pil_horizontal_first] holds (1280x720 -> 800x450 included).

    Args:
        images: B x N x H x W x 3, any dtype holding uint8 values.
        horizontal: The columns' (index, high, low) tables.
        vertical: The rows' (index, high, low) tables.
        size: (h, w) of the result.

    Returns:
        torch.Tensor: B x N x h x w x 3 of the tables' float type.
    """
    n, height, width, channels = images.shape[1:]
    h, w = size
    dtype = horizontal[1].dtype  # float32 in the graph, float64 when the model runs in double
    columns = images.to(dtype).reshape(-1, height, width * channels).transpose(1, 2)  # B N x W 3 x H
    resized = resize_pass(columns.reshape(-1, width, channels * height), *horizontal, size=w)  # B N x w x 3 H
    rows = resized.reshape(-1, w * channels, height).transpose(1, 2)  # B N x H x w 3
    return resize_pass(rows, *vertical, size=h).reshape(-1, n, h, w, channels)
