"""``Tracker``: 3D multi-object tracking by detection, one ``update`` per frame.

    tracker = Tracker()                                  # TrackerConfig() settings
    for frame, stamp, pose in stream:
        tracks = tracker.update(detector.detect(frame), stamp, ego_pose=pose)
        tracks.ids, tracks.boxes, tracks.velocities     # confirmed tracks seen at this frame

Each frame: every live track is predicted to ``stamp`` by its class's motion model (a Kalman filter:
``motion``); detections at or above ``score_threshold`` are paired with the predictions by the
minimum total centre distance among same-class pairs within the gate (``associate.assign``); the
tracks left over then try the detections between ``low_score`` and ``score_threshold``, which
keep a track alive but never start one (SimpleTrack's two stages). Unpaired confident detections
start tentative tracks, confirmed after ``min_hits`` matches; a tentative track dies at its first
miss, a confirmed one after ``max_coast`` seconds without a match. A frame whose detections used
fewer cameras than the tracker has seen (``Detections.cameras_used``), or one flagged
``degraded``, counts no misses. With ego poses the tracks live in the world frame, so the robot's
own motion neither moves nor speeds them; without, in the ego frame. A track of a class with a
``parked_level`` whose velocity cannot be told from zero is reported standing still.

The time step is the difference of stamps (dropped frames just make a longer step); the same
inputs give the same tracks; at most ``max_tracks`` tracks live at once. The tracks of a class are
held as arrays (``_Bank``), so a frame costs a few array operations per class, not a filter per track;
association is class-aware, so solving it per class gives the same pairs as solving it whole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.tracking.associate import assign, centre_cost
from fisheye_infer.tracking.config import TrackerConfig
from fisheye_infer.tracking.frames import (
    check_pose,
    check_update,
    covariances_to_ego,
    from_world,
    to_world,
    velocities_to_ego,
)
from fisheye_infer.tracking.motion import MotionModel, wrap_angle
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["Tracker"]


@dataclass
class _Bank:
    """The live tracks of one class, as arrays, in the tracking frame (world with ego poses, else ego)."""

    model: MotionModel
    gate: float
    dim: int
    parked_level: float
    ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    x: np.ndarray = field(init=False)
    p: np.ndarray = field(init=False)
    # x, y: the last detection's; z and sizes smoothed; yaw: the filter's heading where it has one (_correct)
    box: np.ndarray = field(default_factory=lambda: np.zeros((0, 7)))
    score: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hits: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    age: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    missed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # seconds unmatched (degraded frames not counted)
    matched: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def __post_init__(self) -> None:
        self.x, self.p = np.zeros((0, self.dim)), np.zeros((0, self.dim, self.dim))

    def __len__(self) -> int:
        return len(self.ids)

    def keep(self, mask: np.ndarray) -> None:
        for name in ("ids", "x", "p", "box", "score", "hits", "age", "missed", "matched"):
            setattr(self, name, getattr(self, name)[mask])

    def add(self, ids: np.ndarray, boxes: np.ndarray, scores: np.ndarray) -> None:
        x, p = self.model.init(boxes)
        n = len(ids)
        self.ids, self.x, self.p = np.append(self.ids, ids), np.vstack([self.x, x]), np.concatenate([self.p, p])
        self.box, self.score = np.vstack([self.box, boxes]), np.append(self.score, scores)
        self.hits, self.age = np.append(self.hits, np.ones(n, np.int64)), np.append(self.age, np.zeros(n, np.int64))
        self.missed, self.matched = np.append(self.missed, np.zeros(n)), np.append(self.matched, np.ones(n, bool))

    def reach(self) -> np.ndarray:
        """Gate plus twice the predicted centre's standard deviation, per track."""
        return self.gate + 2.0 * np.sqrt(np.maximum(self.p[:, 0, 0], self.p[:, 1, 1]))


