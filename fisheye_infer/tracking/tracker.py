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
own motion neither moves nor speeds them; without, in the ego frame.

The time step is the difference of stamps (dropped frames just make a longer step); the same
inputs give the same tracks; at most ``max_tracks`` tracks live at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.tracking.associate import assign, centre_cost
from fisheye_infer.tracking.config import TrackerConfig
from fisheye_infer.tracking.frames import check_pose, check_update, from_world, to_world, velocities_to_ego
from fisheye_infer.tracking.motion import MotionModel, wrap_angle
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["Tracker"]


@dataclass
class _Track:
    """One live track, in the tracking frame (world with ego poses, else ego)."""

    id: int
    label: int
    model: MotionModel
    gate: float
    x: np.ndarray
    p: np.ndarray
    box: np.ndarray  # (7,) float64: the smoothed box; x, y come from the filter
    score: float
    hits: int = 1
    age: int = 0
    missed: float = 0.0  # seconds unmatched (degraded frames not counted)
    matched: bool = True

    def reach(self) -> float:
        """Gate plus twice the predicted centre's standard deviation."""
        return self.gate + 2.0 * math.sqrt(max(self.p[0, 0], self.p[1, 1]))


class Tracker:
    """Tracks of the boxes of a stream of frames; see the module docstring for the algorithm.

    Args:
        config (TrackerConfig | None): Thresholds, birth and death rules, per-class models (default:
            ``TrackerConfig()``).
    """

    def __init__(self, config: TrackerConfig | None = None) -> None:
        self.config = config or TrackerConfig()
        self._next_id = 1
        self.reset()

    def reset(self) -> None:
        """Forget every track and the last stamp (ids keep counting, so an old id never names a new object)."""
        self._tracks: list[_Track] = []
        self._last_stamp: float | None = None
        self._class_names: tuple[str, ...] | None = None
        self._cameras_seen = 0

    @property
    def live(self) -> int:
        """Tracks held now, tentative and coasting ones included."""
        return len(self._tracks)

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

        for tr in self._tracks:
            if dt > 0:
                tr.x, tr.p = tr.model.predict(tr.x, tr.p, dt)
            tr.matched = False
        pairs = self._associate(boxes, labels, np.flatnonzero(high), self._tracks)
        rest = [tr for tr in self._tracks if not tr.matched and tr.hits >= cfg.min_hits]
        pairs += self._associate(boxes, labels, np.flatnonzero(~high), rest)
        used = np.zeros(len(boxes), bool)
        for tr, j in pairs:
            self._correct(tr, boxes[j], float(scores[j]))
            used[j] = True

        survivors = []
        for tr in self._tracks:
            if not tr.matched and not degraded:
                if tr.hits < cfg.min_hits:
                    continue
                tr.missed += dt
            if tr.missed > cfg.max_coast:
                continue
            tr.age += 1
            survivors.append(tr)
        self._tracks = survivors
        self._births(boxes, scores, labels, np.flatnonzero(high & ~used))
        return self._report(t, pose)

    def _associate(
        self, boxes: np.ndarray, labels: np.ndarray, det_index: np.ndarray, tracks: list[_Track]
    ) -> list[tuple[_Track, int]]:
        """Pairs (track, detection index) among ``tracks`` and the detections ``det_index``."""
        if not len(tracks) or not len(det_index):
            return []
        track_xy = np.array([tr.x[:2] for tr in tracks])
        track_labels = np.array([tr.label for tr in tracks], np.int64)
        gates = np.array([tr.reach() for tr in tracks])
        cost, valid = centre_cost(track_xy, track_labels, boxes[det_index, :2], labels[det_index], gates)
        rows, cols = assign(cost, valid)
        return [(tracks[i], int(det_index[j])) for i, j in zip(rows, cols)]

    def _correct(self, tr: _Track, box: np.ndarray, score: float) -> None:
        """Kalman update with a matched box; height and size smoothed, yaw from the filter's heading where it has
        one (turned by half a turn to the box's own), else the box's."""
        tr.x, tr.p = tr.model.update(tr.x, tr.p, box)
        a = self.config.size_smoothing
        tr.box[2:6] = (1 - a) * tr.box[2:6] + a * box[2:6]
        tr.box[6] = box[6] + float(wrap_angle(tr.x[2] - box[6], math.pi)) if len(tr.x) == 5 else box[6]
        tr.score, tr.hits, tr.missed, tr.matched = score, tr.hits + 1, 0.0, True

    def _births(self, boxes: np.ndarray, scores: np.ndarray, labels: np.ndarray, index: np.ndarray) -> None:
        """Tentative tracks from unpaired confident detections, highest score first, within ``max_tracks``."""
        assert self._class_names is not None
        cfg = self.config
        for j in index[np.argsort(-scores[index], kind="stable")]:
            if len(self._tracks) >= cfg.max_tracks and not self._make_room(float(scores[j])):
                break
            cc = cfg.for_class(self._class_names[labels[j]])
            x, p = cc.model.init(boxes[j])
            track = _Track(self._next_id, int(labels[j]), cc.model, cc.gate, x, p, boxes[j].copy(), float(scores[j]))
            self._tracks.append(track)
            self._next_id += 1

    def _make_room(self, score: float) -> bool:
        """Drop the least certain track (tentative first, then longest unmatched, then lowest score) if a new one
        with ``score`` ranks above it."""
        rank = [(tr.hits >= self.config.min_hits, -tr.missed, tr.score) for tr in self._tracks]
        worst = min(range(len(rank)), key=rank.__getitem__)
        if rank[worst] >= (False, 0.0, score):
            return False
        del self._tracks[worst]
        return True

    def _report(self, stamp: float, pose: np.ndarray | None) -> Tracks:
        assert self._class_names is not None
        shown = [tr for tr in self._tracks if tr.matched and tr.hits >= self.config.min_hits]
        shown.sort(key=lambda tr: tr.id)
        if not shown:
            return Tracks.empty(self._class_names, stamp)
        boxes = np.array([tr.box for tr in shown])
        boxes[:, :2] = [tr.x[:2] for tr in shown]
        velocities = np.array([tr.model.velocity(tr.x) for tr in shown])
        if pose is not None:
            boxes, velocities = from_world(boxes, pose), velocities_to_ego(velocities, pose)
        boxes[:, 6] = wrap_angle(boxes[:, 6])
        return Tracks(
            ids=np.array([tr.id for tr in shown], np.int64),
            boxes=boxes.astype(np.float32),
            velocities=velocities.astype(np.float32),
            scores=np.array([tr.score for tr in shown], np.float32),
            labels=np.array([tr.label for tr in shown], np.int64),
            ages=np.array([tr.age for tr in shown], np.int64),
            class_names=self._class_names,
            stamp=stamp,
        )
