"""``EvalBoxes``: every box of every sample as flat numpy columns, in evaluation order.

nuScenes keeps one Python object per box; at 10k frames with 200 predictions each that is two
million objects and minutes of evaluation. Here a box is a row: the sample it belongs to, its
class id, gravity centre, (w, l, h), yaw and score. Order matters for the metric (score ties
are broken by position), so rows stay in sample order, then in per-sample record order.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.records import CLASSES, GT_SCORE, quaternion_to_yaw, record_columns, yaw_to_quaternion

__all__ = ["EvalBoxes"]


@dataclass(frozen=True)
class EvalBoxes:
    """Boxes of many samples; ``sample[i]`` indexes ``tokens``."""

    tokens: tuple[str, ...]
    sample: np.ndarray  # (K,) int64
    label: np.ndarray  # (K,) int64
    translation: np.ndarray  # (K, 3) gravity centre, lidar frame
    size: np.ndarray  # (K, 3) w, l, h
    yaw: np.ndarray  # (K,)
    score: np.ndarray  # (K,)

    def __post_init__(self) -> None:
        k = len(self.sample)
        for name, shape in (("label", (k,)), ("translation", (k, 3)), ("size", (k, 3)), ("yaw", (k,)), ("score", (k,))):
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {np.shape(getattr(self, name))}")
        if k and (self.sample.min() < 0 or self.sample.max() >= len(self.tokens)):
            raise ValueError(f"sample: indices must lie in [0, {len(self.tokens)})")

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def empty(cls, tokens: Sequence[str] = ()) -> EvalBoxes:
        z = np.zeros(0)
        return cls(
            tuple(tokens), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros((0, 3)), z, z
        )

    @classmethod
    def from_records(
        cls,
        results: Mapping[str, Sequence[Mapping[str, Any]]],
        class_names: Sequence[str] = CLASSES,
        tokens: Sequence[str] | None = None,
        ground_truth: bool = False,
    ) -> EvalBoxes:
        """``{sample_token: [record, ...]}`` -> boxes; ``tokens`` fixes the sample order (default: the mapping's).

        A token in ``tokens`` that ``results`` lacks is a sample without boxes. With
        ``ground_truth`` the records' ``detection_score`` is ignored (and may be absent).
        """
        if not isinstance(results, Mapping):
            raise FrameError(
                f"results: expected an object mapping sample tokens to lists of records, got {type(results).__name__}"
            )
        order = tuple(results) if tokens is None else tuple(tokens)
        flat: list[Mapping[str, Any]] = []
        counts = np.zeros(len(order), np.int64)
        for i, token in enumerate(order):
            records = results.get(token, ())
            if not isinstance(records, (list, tuple)):
                raise FrameError(f"sample {token}: expected a list of records, got {type(records).__name__}")
            flat.extend(records)
            counts[i] = len(records)
        try:
            cols = record_columns(flat, class_names, source="results", scored=not ground_truth)
        except FrameError:
            for token in order:  # name the sample: rerun only to locate the first bad record
                record_columns(results.get(token, ()), class_names, source=f"sample {token}", scored=not ground_truth)
            raise
        sample = np.repeat(np.arange(len(order), dtype=np.int64), counts)
        return cls(order, sample, cols["label"], cols["translation"], cols["size"], cols["yaw"], cols["score"])

    @classmethod
    def from_arrays(
        cls,
        tokens: Sequence[str],
        boxes: Sequence[np.ndarray],
        scores: Sequence[np.ndarray | None],
        labels: Sequence[np.ndarray],
    ) -> EvalBoxes:
        """Per-sample runtime boxes (K_i, 7) ``x, y, z_bottom, l, w, h, yaw``; a ``None`` score marks ground truth.

        The yaw goes through the record quaternion, so arrays and records evaluate identically.
        """
        if not (len(tokens) == len(boxes) == len(scores) == len(labels)):
            raise ValueError(
                "tokens, boxes, scores, labels: expected equal lengths, got "
                f"{len(tokens)}, {len(boxes)}, {len(scores)}, {len(labels)}"
            )
        parts = []
        for i, (b, s, lab) in enumerate(zip(boxes, scores, labels)):
            b = np.asarray(b, np.float64).reshape(-1, 7)
            k = len(b)
            s = np.full(k, GT_SCORE) if s is None else np.asarray(s, np.float64)
            lab = np.asarray(lab, np.int64)
            if s.shape != (k,) or lab.shape != (k,):
                raise ValueError(f"sample {tokens[i]}: scores {s.shape} and labels {lab.shape} must match {k} boxes")
            parts.append((np.full(k, i, np.int64), lab, b, s))
        if not parts:
            return cls.empty(tokens)
        sample, label, b, score = (np.concatenate(p) for p in zip(*parts))
        translation = b[:, :3].copy()
        translation[:, 2] += b[:, 5] / 2
        yaw = quaternion_to_yaw(yaw_to_quaternion(b[:, 6]))
        return cls(tuple(tokens), sample, label, translation, b[:, [4, 3, 5]], yaw, score)

    # -- selection ----------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.sample)

    def __getitem__(self, index: Any) -> EvalBoxes:
        """Rows by boolean mask or index array, same tokens."""
        return EvalBoxes(
            self.tokens,
            self.sample[index],
            self.label[index],
            self.translation[index],
            self.size[index],
            self.yaw[index],
            self.score[index],
        )

    def take(self, frames: Sequence[int] | np.ndarray) -> EvalBoxes:
        """The boxes of the samples ``frames`` (indices into ``tokens``), in that order, each draw a sample of its
        own: a frame drawn twice counts twice, as a bootstrap resample needs. Tokens become ``token#draw``."""
        frames = np.asarray(frames, np.int64).reshape(-1)
        if len(frames) and (frames.min() < 0 or frames.max() >= len(self.tokens)):
            raise ValueError(f"frames: indices must lie in [0, {len(self.tokens)})")
        order = np.argsort(self.sample, kind="stable")  # rows by sample, each sample's rows in their order
        counts = self.counts()
        starts = np.concatenate([[0], np.cumsum(counts)])[frames]
        n = counts[frames]
        first = np.repeat(np.cumsum(n) - n, n)  # where each drawn sample's rows begin in the output
        rows = order[np.repeat(starts, n) + np.arange(int(n.sum())) - first]
        tokens = tuple(f"{self.tokens[f]}#{i}" for i, f in enumerate(frames))
        return replace(self[rows], tokens=tokens, sample=np.repeat(np.arange(len(frames)), n))

    @property
    def ego_dist(self) -> np.ndarray:
        """(K,) distance of the gravity centre from the lidar origin in the x-y plane (m)."""
        return np.sqrt(self.translation[:, 0] ** 2 + self.translation[:, 1] ** 2)

    def by_class(self, num_classes: int, class_range: np.ndarray | None = None) -> list[EvalBoxes]:
        """One ``EvalBoxes`` per class id, rows in their original order; one sort and one gather, not C masks.

        With ``class_range`` only rows inside their class's range are kept (see ``in_range``).
        """
        if len(self) and (self.label.min() < 0 or self.label.max() >= num_classes):
            raise ValueError(
                f"label: expected class ids in [0, {num_classes}), got {self.label.min()}..{self.label.max()}"
            )
        rows = np.arange(len(self)) if class_range is None else np.nonzero(self.in_range(class_range))[0]
        rows = rows[np.argsort(self.label[rows], kind="stable")]
        bounds = np.searchsorted(self.label[rows], np.arange(num_classes + 1))
        return [self[rows[bounds[c] : bounds[c + 1]]] for c in range(num_classes)]

    def in_range(self, class_range: np.ndarray) -> np.ndarray:
        """(K,) True where the x-y distance is strictly below the class's range (metres, indexed by class id)."""
        limits = np.asarray(class_range, np.float64)
        return self.ego_dist < limits[self.label]

    def within_range(self, class_range: np.ndarray) -> EvalBoxes:
        """Rows inside their class's range."""
        return self[self.in_range(class_range)]

    def top_per_sample(self, k: int) -> EvalBoxes:
        """At most ``k`` highest-scoring rows per sample, kept in their original order (ties: earlier row)."""
        if k < 0:
            raise ValueError(f"k: expected a non-negative count, got {k}")
        order = np.lexsort((np.arange(len(self)), -self.score, self.sample))
        grouped = self.sample[order]
        first = np.searchsorted(grouped, grouped, side="left")
        keep = np.zeros(len(self), bool)
        keep[order[np.arange(len(order)) - first < k]] = True
        return self[keep]

    def counts(self) -> np.ndarray:
        """(S,) rows per sample."""
        return np.bincount(self.sample, minlength=len(self.tokens))
