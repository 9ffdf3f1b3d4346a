"""The reduced-precision policy: how an int8 file is quantized and when an int8 or fp16 file is kept.

Torch-free, because three places read it: the exporter (``fisheye_infer.export``), the
quantization-aware training that simulates the int8 file's rounding (``models.training.qat``) and
the metadata a runtime reads.

Weights are quantized to 7 bits, [-64, 64], not [-127, 127]. On x86 CPUs without VNNI (AVX2 only,
or AVX-512 before Cascade Lake) ONNX Runtime's u8 x s8 kernels multiply with ``vpmaddubsw``, which
adds each pair of neighbouring products in int16 and saturates: 255 x 127 x 2 = 64,770 does not fit
in int16, 255 x 64 x 2 = 32,640 does. With 7 bits every x86 CPU computes the int8 layers' sums exactly
as the machine that verified the file did; VNNI's ``vpdpbusd`` adds in int32 and is exact for both.
``benchmarks/int8_saturation.py`` counts the saturated sums of an 8-bit file; ``benchmarks/int8.py
--weight-bits 8`` measures what 7 bits cost.
"""

from __future__ import annotations

from typing import Final

__all__ = ["CALIBRATION_PERCENTILE", "COMPARE_FRAMES", "MIN_TOP_MATCHED", "WEIGHT_BITS", "WEIGHT_QMAX", "under_module"]

#: The int8 file's weight bits (symmetric S8 per output channel; 7 is ONNX Runtime's ``reduce_range``).
WEIGHT_BITS: Final = 7
#: The largest weight magnitude for each supported number of weight bits.
WEIGHT_QMAX: Final = {7: 64, 8: 127}
#: The int8 file's activation ranges: ONNX Runtime's percentile calibration, at this percentile of
#: each tensor's magnitudes over the calibration frames (then clipped to its minimum and maximum).
CALIBRATION_PERCENTILE: Final = 99.99
#: A reduced-precision file (int8, fp16) is written when it finds this share of the fp32 file's top-50
#: boxes again (``fisheye_infer.eval.top_match``: within 0.5 m, same label) ...
MIN_TOP_MATCHED: Final = 0.95
#: ... on this many seeded frames. The share varies from frame to frame; its standard error over the
#: frames (reported with it) shrinks with their number. Both files are ONNX, so frames cost inference only.
COMPARE_FRAMES: Final = 32


def under_module(name: str, prefix: str) -> bool:
    """Whether the module ``name`` is the module ``prefix`` or inside it, as state-dict names nest.

    ``img_backbone.conv1`` is under ``img_backbone``, ``img_backbone_x`` is not: how an int8 file's float modules
    (``keep_float``) are matched, in the export and in its training simulation.

    Args:
        name: A module's dotted name in the state dict.
        prefix: The dotted name of the module it may be inside.

    Returns:
        bool: True when ``name`` is ``prefix`` or one of its submodules.
    """
    return name == prefix or name.startswith(prefix + ".")
