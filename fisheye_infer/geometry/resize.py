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
exact by construction (`apply_taps_float32`): every integer coefficient is split into a
high and a low part of 11 bits so that every product and partial sum stays an integer below
2**24, where float32 arithmetic has no rounding. That float32 form is the specification of the
graph's resize (``fisheye_infer.models.resize``), which must stay float32 (no float64, no integer
MatMul) to run on TensorRT.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "PIL_PRECISION_BITS",
    "SPLIT_BITS",
    "FLOAT32_EXACT_LIMIT",
    "ResizeTaps",
    "bicubic_kernel",
    "pil_bicubic_taps",
    "pil_horizontal_first",
    "resize_reference",
    "apply_taps_float32",
]

PIL_PRECISION_BITS = 22  # Pillow's 32 - 8 - 2: 8 bits of result, 2 bits for the kernel's over- and undershoot
# k = high * 2**11 + low: T products of a pixel (< 2**8) and a part (<= 2**11) sum below 2**24 for T <= 32, and
# with Pillow's rounding offset 2**21 added, for T <= 28; apply_taps_float32 checks the actual tables.
SPLIT_BITS = 11
FLOAT32_EXACT_LIMIT = 2**24  # every integer of smaller magnitude is a float32, so sums of them are exact

_SPLIT = 1 << SPLIT_BITS
_HALF = 1 << (PIL_PRECISION_BITS - 1)  # Pillow's rounding offset, added before the shift
_BICUBIC_A = -0.5
_BICUBIC_SUPPORT = 2.0


@dataclass(frozen=True)
class ResizeTaps:
    """Pillow's 8-bit coefficients for one axis, laid out for a gather per tap.

    All arrays are (T, out), T = Pillow's ``ksize``. Taps beyond an output's support have
    coefficient 0 and an index clamped into ``[0, in_size)``, so every tap can be gathered without
    a mask. ``high`` and ``low`` are the integer coefficient split by floor division,
    ``coefficients == high * 2048 + low`` with ``0 <= low < 2048``, stored as float32 because the
    graph multiplies float32 pixels by them; ``coefficients`` is kept for the int64 reference.
    """

    index: np.ndarray  # (T, out) int64 input position of each tap
    high: np.ndarray  # (T, out) float32, integer-valued, may be negative
    low: np.ndarray  # (T, out) float32, integer-valued, in [0, 2048)
    coefficients: np.ndarray  # (T, out) int64, Pillow's fixed-point coefficient

    @property
    def taps(self) -> int:
        """T, the number of taps per output position (Pillow's ``ksize``)."""
        return int(self.index.shape[0])

    @property
    def size(self) -> int:
        """The number of output positions the tables cover."""
        return int(self.index.shape[1])

    def trimmed(self) -> ResizeTaps:
        """The same resampling without the taps whose coefficient is 0 at every output position.

        Pillow sizes its tables for the widest support (``ksize``), so some taps never contribute
        (two of the nine of 1280 -> 800); a graph that skips them does less work for the same
        integers, hence the same output.
        """
        keep = np.flatnonzero((self.coefficients != 0).any(axis=1))
        keep = keep if keep.size else np.arange(1)
        return ResizeTaps(
            index=self.index[keep], high=self.high[keep], low=self.low[keep], coefficients=self.coefficients[keep]
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
    high, low = np.divmod(coefficients, _SPLIT)
    return ResizeTaps(index=index, high=high.astype(np.float32), low=low.astype(np.float32), coefficients=coefficients)


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


def _exact_bound(taps: ResizeTaps) -> int:
    """The largest magnitude any product, partial sum or rounding term of `apply_taps_float32` reaches."""
    high = 255 * int(np.abs(taps.high.astype(np.int64)).sum(axis=0).max())
    low = 255 * int(taps.low.astype(np.int64).sum(axis=0).max()) + _HALF
    return max(high + low // _SPLIT + 1, low)


def apply_taps_float32(x: np.ndarray, taps: ResizeTaps, axis: int) -> np.ndarray:
    """One of Pillow's 8-bit passes along ``axis`` of a float32 array of uint8 values, in float32 only.

    With ``Sh = sum_t x[index_t] * high_t``, ``Sl = sum_t x[index_t] * low_t``, ``b = Sl + 2**21``,
    ``bq = floor(b / 2048)`` and ``q = floor((Sh + bq) / 2048)``, the result is ``clip(q, 0, 255)``.
    ``x`` must hold integers in [0, 255]. Every term is then an integer of magnitude below 2**24
    (about ``255 * 2048 * T + 2**21`` at most; the bound of the actual tables is checked), so
    float32 sums are exact in any order, and the divisions by 2048 are exact.

    Why ``q`` is Pillow's ``ss >> 22``, ``ss = 2**21 + sum x * k = 2048 * Sh + b``:
    ``ss = 2048 * (Sh + bq) + (b mod 2048)`` with ``0 <= b mod 2048 < 2048``, so ``floor(ss / 2048) = Sh + bq``;
    and ``floor(floor(ss / 2048) / 2048) = floor(ss / 2**22)``, the arithmetic shift.
    """
    bound = _exact_bound(taps)
    if bound >= FLOAT32_EXACT_LIMIT:
        raise ValueError(f"{taps.taps} taps reach {bound} >= 2**24: the float32 evaluation would not be exact")
    shape = [1] * x.ndim
    shape[axis] = taps.size
    sh = np.zeros((), dtype=np.float32)
    sl = np.zeros((), dtype=np.float32)
    for index, high, low in zip(taps.index, taps.high, taps.low):
        gathered = np.take(x, index, axis=axis).astype(np.float32, copy=False)
        sh = sh + gathered * high.reshape(shape)
        sl = sl + gathered * low.reshape(shape)
    split = np.float32(_SPLIT)
    bq = np.floor((sl + np.float32(_HALF)) / split)
    q = np.floor((sh + bq) / split)
    return np.clip(q, np.float32(0), np.float32(255)).astype(np.float32, copy=False)
