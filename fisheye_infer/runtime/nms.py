"""Optional non-maximum suppression on BEV boxes: arrays in, kept indices out.

The official test-time output of both detectors has no NMS; these are opt-in tools for
users whose downstream needs one box per object:

- ``rotated_bev_nms``: IoU of the rotated BEV footprints (OpenCV's rotated-rectangle
  intersection), class-aware, with per-class thresholds;
- ``circle_nms``: centre distance in BEV, class-aware, with per-class radii (as CenterPoint).

    keep = rotated_bev_nms(boxes, scores, labels, iou=0.2, per_class={4: 0.5})
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Literal

import cv2
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from fisheye_infer.runtime.box_geometry import check_boxes

__all__ = ["NmsConfig", "bev_iou", "rotated_bev_nms", "circle_nms", "apply_nms"]


class NmsConfig(BaseModel):
    """What non-maximum suppression to run; thresholds per class name override the default.

    Attributes:
        kind (Literal['rotated', 'circle']): ``"rotated"``: suppress by bird's-eye-view IoU of the rotated
            boxes; ``"circle"``: by centre distance (CenterPoint's).
        iou (float): Rotated: suppress a box overlapping a better one above this BEV IoU, in (0, 1].
        radius (float): Circle: suppress a box within this centre distance of a better one, metres, > 0.
        per_class (dict[str, float]): Class name -> its own IoU or radius.
        class_aware (bool): Boxes suppress only boxes of their own class.

    Raises:
        pydantic.ValidationError: A value is out of range or a field is unknown.

    Examples:
        ```python
        NmsConfig(kind="rotated", iou=0.2, per_class={"Pedestrian": 0.5})
        NmsConfig(kind="circle", radius=2.0, per_class={"Pedestrian": 0.5, "Bus": 4.0})
        ```
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["rotated", "circle"] = "rotated"
    iou: float = Field(default=0.2, gt=0.0, le=1.0, description="rotated: suppress above this BEV IoU")
    radius: float = Field(default=2.0, gt=0.0, description="circle: suppress within this centre distance (m)")
    per_class: dict[str, float] = Field(default_factory=dict, description="class name -> iou or radius")
    class_aware: bool = True

    @model_validator(mode="after")
    def _check_per_class(self) -> NmsConfig:
        """Per-class values obey the default's bounds: an IoU of 0 or a negative radius would
        silently suppress every other box of the class."""
        for name, value in self.per_class.items():
            if not value > 0 or (self.kind == "rotated" and value > 1):
                expected = "an IoU in (0, 1]" if self.kind == "rotated" else "a radius > 0 (m)"
                raise ValueError(f"per_class['{name}']: expected {expected}, got {value}")
        return self


def _rect(box: np.ndarray) -> tuple[tuple[float, float], tuple[float, float], float]:
    return (float(box[0]), float(box[1])), (float(box[3]), float(box[4])), float(np.degrees(box[6]))


def bev_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boxes' rotated footprints in the x-y plane."""
    area_a, area_b = float(a[3] * a[4]), float(b[3] * b[4])
    if area_a <= 0 or area_b <= 0:
        return 0.0
    if np.hypot(a[0] - b[0], a[1] - b[1]) > 0.5 * (np.hypot(a[3], a[4]) + np.hypot(b[3], b[4])):
        return 0.0
    kind, points = cv2.rotatedRectangleIntersection(_rect(a), _rect(b))
    if kind == cv2.INTERSECT_NONE or points is None:
        return 0.0
    inter = float(cv2.contourArea(cv2.convexHull(points)))
    return inter / (area_a + area_b - inter)


def _thresholds(labels: np.ndarray, default: float, per_class: Mapping[int, float] | None) -> np.ndarray:
    out = np.full(len(labels), default, dtype=np.float64)
    for label, value in (per_class or {}).items():
        out[labels == label] = value
    return out


def _greedy(
    boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray, class_aware: bool, suppresses: Callable[[int, int], bool]
) -> np.ndarray:
    order = np.argsort(-np.asarray(scores), kind="stable")
    alive = np.ones(len(order), dtype=bool)
    keep = []
    for i, idx in enumerate(order):
        if not alive[i]:
            continue
        keep.append(idx)
        for j in range(i + 1, len(order)):
            other = order[j]
            if alive[j] and (not class_aware or labels[other] == labels[idx]) and suppresses(idx, other):
                alive[j] = False
    return np.asarray(keep, dtype=np.int64)


def _check(boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    b = check_boxes(boxes).astype(np.float64)
    s, lab = np.asarray(scores), np.asarray(labels)
    if s.shape != (len(b),) or lab.shape != (len(b),):
        raise ValueError(f"scores and labels: expected shape ({len(b)},), got {s.shape} and {lab.shape}")
    return b, s, lab


def rotated_bev_nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    labels: np.ndarray,
    iou: float = 0.2,
    per_class: Mapping[int, float] | None = None,
    class_aware: bool = True,
) -> np.ndarray:
    """Indices of the boxes kept, highest score first; a box goes when its BEV IoU with a kept
    box of the same class exceeds that class's threshold."""
    b, s, lab = _check(boxes, scores, labels)
    limit = _thresholds(lab, iou, per_class)
    return _greedy(b, s, lab, class_aware, lambda i, j: bev_iou(b[i], b[j]) > limit[i])


def circle_nms(
    boxes: np.ndarray,
    scores: np.ndarray,
    labels: np.ndarray,
    radius: float = 2.0,
    per_class: Mapping[int, float] | None = None,
    class_aware: bool = True,
) -> np.ndarray:
    """Indices of the boxes kept, highest score first; a box goes when its centre lies within
    the class's radius of a kept box's centre."""
    b, s, lab = _check(boxes, scores, labels)
    limit = _thresholds(lab, radius, per_class)
    return _greedy(b, s, lab, class_aware, lambda i, j: np.hypot(b[i, 0] - b[j, 0], b[i, 1] - b[j, 1]) < limit[i])


def apply_nms(
    boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray, config: NmsConfig, class_names: tuple[str, ...]
) -> np.ndarray:
    """Run the suppression ``config`` describes; class names in ``per_class`` must be known."""
    unknown = set(config.per_class) - set(class_names)
    if unknown:
        raise ValueError(f"nms per_class: unknown class {sorted(unknown)}; classes are {', '.join(class_names)}")
    per_class = {class_names.index(name): value for name, value in config.per_class.items()}
    if config.kind == "rotated":
        return rotated_bev_nms(boxes, scores, labels, config.iou, per_class, config.class_aware)
    return circle_nms(boxes, scores, labels, config.radius, per_class, config.class_aware)
