"""What ``export``, ``export_int8`` and ``export_fp16`` are asked to do beyond the fp32 file, grouped.

``Int8Options`` says how the int8 file is made (calibration, scope, float modules, weight bits);
``Comparison`` says how a reduced-precision file (int8 or fp16) is judged against its fp32 file.
Both check their values where they are made, so a bad option fails before anything is computed.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from fisheye_infer.errors import ExportError
from fisheye_infer.precision import COMPARE_FRAMES, MIN_TOP_MATCHED, WEIGHT_BITS, WEIGHT_QMAX

__all__ = ["AUTO", "SCOPES", "Comparison", "Int8Options", "options_from_keywords"]

#: What the int8 file may cover: ``network`` (the image trunk and every weighted layer beyond it) or ``trunk``.
SCOPES = ("network", "trunk")
#: The default scope: the int8 search chooses the scope and the float32 modules (``int8_search``).
AUTO = "auto"


@dataclass(frozen=True)
class Int8Options:
    """How the int8 file is made: calibration frames, what stays float32, weight bits.

    ``calib_frames`` seeded synthetic renders of the file's rig plus the frames in ``calib_images`` calibrate the
    activation ranges. By default (``scope="auto"``, ``keep_float=None``) the int8 search chooses what stays
    float32, starting from the architecture's own ``int8_float`` modules, until the file passes its comparison.
    Every value is checked here, so a bad option fails before anything is computed.

    Attributes:
        calib_images (str | Path | None): A file or folder of your own frames added to the calibration; None for
            synthetic frames only.
        calib_frames (int): Seeded synthetic calibration frames of the file's rig; 0 only with ``calib_images``.
        scope (str): ``auto`` (the int8 search chooses), ``network`` (the image trunk and every weighted layer
            beyond it) or ``trunk`` (the image trunk only). ``auto`` with ``keep_float`` given means ``network``.
        keep_float (Sequence[str] | None): Modules (state-dict prefixes) left float32, chosen by hand; None lets
            the search choose (``scope="auto"``) or keeps the architecture's ``int8_float``.
        weight_bits (int): Bits of the int8 weights: 7 (default; every x86 CPU computes the same integers), or 8
            only to measure what 7 costs.

    Raises:
        ExportError: A value is out of range, there are no calibration frames, or ``calib_images`` does not exist.
    """

    calib_images: str | Path | None = None
    calib_frames: int = 8
    scope: str = AUTO
    keep_float: Sequence[str] | None = None
    weight_bits: int = WEIGHT_BITS

    @property
    def searched(self) -> bool:
        """Whether the int8 search chooses the scope and float modules (neither was given)."""
        return self.scope == AUTO and self.keep_float is None

    @property
    def chosen_scope(self) -> str:
        """The scope of a file chosen by hand: ``scope``, or ``network`` where it says ``AUTO``."""
        return "network" if self.scope == AUTO else self.scope

    def __post_init__(self) -> None:
        if self.scope not in (AUTO, *SCOPES):
            raise ExportError(f"--int8-scope {self.scope}: expected one of {', '.join((AUTO, *SCOPES))}")
        if self.calib_frames < 0:
            raise ExportError(f"--calib-frames {self.calib_frames}: expected 0 or more synthetic calibration frames")
        if self.calib_frames == 0 and self.calib_images is None:
            raise ExportError("--calib-frames 0 without --calib-images: int8 calibration needs at least one frame")
        if self.calib_images is not None and not Path(self.calib_images).exists():
            raise ExportError(f"--calib-images {self.calib_images}: no such file or folder")
        if self.weight_bits not in WEIGHT_QMAX:
            raise ExportError(f"int8: weight_bits {self.weight_bits}: expected one of {sorted(WEIGHT_QMAX)}")
        if self.keep_float is not None:
            object.__setattr__(self, "keep_float", tuple(self.keep_float))


@dataclass(frozen=True)
class Comparison:
    """How a reduced-precision file (int8 or fp16) is judged against its fp32 file, ONNX against ONNX.

    The file is written when it finds ``min_kept`` of the fp32 file's top-50 boxes again (same label, within the
    match radius) on the comparison frames.

    Attributes:
        frames (int): Seeded synthetic frames (the first ones are the fp32 export's own verification frames);
            default 32; 0 only with ``images``.
        min_kept (float): The share of the fp32 file's top-50 boxes the file must find again, in (0, 1]; default
            0.95.
        images (str | Path | None): A folder of your own frames added to the comparison; None for synthetic frames
            only.
        threads (int): ONNX Runtime threads for both files; at least 1.

    Raises:
        ExportError: A value is out of range.
    """

    frames: int = COMPARE_FRAMES
    min_kept: float = MIN_TOP_MATCHED
    images: str | Path | None = None
    threads: int = 2

    def __post_init__(self) -> None:
        if self.frames < 0 or (self.frames == 0 and self.images is None):
            raise ExportError(
                f"--compare-frames {self.frames}: expected 1 or more seeded frames (or 0 with --verify-images)"
            )
        if not 0.0 < self.min_kept <= 1.0:
            raise ExportError(
                f"--min-kept {self.min_kept}: expected a share of the fp32 top-50 boxes in (0, 1], e.g. 0.9"
            )
        if self.threads < 1:
            raise ExportError(f"comparison threads {self.threads}: expected 1 or more")


#: The previous release's keyword arguments that now live in ``Int8Options``, and their fields.
_INT8_KEYWORDS = {
    "calib_images": "calib_images",
    "calib_frames": "calib_frames",
    "int8_scope": "scope",
    "scope": "scope",
    "int8_float": "keep_float",
    "keep_float": "keep_float",
    "weight_bits": "weight_bits",
}
#: ... and those of ``export`` that now live in ``Comparison``.
_COMPARISON_KEYWORDS = {"compare_frames": "frames", "min_kept": "min_kept"}


def options_from_keywords(
    int8: Int8Options | None,
    comparison: Comparison,
    keywords: Mapping[str, Any],
    *,
    comparison_names: Mapping[str, str] | None = None,
    caller: str = "export",
) -> tuple[Int8Options | None, Comparison]:
    """Fold the previous release's keyword arguments (``calib_frames=``, ``min_kept=``, ...) into the option
    objects, with a DeprecationWarning; an unknown keyword is a TypeError, as for any function."""
    if not keywords:
        return int8, comparison
    names = {**_COMPARISON_KEYWORDS, **(comparison_names or {})}
    unknown = sorted(set(keywords) - set(_INT8_KEYWORDS) - set(names))
    if unknown:
        raise TypeError(f"{caller}() got unexpected keyword argument(s): {', '.join(unknown)}")
    warnings.warn(
        f"{caller}({', '.join(f'{k}=' for k in keywords)}): pass int8=Int8Options(...) and comparison=Comparison(...) "
        "(fisheye_infer.export.options); the keywords will be removed in the next release",
        DeprecationWarning,
        stacklevel=3,
    )
    int8_fields = {_INT8_KEYWORDS[k]: v for k, v in keywords.items() if k in _INT8_KEYWORDS}
    if int8_fields:
        int8 = replace(int8 or Int8Options(), **int8_fields)
    comparison_fields = {names[k]: v for k, v in keywords.items() if k in names}
    return int8, replace(comparison, **comparison_fields) if comparison_fields else comparison
