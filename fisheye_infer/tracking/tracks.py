"""``Tracks``: what a tracker reports for one frame, as equal-length numpy arrays.

    tracks = tracker.update(detections, stamp)
    for i, box, v in zip(tracks.ids, tracks.boxes, tracks.velocities): ...
    tracks.to_nuscenes()            # nuScenes tracking results records
    tracks.detection_records()      # detection records with the velocity filled from the track

Boxes are (K, 7) ``x, y, z_bottom, l, w, h, yaw`` in the frame of the detections they came from
(the ego frame at ``stamp``); velocities are over ground (the ego's own motion taken out when the
tracker was given ego poses), in that frame's axes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from fisheye_infer.runtime.box_geometry import check_boxes
from fisheye_infer.runtime.records import boxes_to_records

__all__ = ["Tracks"]


@dataclass(frozen=True)
class Tracks:
    """The tracks of one frame that a detection confirmed at ``stamp``, in order of track id.

    Boxes are in the frame of the detections they came from (the ego frame at ``stamp``); velocities are over
    ground (the ego's own motion taken out when the tracker was given ego poses), in that frame's axes.

    Attributes:
        ids (np.ndarray): `(K,)` int64 track ids, unique while the tracker lives (never reused, even after a reset).
        boxes (np.ndarray): `(K, 7)` float32 ``x, y, z_bottom, l, w, h, yaw``, metres and radians.
        velocities (np.ndarray): `(K, 2)` float32 velocities over ground, m/s (a ``Tracker`` reports exactly 0 for
            a vehicle it cannot tell from standing still: ``ClassConfig.parked_level``).
        scores (np.ndarray): `(K,)` float32 score of each track: the detection's at this frame (a ``Tracker``
            weights young tracks down by ``TrackerConfig.young_weight``).
        labels (np.ndarray): `(K,)` int64 class indices into ``class_names``.
        ages (np.ndarray): `(K,)` int64 frames since each track was born (0 on its first frame).
        class_names (tuple[str, ...]): Class names, in label order.
        stamp (float): The frame's time, seconds.
        position_covariances (np.ndarray | None): `(K, 2, 2)` float32 covariance of each bird's-eye-view centre,
            m^2, in the boxes' frame; None where the tracker keeps none (``GreedyTracker``).
        velocity_covariances (np.ndarray | None): `(K, 2, 2)` float32 covariance of each velocity, (m/s)^2, in the
            boxes' frame (the filter's, also where the velocity is reported as 0); None where the tracker keeps none.
        detected_centres (np.ndarray | None): `(K, 2)` float32 bird's-eye-view centre of the detection each track
            took at this frame, in the boxes' frame (a ``Tracker``'s boxes hold the filter's centres); None where
            the boxes' centres are the detections' (``GreedyTracker``).

    Raises:
        ValueError: An array's shape disagrees with ``boxes``.
    """

    ids: np.ndarray  # (K,) int64, unique while the tracker lives (and after a reset: never reused)
    boxes: np.ndarray  # (K, 7) float32
    velocities: np.ndarray  # (K, 2) float32, m/s over ground
    scores: np.ndarray  # (K,) float32, the score of the detection the track took at this frame
    labels: np.ndarray  # (K,) int64
    ages: np.ndarray  # (K,) int64, frames since the track was born (0 on its first frame)
    class_names: tuple[str, ...]
    stamp: float = 0.0
    position_covariances: np.ndarray | None = None  # (K, 2, 2) float32, m^2
    velocity_covariances: np.ndarray | None = None  # (K, 2, 2) float32, (m/s)^2
    detected_centres: np.ndarray | None = None  # (K, 2) float32, m

    def __post_init__(self) -> None:
        check_boxes(self.boxes)
        k = len(self.boxes)
        shapes = {"ids": (k,), "velocities": (k, 2), "scores": (k,), "labels": (k,), "ages": (k,)}
        for name in ("position_covariances", "velocity_covariances"):
            if getattr(self, name) is not None:
                shapes[name] = (k, 2, 2)
        if self.detected_centres is not None:
            shapes["detected_centres"] = (k, 2)
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"{name}: expected shape {shape} to match boxes, got {np.shape(getattr(self, name))}")

    @classmethod
    def empty(cls, class_names: Sequence[str], stamp: float = 0.0) -> Tracks:
        """No tracks.

        Args:
            class_names (Sequence[str]): Class names, in label order.
            stamp (float): The frame's time, seconds.

        Returns:
            Tracks: An object with K = 0.
        """
        z = np.zeros(0, np.int64)
        return cls(
            z, np.zeros((0, 7), np.float32), np.zeros((0, 2), np.float32), np.zeros(0, np.float32), z, z,
            tuple(class_names), float(stamp),
        )  # fmt: skip

    def __len__(self) -> int:
        return len(self.ids)

    def __getitem__(self, index: Any) -> Tracks:
        """Select by integer array, slice or boolean mask; returns a new ``Tracks``."""
        if isinstance(index, (int, np.integer)):
            index = [index]
        optional = (self.position_covariances, self.velocity_covariances, self.detected_centres)
        return Tracks(
            self.ids[index], self.boxes[index], self.velocities[index], self.scores[index], self.labels[index],
            self.ages[index], self.class_names, self.stamp, *(a if a is None else a[index] for a in optional),
        )  # fmt: skip

    @property
    def names(self) -> list[str]:
        """Class name of each track."""
        return [self.class_names[i] for i in self.labels]

    def detection_records(self) -> list[dict[str, Any]]:
        """Detection records with the velocity filled in from the track.

        Returns:
            list[dict[str, Any]]: One record per track, as
                [`Detections.to_nuscenes`][fisheye_infer.runtime.detections.Detections.to_nuscenes] writes them,
                with ``velocity`` (vx, vy, m/s).
        """
        records = boxes_to_records(self.boxes, self.scores, self.labels, self.class_names)
        for record, v in zip(records, self.velocities.tolist()):
            record["velocity"] = [float(v[0]), float(v[1])]
        return records

    def to_nuscenes(self) -> list[dict[str, Any]]:
        """nuScenes tracking results records, as the tracking evaluation reads them.

        Returns:
            list[dict[str, Any]]: One record per track: ``translation``, ``size``, ``rotation``, ``velocity``,
                ``tracking_id`` (a string), ``tracking_name``, ``tracking_score``.
        """
        out = []
        for record, track_id in zip(self.detection_records(), self.ids.tolist()):
            out.append(
                {
                    "translation": record["translation"],
                    "size": record["size"],
                    "rotation": record["rotation"],
                    "velocity": record["velocity"],
                    "tracking_id": str(track_id),
                    "tracking_name": record["detection_name"],
                    "tracking_score": record["detection_score"],
                }
            )
        return out

    def to_dicts(self) -> list[dict[str, Any]]:
        """One plain dict per track, in this object's layout (bottom-centred, ego frame).

        Returns:
            list[dict[str, Any]]: ``track_id, x, y, z_bottom, l, w, h, yaw, vx, vy, score, label, class_name,
                age, position_covariance, velocity_covariance`` per track (each covariance 2x2 nested lists, or
                None where the tracker keeps none).
        """
        keys = ("x", "y", "z_bottom", "l", "w", "h", "yaw")
        count = len(self)
        position = [None] * count if self.position_covariances is None else self.position_covariances.tolist()
        velocity = [None] * count if self.velocity_covariances is None else self.velocity_covariances.tolist()
        return [
            {
                "track_id": int(i),
                **{k: float(v) for k, v in zip(keys, box)},
                "vx": float(v[0]),
                "vy": float(v[1]),
                "score": float(s),
                "label": int(label),
                "class_name": self.class_names[label],
                "age": int(a),
                "position_covariance": pc,
                "velocity_covariance": vc,
            }
            for i, box, v, s, label, a, pc, vc in zip(
                self.ids, self.boxes, self.velocities, self.scores, self.labels, self.ages, position, velocity
            )
        ]
