"""The detect options, checked where they enter: a score threshold, class names, NMS.

``Detector`` (per Detector and per call), ``Detections.filter`` and the service check them
before any work and refuse a bad one with an ``OptionError`` naming the option: a threshold of
2.0 or NaN would otherwise silently return no boxes, and ``classes="Car"`` would be split into
letters.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterable, Mapping, Sequence

from fisheye_infer.errors import OptionError
from fisheye_infer.runtime.nms import NmsConfig

__all__ = ["NMS_KINDS", "check_score_threshold", "check_classes", "check_nms"]

NMS_KINDS = ("rotated", "circle")


def _shown(value: object, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_score_threshold(value: object) -> float | None:
    """``None`` or a real number in [0, 1] (NaN refused), as a float."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise OptionError(f"score_threshold: expected a number in [0, 1], got {type(value).__name__} {_shown(value)}")
    number = float(value)
    if math.isnan(number) or not 0.0 <= number <= 1.0:
        raise OptionError(f"score_threshold: expected a number in [0, 1], got {number}")
    return number


def check_classes(value: object, known: Sequence[str]) -> tuple[str, ...] | None:
    """``None`` or class names of this model; a bare string is refused rather than split into letters."""
    if value is None:
        return None
    if isinstance(value, (str, bytes)):
        raise OptionError(
            f"classes: got the single string {_shown(value)}; pass a list of class names, e.g. [{_shown(value)}]"
        )
    if isinstance(value, Mapping) or not isinstance(value, Iterable):
        raise OptionError(f"classes: expected a list of class names, got {type(value).__name__}")
    names = tuple(value)
    wrong = [name for name in names if not isinstance(name, str)]
    if wrong:
        raise OptionError(f"classes: expected class names (strings), got {type(wrong[0]).__name__} {_shown(wrong[0])}")
    unknown = sorted(set(names) - set(known))
    if unknown:
        shown = ", ".join(_shown(name) for name in unknown[:20]) + (
            f" and {len(unknown) - 20} more" if len(unknown) > 20 else ""
        )
        raise OptionError(f"classes: unknown {shown}; the model's classes are {', '.join(known)}")
    return names


def check_nms(value: object) -> NmsConfig | None:
    """``None``, an ``NmsConfig``, or the name of a kind (``"rotated"``/``"circle"``) with its defaults."""
    if value is None or isinstance(value, NmsConfig):
        return value
    if isinstance(value, str) and value in NMS_KINDS:
        return NmsConfig(kind=value)
    raise OptionError(
        f"nms: expected an NmsConfig or one of {', '.join(repr(k) for k in NMS_KINDS)}, "
        f"got {type(value).__name__} {_shown(value)}"
    )
