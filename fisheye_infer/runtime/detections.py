"""``Detections``: one frame's boxes as equal-length numpy arrays, with filters and exports.

    dets = detector.detect(frame)
    cars = dets.filter(classes=["Car"], min_score=0.3, max_range=30.0)
    cars.to_nuscenes()            # records for the evaluator / a results file
    dets.with_nms(NmsConfig())    # opt-in; the official output has none

Boxes are (K, 7) ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.box_geometry import check_boxes
from fisheye_infer.runtime.box_geometry import corners as box_corners
from fisheye_infer.runtime.nms import NmsConfig, apply_nms
from fisheye_infer.runtime.options import check_classes

__all__ = ["Detections"]


@dataclass(frozen=True)
class Detections:
    """Detections of one frame, highest proposals first (the model's order, not sorted by score).

    Boxes are `(K, 7)` ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame: the bottom centre and yaw in
    metres and radians (x forward, y left, z up; yaw about +z, 0 along +x). Constructing one checks that
    every array has K rows and every label names a class.

    Attributes:
        boxes (np.ndarray): `(K, 7)` float32 boxes, lidar frame, metres and radians.
        scores (np.ndarray): `(K,)` float32 confidence of each box, in [0, 1].
        labels (np.ndarray): `(K,)` int64 index of each box's class in ``class_names``.
        class_names (tuple[str, ...]): The model's classes, in label order.
        cameras_used (tuple[str, ...]): The cameras that had an image in this frame (fewer than the model's
            in degraded mode).
        timings_ms (dict[str, float]): Milliseconds per stage of the call that produced this
            (``decode``, ``preprocess``, ``inference``, ``postprocess``).
        model_id (str): The producing file's model id (architecture, rig hash, checkpoint digest).

    Raises:
        ValueError: The arrays' shapes disagree, or a label is outside ``class_names``.

    Examples:
        ```python
        dets = detector.detect(frame)
        cars = dets.filter(classes=["Car"], min_score=0.3, max_range=30.0)
        for name, score, box in zip(cars.names, cars.scores, cars.boxes):
            print(name, f"{score:.2f}", box[:3])
        records = dets.to_nuscenes()          # for the evaluator or a results file
        ```
    """

    boxes: np.ndarray  # (K, 7) float32
    scores: np.ndarray  # (K,) float32
    labels: np.ndarray  # (K,) int64
    class_names: tuple[str, ...]
    cameras_used: tuple[str, ...] = ()
    timings_ms: dict[str, float] = field(default_factory=dict)
    model_id: str = ""

    def __post_init__(self) -> None:
        check_boxes(self.boxes)
        k = len(self.boxes)
        for name in ("scores", "labels"):
            value = getattr(self, name)
            if np.shape(value) != (k,):
                raise ValueError(f"{name}: expected shape ({k},) to match boxes, got {np.shape(value)}")
        if k and (self.labels.min() < 0 or self.labels.max() >= len(self.class_names)):
            raise ValueError(
                f"labels: expected values in [0, {len(self.class_names)}), got {self.labels.min()}..{self.labels.max()}"
            )

    @classmethod
    def empty(cls, class_names: Sequence[str]) -> Detections:
        """No boxes.

        Args:
            class_names (Sequence[str]): The model's classes, in label order.

        Returns:
            Detections: An object with K = 0.
        """
        return cls(np.zeros((0, 7), np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64), tuple(class_names))

    def __len__(self) -> int:
        return len(self.boxes)

    def __getitem__(self, index: Any) -> Detections:
        """Select by integer array, slice or boolean mask; returns a new ``Detections``."""
        if isinstance(index, (int, np.integer)):
            index = [index]
        return Detections(
            self.boxes[index],
            self.scores[index],
            self.labels[index],
            self.class_names,
            self.cameras_used,
            dict(self.timings_ms),
            self.model_id,
        )

    @property
    def names(self) -> list[str]:
        """Class name of each box."""
        return [self.class_names[i] for i in self.labels]

    # -- filters ------------------------------------------------------------------------

    def filter(
        self, min_score: float | None = None, classes: Iterable[str] | None = None, max_range: float | None = None
    ) -> Detections:
        """The boxes that pass every given filter; a filter left at None keeps everything.

        Args:
            min_score (float | None): Keep boxes scoring at least this.
            classes (Iterable[str] | None): Keep boxes of these class names.
            max_range (float | None): Keep boxes whose centre lies within this many metres of the
                lidar origin in the bird's-eye view.

        Returns:
            Detections: A new object with the kept boxes, in the same order.

        Raises:
            OptionError: ``classes`` names a class the model does not have.
        """
        keep = np.ones(len(self), dtype=bool)
        if min_score is not None:
            keep &= self.scores >= min_score
        wanted = check_classes(classes, self.class_names)
        if wanted is not None:
            keep &= np.isin(self.labels, [self.class_names.index(c) for c in wanted])
        if max_range is not None:
            keep &= np.hypot(self.boxes[:, 0], self.boxes[:, 1]) <= max_range
        return self[keep]

    def with_nms(self, config: NmsConfig) -> Detections:
        """The boxes left after non-maximum suppression (the official output has none).

        Args:
            config (NmsConfig): What suppression to run and its thresholds
                ([`NmsConfig`][fisheye_infer.runtime.nms.NmsConfig]).

        Returns:
            Detections: A new object with the kept boxes.
        """
        return self[apply_nms(self.boxes, self.scores, self.labels, config, self.class_names)]

    # -- geometry and exports -----------------------------------------------------------

    def corners(self) -> np.ndarray:
        """The corners of every box.

        Returns:
            np.ndarray: `(K, 8, 3)` corners in the lidar frame, metres.
        """
        return box_corners(self.boxes)

    def to_dicts(self) -> list[dict[str, Any]]:
        """One plain dict per box, in this object's layout (bottom-centred, lidar frame).

        Returns:
            list[dict[str, Any]]: ``x, y, z_bottom, l, w, h, yaw, score, label, class_name`` per box.
        """
        keys = ("x", "y", "z_bottom", "l", "w", "h", "yaw")
        return [
            {
                **{k: float(v) for k, v in zip(keys, box)},
                "score": float(score),
                "label": int(label),
                "class_name": self.class_names[label],
            }
            for box, score, label in zip(self.boxes, self.scores, self.labels)
        ]

    def to_nuscenes(self) -> list[dict[str, Any]]:
        """nuScenes-style result records, as the evaluator reads them.

        Returns:
            list[dict[str, Any]]: One record per box (see
                [`boxes_to_records`][fisheye_infer.runtime.records.boxes_to_records]).
        """
        from fisheye_infer.runtime.records import boxes_to_records

        return boxes_to_records(self.boxes, self.scores, self.labels, self.class_names)

    def to_json(self, **kwargs: Any) -> str:
        """A JSON document with the model id, cameras used, timings and one object per box.

        Args:
            **kwargs: Passed to `json.dumps` (e.g. ``indent=2``).

        Returns:
            str: The document; [`from_json`][fisheye_infer.runtime.detections.Detections.from_json] reads it back.
        """
        doc = {
            "model_id": self.model_id,
            "cameras_used": list(self.cameras_used),
            "timings_ms": self.timings_ms,
            "detections": self.to_dicts(),
        }
        return json.dumps(doc, **kwargs)

    @classmethod
    def from_json(cls, text: str, class_names: Sequence[str]) -> Detections:
        """Read back what ``to_json`` wrote (e.g. to draw a saved result).

        Args:
            text (str): The JSON document.
            class_names (Sequence[str]): The model's classes; each row's ``class_name`` must be one of them.

        Returns:
            Detections: The boxes, scores and labels, with the model id, cameras and timings stored.

        Raises:
            FrameError: The text is not JSON, lacks the ``detections`` list, or a row misses a field, has a
                non-numeric value or an unknown class (the row is named).
        """
        try:
            doc = json.loads(text)
        except (ValueError, RecursionError) as exc:  # ValueError: not JSON, a number of 4300+ digits
            raise FrameError(f"detections: not valid JSON ({str(exc)[:200] or 'nested too deep'})") from None
        rows = doc.get("detections", []) if isinstance(doc, dict) else None
        if not isinstance(rows, list):
            raise FrameError("detections: expected an object with a 'detections' list")
        fields = ("x", "y", "z_bottom", "l", "w", "h", "yaw", "score")
        for i, r in enumerate(rows):
            missing = [k for k in (*fields, "class_name") if not isinstance(r, dict) or k not in r]
            if missing:
                raise FrameError(f"detections[{i}]: missing {', '.join(missing)}")
            if r["class_name"] not in class_names:
                raise FrameError(
                    f"detections[{i}]: class_name {r['class_name']!r} is not one of {', '.join(class_names)}"
                )
        try:
            values = np.array([[r[k] for k in fields] for r in rows], np.float32).reshape(-1, len(fields))
        except (TypeError, ValueError) as exc:
            raise FrameError(f"detections: box fields must be numbers ({exc})") from None
        boxes, scores = values[:, :7], values[:, 7]
        labels = np.array([list(class_names).index(r["class_name"]) for r in rows], np.int64)
        return cls(
            boxes,
            scores,
            labels,
            tuple(class_names),
            tuple(doc.get("cameras_used", ())),
            doc.get("timings_ms", {}),
            doc.get("model_id", ""),
        )
