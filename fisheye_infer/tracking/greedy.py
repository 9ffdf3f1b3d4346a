"""``GreedyTracker``: CenterPoint's tracking, the simplest reasonable baseline for ``Tracker``.

    baseline = GreedyTracker(score_threshold=0.3)
    tracks = baseline.update(detections, stamp, ego_pose=pose)

Each track is its last matched centre and a velocity, the difference of its last two centres over
their time apart (CenterPoint's head predicts the velocity; these detections carry none). Each
frame, the tracks are moved by velocity x time, and the detections, highest score first, each take
the nearest free track of their class within the class's gate (``associate.greedy_assign``). An
unpaired detection starts a track at once; a track dies after ``max_age`` frames unmatched. It
reports every track matched at this frame, with no filter, no second stage and no confirmation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fisheye_infer.errors import FrameError, OptionError
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.tracking.associate import centre_cost, greedy_assign
from fisheye_infer.tracking.config import DEFAULT_CLASSES
from fisheye_infer.tracking.frames import check_pose, check_update, from_world, to_world, velocities_to_ego
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["GreedyTracker"]


@dataclass
class _Track:
    id: int
    label: int
    box: np.ndarray  # (7,) float64, the last matched box
    velocity: np.ndarray  # (2,)
    stamp: float  # of the last match
    score: float
    age: int = 0
    misses: int = 0


class GreedyTracker:
    """Greedy nearest-centre tracking with velocity projection (CenterPoint's), the baseline for ``Tracker``.

    Each track is its last matched box and a velocity, the difference of its last two centres over their
    time apart. Each frame the tracks are moved by velocity x time, and the detections, highest score first,
    each take the nearest free track of their class within the class's gate; an unpaired detection starts a
    track at once. Every track matched at this frame is reported: no filter, no second stage, no confirmation.

    Args:
        score_threshold (float): Detections below it are ignored.
        max_age (int): Frames a track survives unmatched.
        gates (dict[str, float] | None): Gate per class name, metres (default: the ``Tracker``'s class gates);
            a class not named gets 3 m.

    Raises:
        OptionError: ``score_threshold`` is outside [0, 1] or ``max_age`` is not an integer >= 0.
    """

    def __init__(self, score_threshold: float = 0.3, max_age: int = 3, gates: dict[str, float] | None = None) -> None:
        if not 0 <= score_threshold <= 1:
            raise OptionError(f"score_threshold: expected a number in [0, 1], got {score_threshold!r}")
        if not isinstance(max_age, int) or max_age < 0:
            raise OptionError(f"max_age: expected an integer >= 0, got {max_age!r}")
        self.score_threshold, self.max_age = float(score_threshold), max_age
        self.gates = gates if gates is not None else {name: cc.gate for name, cc in DEFAULT_CLASSES.items()}
        self._next_id = 1
        self.reset()

    def reset(self) -> None:
        """Forget every track and the last stamp."""
        self._tracks: list[_Track] = []
        self._last_stamp: float | None = None

    def update(self, detections: Detections, stamp: float, ego_pose: np.ndarray | None = None) -> Tracks:
        """Advance to ``stamp`` with this frame's detections; as ``Tracker.update``.

        Args:
            detections (Detections): The frame's boxes in the ego frame.
            stamp (float): The frame's time, seconds; must increase from call to call.
            ego_pose (np.ndarray | None): 4x4 ego-to-world matrix of this frame.

        Returns:
            Tracks: The tracks matched or started at this frame.

        Raises:
            FrameError: The detections, stamp or pose are unusable, as for ``Tracker.update``.
        """
        t = check_update(detections, stamp, self._last_stamp)
        pose = None if ego_pose is None else check_pose(ego_pose)
        if self._tracks and len(detections.class_names) <= max(tr.label for tr in self._tracks):
            raise FrameError("detections: fewer classes than the tracks were started with")
        self._last_stamp = t
        keep = detections.scores >= self.score_threshold
        order = np.argsort(-detections.scores[keep], kind="stable")
        boxes = np.asarray(detections.boxes[keep], np.float64)[order]
        boxes = to_world(boxes, pose) if pose is not None else boxes
        scores = np.asarray(detections.scores[keep], np.float64)[order]
        labels = np.asarray(detections.labels[keep], np.int64)[order]
        names = detections.class_names

        predicted = np.array([tr.box[:2] + tr.velocity * (t - tr.stamp) for tr in self._tracks]).reshape(-1, 2)
        track_labels = np.array([tr.label for tr in self._tracks], np.int64)
        gates = np.array([self.gates.get(names[label], 3.0) for label in labels])
        cost, valid = centre_cost(boxes[:, :2], labels, predicted, track_labels, gates)
        rows, cols = greedy_assign(cost, valid)
        matched = dict(zip(cols.tolist(), rows.tolist()))

        survivors, shown = [], []
        for k, tr in enumerate(self._tracks):
            j = matched.get(k)
            if j is None:
                tr.misses += 1
                if tr.misses <= self.max_age:
                    tr.age += 1
                    survivors.append(tr)
                continue
            tr.velocity = (boxes[j, :2] - tr.box[:2]) / (t - tr.stamp)
            tr.box, tr.stamp, tr.score, tr.misses = boxes[j].copy(), t, float(scores[j]), 0
            tr.age += 1
            survivors.append(tr)
            shown.append(tr)
        for j in sorted(set(range(len(boxes))) - set(rows.tolist())):
            tr = _Track(self._next_id, int(labels[j]), boxes[j].copy(), np.zeros(2), t, float(scores[j]))
            self._next_id += 1
            survivors.append(tr)
            shown.append(tr)
        self._tracks = survivors
        return _report(sorted(shown, key=lambda tr: tr.id), names, t, pose)


def _report(shown: list[_Track], class_names: tuple[str, ...], stamp: float, pose: np.ndarray | None) -> Tracks:
    if not shown:
        return Tracks.empty(class_names, stamp)
    boxes = np.array([tr.box for tr in shown])
    velocities = np.array([tr.velocity for tr in shown])
    if pose is not None:
        boxes, velocities = from_world(boxes, pose), velocities_to_ego(velocities, pose)
    return Tracks(
        ids=np.array([tr.id for tr in shown], np.int64),
        boxes=boxes.astype(np.float32),
        velocities=velocities.astype(np.float32),
        scores=np.array([tr.score for tr in shown], np.float32),
        labels=np.array([tr.label for tr in shown], np.int64),
        ages=np.array([tr.age for tr in shown], np.int64),
        class_names=class_names,
        stamp=stamp,
    )
