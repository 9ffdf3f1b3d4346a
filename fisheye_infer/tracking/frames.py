"""Between the ego frame of one stamp and the world frame tracks live in, and the checks on what ``update`` is given.

    world = to_world(boxes, pose)              # (K, 7) ego boxes -> world boxes
    ego = from_world(world, pose)              # and back
    v_ego = velocities_to_ego(v_world, pose)
    c_ego = covariances_to_ego(c_world, pose)  # (K, 2, 2) bird's-eye-view covariances

A pose is a 4x4 ego-to-world matrix (the ego frame is the detections' frame: the lidar frame of
the dataset). Yaw turns with the pose's heading, the bird's-eye view's rotation about z.
"""

from __future__ import annotations

import math

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.detections import Detections

__all__ = ["to_world", "from_world", "velocities_to_ego", "covariances_to_ego", "check_pose", "check_update"]


def _heading(pose: np.ndarray) -> float:
    return math.atan2(pose[1, 0], pose[0, 0])


def to_world(boxes: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(K, 7) boxes in the ego frame -> the world frame (float64)."""
    out = np.array(boxes, np.float64).reshape(-1, 7)
    out[:, :3] = out[:, :3] @ pose[:3, :3].T + pose[:3, 3]
    out[:, 6] = out[:, 6] + _heading(pose)
    return out


def from_world(boxes: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(K, 7) boxes in the world frame -> the ego frame of ``pose`` (float64)."""
    out = np.array(boxes, np.float64).reshape(-1, 7)
    out[:, :3] = (out[:, :3] - pose[:3, 3]) @ pose[:3, :3]
    out[:, 6] = out[:, 6] - _heading(pose)
    return out


def velocities_to_ego(velocities: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(K, 2) world-frame velocities over ground, expressed in the ego frame's axes."""
    return np.asarray(velocities, np.float64).reshape(-1, 2) @ pose[:2, :2]


def covariances_to_ego(covariances: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(K, 2, 2) world-frame bird's-eye-view covariances, expressed in the ego frame's axes."""
    r = pose[:2, :2]
    return r.T @ np.asarray(covariances, np.float64).reshape(-1, 2, 2) @ r


def check_pose(pose: object) -> np.ndarray:
    """A 4x4 rigid ego-to-world matrix (float64), or a ``FrameError`` saying what is wrong."""
    try:
        m = np.asarray(pose, np.float64)
    except (TypeError, ValueError):
        raise FrameError(f"ego_pose: expected a 4x4 matrix of numbers, got {type(pose).__name__}") from None
    if m.shape != (4, 4):
        raise FrameError(f"ego_pose: expected a 4x4 ego-to-world matrix, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise FrameError("ego_pose: contains NaN or infinity")
    r = m[:3, :3]
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-5) or np.linalg.det(r) < 0 or not np.allclose(m[3], [0, 0, 0, 1]):
        raise FrameError("ego_pose: not a rigid transform (rotation not orthonormal or last row not 0, 0, 0, 1)")
    return m


def check_update(detections: object, stamp: object, last_stamp: float | None) -> float:
    """The stamp as a float after checking the arguments of ``update``; a ``FrameError`` names the problem."""
    if not isinstance(detections, Detections):
        raise FrameError(f"detections: expected a fisheye_infer Detections, got {type(detections).__name__}")
    if isinstance(stamp, bool) or not isinstance(stamp, (int, float, np.integer, np.floating)):
        raise FrameError(f"stamp: expected seconds as a number, got {type(stamp).__name__}")
    t = float(stamp)
    if not math.isfinite(t):
        raise FrameError(f"stamp: expected a finite number of seconds, got {t}")
    if last_stamp is not None and t <= last_stamp:
        raise FrameError(
            f"stamp: {t} s is not after the previous frame's {last_stamp} s; stamps must increase (reset() starts over)"
        )
    if not np.all(np.isfinite(detections.boxes)) or not np.all(np.isfinite(detections.scores)):
        raise FrameError("detections: boxes or scores contain NaN or infinity")
    return t
