"""Pillow's BICUBIC image resize, reproduced bit for bit so an exported graph can equal it.

The official BEVDet/PETR pinhole pipelines resize each uint8 RGB camera image with Pillow
(``Image.resize((800, 450))``, BICUBIC for RGB) before cropping it. Pillow does not evaluate the
bicubic kernel in floating point: it resamples in two passes (horizontal, then vertical on the
uint8 result of the first), each with integer coefficients of 22 fractional bits, a rounding
offset and an arithmetic shift. A float resize that is "close" differs from it by one grey level
on many pixels, which the trained weights never saw; equality needs the same integer arithmetic.
The pass order is part of the result: Pillow 13 runs the vertical pass first when the height
shrinks by more than twice as many pixels as the width (`pil_horizontal_first`); earlier
versions always start with the horizontal pass. Both orders agree on 1280x720 -> 800x450.

This module gives the per-axis coefficient tables (`pil_bicubic_taps`), the exact int64
evaluation of Pillow's two passes (`resize_reference`) and a float32 evaluation that is
exact by construction (`apply_blocks_float32`) on the graph's form of the tables
(`ResizeTaps.blocks`): the outputs of an axis in blocks of `RESIZE_BLOCK`, each block reading
one window of consecutive input positions, its coefficients a dense (block, window) matrix, so
that a pass is one gather of whole rows and one batched MatMul per coefficient part. Every
integer coefficient is split into a high and a low part of 11 bits (each divided by 2048) so
that every product and partial sum is an integer multiple of 2**-11 below 2**13, where float32
arithmetic has no rounding, in any summation order. That float32 form is the specification of
the graph's resize (``fisheye_infer.models.resize``), which must stay float32 (no float64, no
integer MatMul) to run on TensorRT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "PIL_PRECISION_BITS",
    "SPLIT_BITS",
    "FLOAT32_EXACT_LIMIT",
    "RESIZE_BLOCK",
    "ResizeTaps",
    "ResizeBlocks",
    "bicubic_kernel",
    "pil_bicubic_taps",
    "pil_horizontal_first",
    "resize_reference",
    "apply_blocks_float32",
]

PIL_PRECISION_BITS = 22  # Pillow's 32 - 8 - 2: 8 bits of result, 2 bits for the kernel's over- and undershoot
# k = high * 2**11 + low: T products of a pixel (< 2**8) and a part (<= 2**11) sum below 2**24 for T <= 32, and
# with Pillow's rounding offset 2**21 added, for T <= 28; apply_blocks_float32 checks the actual tables.
SPLIT_BITS = 11
FLOAT32_EXACT_LIMIT = 2**24  # every integer of smaller magnitude is a float32, so sums of them are exact
#: Output positions per block of the graph's tables (`ResizeTaps.blocks`).
RESIZE_BLOCK = 10

_SPLIT = 1 << SPLIT_BITS
_HALF = 1 << (PIL_PRECISION_BITS - 1)  # Pillow's rounding offset, added before the shift
_BICUBIC_A = -0.5
_BICUBIC_SUPPORT = 2.0


@dataclass(frozen=True)
class ResizeBlocks:
    """One axis of Pillow's resize in the graph's form: outputs in blocks, each block reading one window.

    ``index`` (G, L) holds the window of each block of ``RESIZE_BLOCK`` = S consecutive outputs: L
    consecutive input positions, clamped into the image (a clamped repeat weighs 0). ``high`` and
    ``low`` (G, S, L) are the block's coefficient matrices: Pillow's integer coefficient
    ``k = 2048 * h + l`` (``0 <= l < 2048``) of output ``g * S + s`` and input ``index[g, j]`` as
    ``h / 2048`` and ``l / 2048``, float32 and exact; 0 where the output does not read that input.
    The last block is padded with outputs of no coefficient: ``size`` is the real number of outputs.
    """

    index: np.ndarray  # (G, L) int64
    high: np.ndarray  # (G, S, L) float32, multiples of 1/2048 in [-1, 1]
    low: np.ndarray  # (G, S, L) float32, multiples of 1/2048 in [0, 1)
    size: int


@dataclass(frozen=True)
class ResizeTaps:
    """Pillow's 8-bit coefficients for one axis, tap by tap.

    Both arrays are (T, out), T = Pillow's ``ksize``. Taps beyond an output's support have
    coefficient 0 and an index clamped into ``[0, in_size)``.
    """

    index: np.ndarray  # (T, out) int64 input position of each tap
    coefficients: np.ndarray  # (T, out) int64, Pillow's fixed-point coefficient

    @property
    def taps(self) -> int:
        """T, the number of taps per output position (Pillow's ``ksize``)."""
        return int(self.index.shape[0])

    @property
    def size(self) -> int:
        """The number of output positions the tables cover."""
        return int(self.index.shape[1])

    def blocks(self, block: int = RESIZE_BLOCK) -> ResizeBlocks:
        """The same coefficients in the graph's form ([`ResizeBlocks`][fisheye_infer.geometry.resize.ResizeBlocks]).

        Args:
            block: Outputs per block.

        Returns:
            ResizeBlocks: Each block's window of inputs and its coefficient matrices; taps of coefficient 0
            are left out, so the windows span only the inputs that contribute.
        """
        groups = -(-self.size // block)
        pad = groups * block - self.size
        coefficients = np.pad(self.coefficients, ((0, 0), (0, pad)))
        index = np.pad(self.index, ((0, 0), (0, pad)), mode="edge")
        live = coefficients != 0
        by_block = (self.taps, groups, block)
        first = np.where(live, index, np.iinfo(np.int64).max).reshape(by_block).min(axis=(0, 2))
        last = np.where(live, index, -1).reshape(by_block).max(axis=(0, 2))
        empty = last < 0
        first[empty], last[empty] = 0, 0
        length = int((last - first).max()) + 1
        window = np.minimum(first[:, None] + np.arange(length), int(self.index.max()))
        output = np.broadcast_to(np.arange(groups * block), index.shape)[live]
        matrix = np.zeros((groups, block, length), np.int64)
        np.add.at(matrix, (output // block, output % block, index[live] - first[output // block]), coefficients[live])
        high, low = np.divmod(matrix, _SPLIT)
        return ResizeBlocks(
            index=window.astype(np.int64),
            high=(high / _SPLIT).astype(np.float32),
            low=(low / _SPLIT).astype(np.float32),
            size=self.size,
        )


def bicubic_kernel(x: np.ndarray) -> np.ndarray:
    """Pillow's cubic convolution kernel (a = -0.5), with its operations in Pillow's order.

    The order matters: the normalised weights are rounded to 22 bits, and a different float64
    evaluation order can move a weight across a rounding boundary.
    """
    a = _BICUBIC_A
    x = np.abs(x)
    inner = ((a + 2.0) * x - (a + 3.0)) * x * x + 1
    outer = (((x - 5) * x + 8) * x - 4) * a
    return np.where(x < 1.0, inner, np.where(x < 2.0, outer, 0.0))


def _float_weights(in_size: int, out_size: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Pillow's ``precompute_coeffs`` for the whole image: (xmin (out,), weights (T, out), T).

    The support grows with the downscale factor so a reduction averages every input pixel
    (antialiasing); the taps past an output's support (clipped at the image's edges) weigh 0, and
    each output's weights are divided by their sum, accumulated tap by tap as Pillow does, unless
    that sum is 0.
    """
    scale = float(np.float32(in_size)) / out_size
    filterscale = max(scale, 1.0)
    support = _BICUBIC_SUPPORT * filterscale
    ksize = int(math.ceil(support)) * 2 + 1
    center = (np.arange(out_size, dtype=np.float64) + 0.5) * scale
    xmin = np.maximum(np.trunc(center - support + 0.5), 0).astype(np.int64)
    xmax = np.minimum(np.trunc(center + support + 0.5).astype(np.int64), in_size) - xmin
    inv = 1.0 / filterscale
    taps = np.arange(ksize, dtype=np.int64)[:, None]
    inside = taps < xmax[None, :]
    weights = np.where(inside, bicubic_kernel(((taps + xmin[None, :]) - center[None, :] + 0.5) * inv), 0.0)
    total = np.zeros(out_size, dtype=np.float64)
    for row in weights:
        total = total + row
    weights = np.where((total != 0.0)[None, :], weights / np.where(total != 0.0, total, 1.0)[None, :], weights)
    return xmin, weights, ksize


def _fixed_point(weights: np.ndarray) -> np.ndarray:
    """Pillow's ``normalize_coeffs_8bpc``: round half away from zero to 22 fractional bits (C truncation)."""
    scaled = weights * float(1 << PIL_PRECISION_BITS)
    return np.trunc(np.where(weights < 0, scaled - 0.5, scaled + 0.5)).astype(np.int64)


def pil_bicubic_taps(in_size: int, out_size: int, first: int = 0, count: int | None = None) -> ResizeTaps:
    """Pillow's BICUBIC coefficients for resizing an axis of ``in_size`` to ``out_size``.

    Only the output positions ``first .. first + count - 1`` are kept (default: all), so a crop
    after the resize costs no gather of the discarded rows. The coefficients do not depend on the
    crop: Pillow computes them for the whole image (box = the full image).
    """
    if in_size < 1 or out_size < 1:
        raise ValueError(f"resize sizes must be positive, got {in_size} -> {out_size}")
    count = out_size - first if count is None else count
    if first < 0 or count < 1 or first + count > out_size:
        raise ValueError(f"output positions {first}..{first + count - 1} are outside 0..{out_size - 1}")
    xmin, weights, ksize = _float_weights(in_size, out_size)
    coefficients = _fixed_point(weights)[:, first : first + count]
    index = np.minimum(xmin[None, first : first + count] + np.arange(ksize, dtype=np.int64)[:, None], in_size - 1)
    return ResizeTaps(index=index, coefficients=coefficients)


def _pass_reference(x: np.ndarray, taps: ResizeTaps, axis: int) -> np.ndarray:
    """One of Pillow's 8-bit passes in int64: ``clip((2**21 + sum p * k) >> 22, 0, 255)``."""
    shape = [1] * x.ndim
    shape[axis] = taps.size
    acc = np.full((), _HALF, dtype=np.int64)
    for index, k in zip(taps.index, taps.coefficients):
        acc = acc + np.take(x, index, axis=axis).astype(np.int64) * k.reshape(shape)
    return np.clip(acc >> PIL_PRECISION_BITS, 0, 255).astype(np.uint8)


def pil_horizontal_first(in_width: int, in_height: int, width: int, height: int) -> bool:
    """Whether evaluating the horizontal pass first gives Pillow 13's result (earlier versions always do).

    Pillow 13 starts with the vertical pass when the height loses more than twice as many pixels
    as the width, so the second pass runs on fewer rows. The order changes the output (the
    intermediate image is rounded to uint8), except when one axis keeps its size and Pillow skips
    that pass; a graph that runs the horizontal pass first equals Pillow 13 only where this is True.
    """
    if width == in_width or height == in_height:
        return True
    lost_rows = in_height - height
    return not (lost_rows > 0 and lost_rows > (in_width - width) * 2)


def resize_reference(
    image: np.ndarray, width: int, height: int, rows: tuple[int, int] | None = None, *, horizontal_first: bool = True
) -> np.ndarray:
    """Pillow's ``Image.resize((width, height), BICUBIC)`` of a uint8 (H, W, C) image, in exact integers.

    The first pass's result is rounded to uint8 before the second pass, as in Pillow; that
    intermediate rounding is part of the output. The horizontal pass runs first (Pillow < 13, and
    Pillow 13 where `pil_horizontal_first` holds); ``horizontal_first=False`` gives Pillow
    13's other order. ``rows = (first, count)`` keeps the output rows ``first .. first + count - 1``
    (the pipelines' crop after the resize).
    """
    if image.dtype != np.uint8 or image.ndim != 3:
        raise ValueError(f"expected a uint8 (H, W, C) image, got {image.dtype} {image.shape}")
    first, count = rows if rows is not None else (0, height)
    horizontal = pil_bicubic_taps(image.shape[1], width)
    vertical = pil_bicubic_taps(image.shape[0], height, first, count)
    if horizontal_first:
        return _pass_reference(_pass_reference(image, horizontal, 1), vertical, 0)
    return _pass_reference(_pass_reference(image, vertical, 0), horizontal, 1)


def _exact_bound(blocks: ResizeBlocks) -> int:
    """The largest magnitude, in units of 2**-11, of any product, partial sum or rounding term of
    `apply_blocks_float32`."""
    high = 255 * int(np.abs(blocks.high * _SPLIT).astype(np.int64).sum(axis=2).max())
    low = 255 * int((blocks.low * _SPLIT).astype(np.int64).sum(axis=2).max())
    return max(high + (low + _HALF) // _SPLIT + 1, low)


def apply_blocks_float32(x: np.ndarray, blocks: ResizeBlocks, axis: int) -> np.ndarray:
    """One of Pillow's 8-bit passes along ``axis`` of a float32 array of uint8 values, in float32 only.

    Each block's window of ``x`` is multiplied by the block's ``high`` and ``low`` matrices:
    ``H = Sh / 2048`` and ``L = Sl / 2048`` with ``Sh = sum x * h`` and ``Sl = sum x * l`` over the
    coefficients ``k = 2048 * h + l``. The result is ``clip(floor(H + (floor(L) + 1024) / 2048), 0, 255)``.
    ``x`` must hold integers in [0, 255]. Every term is then a multiple of 2**-11 of magnitude below
    2**13 (the bound of the actual tables is checked), so float32 sums are exact in any order, and
    the scalings by 2048 are exact.

    Why that is Pillow's ``ss >> 22``, ``ss = 2**21 + sum x * k = 2048 * Sh + Sl + 2**21``: with
    ``bq = floor((Sl + 2**21) / 2048) = floor(L) + 1024``, ``ss = 2048 * (Sh + bq) + r`` with
    ``0 <= r < 2048``, so ``floor(ss / 2048) = Sh + bq``, and ``floor((Sh + bq) / 2048) = floor(ss / 2**22)``,
    the arithmetic shift.

    Args:
        x: Integer values in [0, 255], float32.
        blocks: The axis's tables (`ResizeTaps.blocks`).
        axis: The axis of ``x`` to resize.

    Returns:
        np.ndarray: float32, ``x`` with ``axis`` resized to ``blocks.size``.

    Raises:
        ValueError: The tables' sums would leave float32's exact range.
    """
    bound = _exact_bound(blocks)
    if bound >= FLOAT32_EXACT_LIMIT:
        raise ValueError(f"the resize's sums reach {bound} >= 2**24 units: the float32 evaluation would not be exact")
    moved = np.moveaxis(np.asarray(x, np.float32), axis, 0)
    windows = moved.reshape(moved.shape[0], -1)[blocks.index]  # (G, L, R)
    high, low = blocks.high @ windows, blocks.low @ windows  # (G, S, R)
    q = np.floor(high + (np.floor(low) + np.float32(_HALF // _SPLIT)) * np.float32(1.0 / _SPLIT))
    q = np.clip(q, np.float32(0), np.float32(255)).reshape(-1, *moved.shape[1:])[: blocks.size]
    return np.moveaxis(q, 0, axis).astype(np.float32, copy=False)
