"""A picture of tracks: each track's box and id projected into the camera images, and a bird's-eye view with
its velocity arrow and recent path.

    paths = TrackPaths()
    for images, stamp, pose in stream:
        tracks = tracker.update(detector.detect(images), stamp, ego_pose=pose)
        paths.add(tracks, pose)
    save_png("tracks.png", draw_tracks(tracks, detector.info.rig, images, paths.in_ego(pose)))
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping

import cv2
import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.tools.viz import _text, bev_pixels, class_colour, draw_detections
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["TrackPaths", "draw_tracks"]

#: Seconds of motion a velocity arrow spans.
ARROW_S = 1.0
_SPAN = np.array([0.0, ARROW_S])


class TrackPaths:
    """The recent centres of each track, in the world frame (or the ego frame when there are no poses).

    Args:
        points (int): Centres kept per track (the newest).
    """

    def __init__(self, points: int = 20) -> None:
        self.points = points
        self._paths: dict[int, deque[np.ndarray]] = {}

    def add(self, tracks: Tracks, ego_pose: np.ndarray | None = None) -> None:
        """Append a frame's track centres.

        Args:
            tracks (Tracks): The frame's tracks (ego frame).
            ego_pose (np.ndarray | None): 4x4 ego-to-world matrix of the frame; None keeps ego-frame centres.
        """
        centres = tracks.boxes[:, :2].astype(np.float64)
        if ego_pose is not None:
            centres = centres @ ego_pose[:2, :2].T + ego_pose[:2, 3]
        for track_id, centre in zip(tracks.ids.tolist(), centres):
            self._paths.setdefault(track_id, deque(maxlen=self.points)).append(centre)

    def in_ego(self, ego_pose: np.ndarray | None = None) -> dict[int, np.ndarray]:
        """Every track's path in the ego frame of a pose.

        Args:
            ego_pose (np.ndarray | None): 4x4 ego-to-world matrix of the frame to draw in; None: paths as kept.

        Returns:
            dict[int, np.ndarray]: Track id -> `(n, 2)` centres, oldest first.
        """
        out = {}
        for track_id, path in self._paths.items():
            xy = np.array(path)
            if ego_pose is not None:
                xy = (xy - ego_pose[:2, 3]) @ ego_pose[:2, :2]
            out[track_id] = xy
        return out


def draw_tracks(
    tracks: Tracks,
    rig: Rig,
    images: Mapping[str, np.ndarray | None] | None = None,
    paths: Mapping[int, np.ndarray] | None = None,
    tile: int = 400,
) -> np.ndarray:
    """The camera images with each track's box and ``#id speed`` label, beside a bird's-eye view that adds each
    track's velocity (an arrow over ``ARROW_S`` seconds of motion) and its recent path.

    Args:
        tracks (Tracks): The frame's tracks ([`Tracks`][fisheye_infer.tracking.tracks.Tracks]).
        rig (Rig): The cameras to project through (a detector's ``info.rig``).
        images (Mapping[str, np.ndarray | None] | None): Camera name -> `(H, W, 3)` uint8 BGR image.
        paths (Mapping[int, np.ndarray] | None): Track id -> `(n, 2)` recent ego-frame centres, oldest first
            ([`TrackPaths.in_ego`][fisheye_infer.tools.track_viz.TrackPaths.in_ego]).
        tile (int): Side of each camera's tile, pixels.

    Returns:
        np.ndarray: One BGR uint8 picture, as
            [`draw_detections`][fisheye_infer.tools.viz.draw_detections] lays it out.
    """
    boxes = Detections(tracks.boxes, tracks.scores, tracks.labels, tracks.class_names)
    speeds = np.hypot(tracks.velocities[:, 0], tracks.velocities[:, 1])
    labels = [f"#{i} {s:.1f} m/s" for i, s in zip(tracks.ids.tolist(), speeds.tolist())]
    picture = draw_detections(boxes, rig, images, tile, labels=labels)
    size = picture.shape[0]
    bev = np.ascontiguousarray(picture[:, -size:])
    for track_id, box, v, name in zip(tracks.ids.tolist(), tracks.boxes, tracks.velocities, tracks.names):
        colour = class_colour(name)
        path = None if paths is None else paths.get(track_id)
        if path is not None and len(path) > 1:
            line = np.round(bev_pixels(path[:, 0], path[:, 1], size)).astype(np.int32)
            cv2.polylines(bev, [line], False, colour, 2, cv2.LINE_AA)
        if v.any():
            ends = np.round(bev_pixels(box[0] + _SPAN * v[0], box[1] + _SPAN * v[1], size))
            start, end = ((int(c), int(r)) for c, r in ends)
            cv2.arrowedLine(bev, start, end, (40, 40, 40), 2, cv2.LINE_AA, tipLength=0.25)
    _text(bev, f"arrows: {ARROW_S:g} s of motion; lines: recent path", (10, size - 12))
    picture[:, -size:] = bev
    return picture