class Tracker:
    """3D multi-object tracking by detection: one [`update`][fisheye_infer.tracking.tracker.Tracker.update] per frame.

    Each frame, every live track is predicted to the frame's stamp by its class's motion model (a Kalman
    filter); detections at or above ``score_threshold`` are paired with the predictions by the minimum total
    centre distance among same-class pairs within the gate; the tracks left over then try the detections
    between ``low_score`` and ``score_threshold``, which keep a track alive but never start one. Unpaired
    confident detections start tentative tracks, confirmed after ``min_hits`` matches; a tentative track dies
    at its first miss, a confirmed one after ``max_coast`` seconds without a match. A frame whose detections
    used fewer cameras than the tracker has seen counts no misses. With ego poses the tracks live in the
    world frame, so the robot's own motion neither moves nor speeds them. The same inputs give the same tracks.

    Args:
        config (TrackerConfig | None): Thresholds, birth and death rules, per-class models (default:
            ``TrackerConfig()``; see [`TrackerConfig`][fisheye_infer.tracking.config.TrackerConfig]).

    Examples:
        ```python
        from fisheye_infer import Detector, Tracker

        detector, tracker = Detector("model.onnx"), Tracker()
        for frame, stamp, pose in stream:
            tracks = tracker.update(detector.detect(frame), stamp, ego_pose=pose)
            print(stamp, tracks.ids, tracks.velocities)
        tracker.reset()                  # before an unrelated stream
        ```
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self._next_id = 1
        self.reset()

    def reset(self) -> None:
        """Forget every track and the last stamp (ids keep counting, so an old id never names a new object)."""
        self._banks: dict[int, _Bank] = {}
        self._last_stamp: float | None = None
        self._class_names: tuple[str, ...] | None = None
        self._cameras_seen = 0

    @property
    def live(self) -> int:
        """Tracks held now, tentative and coasting ones included."""
        return sum(len(b) for b in self._banks.values())

    def update(
        self, detections: Detections, stamp: float, ego_pose: np.ndarray | None = None, degraded: bool | None = None
    ) -> Tracks:
        """Advance to ``stamp`` with this frame's detections.

        Args:
            detections (Detections): The frame's boxes in the ego frame (unthresholded output is fine).
            stamp (float): The frame's time, seconds; must increase from call to call.
            ego_pose (np.ndarray | None): 4x4 ego-to-world matrix of this frame; give one on every frame or on none.
            degraded (bool | None): The frame saw less than usual (no misses are counted); None: a frame whose
                detections used fewer cameras than seen before.

        Returns:
            Tracks: The confirmed tracks matched at this frame, boxes and velocities in this frame's ego frame.

        Raises:
            FrameError: ``detections`` is not a Detections or holds NaN, the stamp is not a finite number or does
                not increase, the pose is not a rigid 4x4 transform, or the class list changed.
        """
        t = check_update(detections, stamp, self._last_stamp)
        pose = None if ego_pose is None else check_pose(ego_pose)
        if self._class_names is None:
            self._class_names = detections.class_names
        elif detections.class_names != self._class_names:
            raise FrameError(
                f"detections: classes {list(detections.class_names)} differ from the tracker's "
                f"{list(self._class_names)}"
            )
        dt = 0.0 if self._last_stamp is None else t - self._last_stamp
        self._last_stamp = t
        cameras = len(detections.cameras_used)
        if degraded is None:
            degraded = cameras < self._cameras_seen
        self._cameras_seen = max(self._cameras_seen, cameras)

        cfg = self.config
        keep = detections.scores >= cfg.low_score
        boxes = np.asarray(detections.boxes[keep], np.float64)
        boxes = to_world(boxes, pose) if pose is not None else boxes
        scores = np.asarray(detections.scores[keep], np.float64)
        labels = np.asarray(detections.labels[keep], np.int64)
        high = scores >= cfg.score_threshold
        unused_high = high.copy()
        for label, bank in sorted(self._banks.items()):
            used = self._step(bank, label, boxes, scores, labels, high, dt, degraded)
            unused_high[used] = False
        self._births(boxes, scores, labels, np.flatnonzero(unused_high))
        return self._report(t, pose)

    def _step(
        self,
        bank: _Bank,
        label: int,
        boxes: np.ndarray,
        scores: np.ndarray,
        labels: np.ndarray,
        high: np.ndarray,
        dt: float,
        degraded: bool,
    ) -> np.ndarray:
        """Predict, associate (two stages), correct, and count misses and deaths of one class; returns the detection
        indices it took."""
        cfg = self.config
        bank.matched[:] = False
        if len(bank) and dt > 0:
            bank.x, bank.p = bank.model.predict(bank.x, bank.p, dt)
        mine = labels == label
        rows, cols = _pairs(bank, np.arange(len(bank)), boxes, np.flatnonzero(mine & high))
        bank.matched[rows] = True
        rest = np.flatnonzero(~bank.matched & (bank.hits >= cfg.min_hits))
        rows2, cols2 = _pairs(bank, rest, boxes, np.flatnonzero(mine & ~high))
        rows, cols = np.concatenate([rows, rows2]), np.concatenate([cols, cols2])
        if len(rows):
            self._correct(bank, rows, boxes[cols], scores[cols])
        if not degraded:
            missed = ~bank.matched
            bank.keep(~(missed & (bank.hits < cfg.min_hits)))  # a tentative track dies at its first miss
            bank.missed[~bank.matched] += dt
        bank.keep(bank.missed <= cfg.max_coast)
        bank.age += 1
        return cols

    def _correct(self, bank: _Bank, rows: np.ndarray, boxes: np.ndarray, scores: np.ndarray) -> None:
        """Kalman updates with the matched boxes; height and size smoothed, yaw from the filter's heading where it
        has one (turned by half a turn to the box's own), else the box's."""
        a = self.config.size_smoothing
        x, p = bank.model.update(bank.x[rows], bank.p[rows], boxes)
        new = boxes.copy()
        new[:, 2:6] = (1 - a) * bank.box[rows, 2:6] + a * boxes[:, 2:6]
        if x.shape[1] == 5:
            new[:, 6] += wrap_angle(x[:, 2] - new[:, 6], math.pi)
        bank.x[rows], bank.p[rows], bank.box[rows], bank.score[rows] = x, p, new, scores
        bank.hits[rows] += 1
        bank.missed[rows] = 0.0
        bank.matched[rows] = True

    def _births(self, boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray, index: np.ndarray) -> None:
        """Tentative tracks from unpaired confident detections, highest score first, within ``max_tracks``."""
        assert self._class_names is not None
        order = self._clear(boxes, labels, index[np.argsort(-scores[index], kind="stable")])
        room = self.config.max_tracks - self.live
        born = list(order[: max(room, 0)])
        for j in order[max(room, 0) :]:
            if not self._make_room(float(scores[j])):
                break
            born.append(j)
        ids = self._next_id + np.arange(len(born), dtype=np.int64)
        self._next_id += len(born)
        born_arr = np.array(born, np.int64)
        for label in sorted(set(labels[born_arr].tolist())):
            if label not in self._banks:
                cc = self.config.for_class(self._class_names[label])
                dim = cc.model.init(np.zeros((1, 7)))[0].shape[1]
                self._banks[label] = _Bank(cc.model, cc.gate, dim, cc.parked_level)
            mine = labels[born_arr] == label
            self._banks[label].add(ids[mine], boxes[born_arr[mine]], scores[born_arr[mine]])

    def _clear(self, boxes: np.ndarray, labels: np.ndarray, order: np.ndarray) -> np.ndarray:
        """The candidates of ``order`` (best first) not within ``birth_clearance`` of a live track of their class
        or of a better candidate kept."""
        gap = self.config.birth_clearance
        if gap <= 0 or not len(order):
            return order
        kept: list[int] = []
        for j in order.tolist():
            bank = self._banks.get(int(labels[j]))
            near = bank is not None and len(bank) and np.min(np.hypot(*(bank.x[:, :2] - boxes[j, :2]).T)) < gap
            if not near and all(
                labels[k] != labels[j] or math.hypot(*(boxes[k, :2] - boxes[j, :2])) >= gap for k in kept
            ):
                kept.append(j)
        return np.array(kept, np.int64)

    def _make_room(self, score: float) -> bool:
        """Drop the least certain track (tentative first, then longest unmatched, then lowest score) if a new one
        with ``score`` ranks above it."""
        worst: tuple[tuple[bool, float, float], int, int] | None = None
        for label, bank in self._banks.items():
            for k in range(len(bank)):
                rank = (bool(bank.hits[k] >= self.config.min_hits), -float(bank.missed[k]), float(bank.score[k]))
                if worst is None or rank < worst[0]:
                    worst = (rank, label, k)
        if worst is None or worst[0] >= (False, 0.0, score):
            return False
        bank = self._banks[worst[1]]
        bank.keep(np.arange(len(bank)) != worst[2])
        return True

    def _report(self, stamp: float, pose: np.ndarray | None) -> Tracks:
        assert self._class_names is not None
        parts = []
        for label, bank in self._banks.items():
            shown = bank.matched & (bank.hits >= self.config.min_hits)
            if shown.any():
                box = bank.box[shown].copy()
                box[:, :2] = bank.x[shown, :2]
                v = bank.model.velocity(bank.x[shown])
                if bank.parked_level:
                    v[bank.model.still(bank.x[shown], bank.p[shown], bank.parked_level)] = 0.0
                score = bank.score[shown] * (1 - self.config.young_weight ** bank.hits[shown])
                label_of = np.full(int(shown.sum()), label)
                covariances = bank.model.covariances(bank.x[shown], bank.p[shown])
                parts.append((bank.ids[shown], box, bank.box[shown], v, score, label_of, bank.age[shown], *covariances))
        if not parts:
            none = np.zeros((0, 2, 2), np.float32)
            return replace(
                Tracks.empty(self._class_names, stamp),
                position_covariances=none,
                velocity_covariances=none,
                detected_centres=np.zeros((0, 2), np.float32),
            )
        ids, boxes, detected, velocities, scores, labels, ages, position_cov, velocity_cov = (
            np.concatenate(c) for c in zip(*parts)
        )
        order = np.argsort(ids)
        boxes, detected, velocities, position_cov, velocity_cov = (
            a[order] for a in (boxes, detected, velocities, position_cov, velocity_cov)
        )
        if pose is not None:
            boxes, detected = from_world(boxes, pose), from_world(detected, pose)
            velocities = velocities_to_ego(velocities, pose)
            position_cov, velocity_cov = covariances_to_ego(position_cov, pose), covariances_to_ego(velocity_cov, pose)
        boxes[:, 6] = wrap_angle(boxes[:, 6])
        return Tracks(
            ids=ids[order].astype(np.int64),
            boxes=boxes.astype(np.float32),
            velocities=velocities.astype(np.float32),
            scores=scores[order].astype(np.float32),
            labels=labels[order].astype(np.int64),
            ages=ages[order].astype(np.int64),
            class_names=self._class_names,
            stamp=stamp,
            position_covariances=position_cov.astype(np.float32),
            velocity_covariances=velocity_cov.astype(np.float32),
            detected_centres=detected[:, :2].astype(np.float32),
        )


def _pairs(bank: _Bank, rows: np.ndarray, boxes: np.ndarray, dets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Optimal pairs (track row, detection index) among the bank's ``rows`` and the detections ``dets``."""
    if not len(rows) or not len(dets):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    same = np.zeros(len(rows), np.int64)
    cost, valid = centre_cost(
        bank.x[rows, :2], same, boxes[dets, :2], np.zeros(len(dets), np.int64), bank.reach()[rows]
    )
    r, c = assign(cost, valid)
    return rows[r], dets[c]
