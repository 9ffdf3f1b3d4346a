"""Pillow's BICUBIC resize of uint8 images inside the graph, equal to Pillow bit for bit.

The arithmetic is [`apply_taps_float32`][fisheye_infer.geometry.resize.apply_taps_float32]: Pillow's 22-bit
integer coefficients split into an 11-bit high and low part, so that every product and partial
sum is an integer below 2**24 and float32 evaluates it exactly, followed by the rounding offset
and two exact divisions by 2048 with Floor (Pillow's arithmetic shift). It traces to Gather
(``index_select``), Mul, Add, Div, Floor and Clip only: float32 throughout, no float64 and no
integer MatMul, so TensorRT runs it as written. The tables come from
[`fisheye_infer.geometry.resize.pil_bicubic_taps`][fisheye_infer.geometry.resize.pil_bicubic_taps].

Each tap gathers only the ``out`` positions it needs: gathering all T * out positions at once
would hold a T times larger tensor (about 370 MB for six 1280x720 cameras).
"""

from __future__ import annotations

import torch

__all__ = ["resize_axis", "pil_resize"]

_HALF = float(1 << 21)  # Pillow's rounding offset, 2**(22 - 1)
_SPLIT = 2048.0  # coefficient = high * 2048 + low


def _along(row: torch.Tensor, x: torch.Tensor, dim: int) -> torch.Tensor:
    """A (out,) weight row shaped to broadcast along dimension ``dim`` of ``x`` (no size of ``x`` is read,
    so the batch axis stays symbolic in the exported graph)."""
    return row.reshape([row.shape[0]] + [1] * (x.dim() - dim - 1))


def resize_axis(x: torch.Tensor, index: torch.Tensor, high: torch.Tensor, low: torch.Tensor, dim: int) -> torch.Tensor:
    """One Pillow 8-bit pass along ``dim`` of a float32 tensor of uint8 values; (T, out) tables.

    ``Sh = sum_t x[index_t] * high_t`` and ``Sl = sum_t x[index_t] * low_t`` are exact integers in
    float32; ``floor((Sh + floor((Sl + 2**21) / 2048)) / 2048)`` is then Pillow's
    ``(2**21 + sum x * k) >> 22``, clipped to [0, 255] as Pillow's lookup does.
    """
    dim = dim % x.dim()
    sh: torch.Tensor | None = None
    sl: torch.Tensor | None = None
    for t in range(index.shape[0]):
        gathered = torch.index_select(x, dim, index[t])
        h = gathered * _along(high[t], x, dim)
        l = gathered * _along(low[t], x, dim)
        sh = h if sh is None else sh + h
        sl = l if sl is None else sl + l
    assert sh is not None and sl is not None, "a resize needs at least one tap"
    bq = torch.floor((sl + _HALF) / _SPLIT)
    q = torch.floor((sh + bq) / _SPLIT)
    return torch.clamp(q, 0.0, 255.0)


def pil_resize(
    images: torch.Tensor,
    horizontal: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    vertical: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
) -> torch.Tensor:
    """B x N x H x W x 3 float32 (uint8 values) -> B x N x h x w x 3, Pillow's BICUBIC resize.

    ``horizontal`` and ``vertical`` are the (index, high, low) tables of the two axes; a crop is
    the vertical tables of the kept rows only. The horizontal pass runs first and its result is
    rounded as Pillow rounds its uint8 intermediate image, which is part of the output. That is
    Pillow's order before version 13, and Pillow 13's wherever
    [`pil_horizontal_first`][fisheye_infer.geometry.resize.pil_horizontal_first] holds (1280x720 -> 800x450 included).
    """
    columns_first = images.permute(
        3, 0, 1, 2, 4
    )  # W x B x N x H x 3: each tap gathers whole blocks, not 3-value pixels
    rows = resize_axis(columns_first, *horizontal, dim=0).permute(1, 2, 3, 0, 4)
    return resize_axis(rows, *vertical, dim=2)
