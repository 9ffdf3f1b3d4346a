"""Run a detector and a tracker over the sequences of a split: what ``fisheye-infer eval --tracking`` scores.

    sequences = read_sequences(root, "val")
    results = track_sequences(run_on(detector, Fisheye3DOD(root, "val")), sequences, Tracker())
    report = evaluate_tracking(results)

Each sequence starts from a reset tracker; frames go in time order with their stamps and ego poses, so
the tracks live in the world frame. ``ground_truth_records`` turns a frame's labels into the records the
metric reads (``tracking_id`` = the instance id).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.sequences import TrackingFrame, TrackingSequence
from fisheye_infer.eval.tracking import SequenceResults
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.records import boxes_to_records
from fisheye_infer.tracking.smoothing import smooth_velocities
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["StreamTracker", "ground_truth_records", "run_on", "track_sequences"]


class StreamTracker(Protocol):
    """What ``track_sequences`` needs of a tracker (``Tracker``, ``GreedyTracker``)."""

    def reset(self) -> None: ...

    def update(self, detections: Detections, stamp: float, ego_pose: np.ndarray | None = None) -> Tracks: ...


def ground_truth_records(frame: TrackingFrame, class_names: Sequence[str]) -> list[dict[str, Any]]:
    """A frame's labels as tracking records: ``translation`` (lidar frame), ``tracking_id``, ``tracking_name``."""
    records = boxes_to_records(frame.gt_boxes, None, frame.gt_labels, class_names)
    return [
        {**r, "tracking_id": str(int(i)), "tracking_name": r["detection_name"], "velocity": [float(v) for v in vel]}
        for r, i, vel in zip(records, frame.gt_ids, frame.gt_velocities)
    ]


def run_on(detector: Detector, dataset: Fisheye3DOD) -> Callable[[int], Detections]:
    """Detections of a frame of ``dataset`` by its split index (cameras the dataset leaves out are missing)."""
    return lambda index: detector.detect(dict(dataset.image_paths(index)))


def track_sequences(
    detect: Callable[[int], Detections],
    sequences: Sequence[TrackingSequence],
    tracker: StreamTracker,
    progress: Callable[[int], None] | None = None,
    smooth: float = 0.0,
) -> list[SequenceResults]:
    """Detections and tracks of every frame of ``sequences``, with the ground truth, for ``evaluate_tracking``.

    Args:
        detect (Callable[[int], Detections]): A frame's detections from its split index (``run_on`` a detector,
            noisy ground truth, saved output).
        sequences (Sequence[TrackingSequence]): The split's sequences (``read_sequences``).
        tracker (StreamTracker): Reset at each sequence.
        progress (Callable[[int], None] | None): Called with the count of frames done.
        smooth (float): > 0: each sequence's velocities fitted after the fact, to each track's centres this many
            seconds either side (``smooth_velocities``); 0: the tracker's own.

    Returns:
        list[SequenceResults]: One per sequence.

    Raises:
        ValueError: ``smooth`` is not a number of seconds >= 0.
    """
    if not 0 <= smooth < math.inf:
        raise ValueError(f"smooth: expected seconds >= 0, got {smooth}")
    out, done = [], 0
    for seq in sequences:
        tracker.reset()
        gt, history = [], []
        for frame in seq.frames:
            dets = detect(frame.split_index)
            history.append(tracker.update(dets, frame.stamp, ego_pose=frame.ego_pose))
            gt.append(ground_truth_records(frame, dets.class_names))
            done += 1
            if progress is not None:
                progress(done)
        poses = np.stack([f.ego_pose for f in seq.frames])
        if smooth > 0:
            history = smooth_velocities(history, list(poses), smooth)
        pred = [tracks.to_nuscenes() for tracks in history]
        out.append(SequenceResults(seq.name, [f.stamp for f in seq.frames], poses, gt, pred))
    return out
