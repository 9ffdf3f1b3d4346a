"""CARLA sensor poses (``sensor_metadata.txt``) to cam2lidar matrices, as Fisheye3DOD builds them.

CARLA's world frame is left-handed (x forward, y right, z up, angles in degrees). Fisheye3DOD
converts each pose to its right-handed lidar convention by negating y, pitch and yaw, then
builds the matrix with CARLA's own formula. That conversion ("compat") is exact only when the
sensors have no pitch or roll relative to the world; it is what the released checkpoints were
trained with, so it is the default. The "exact" convention reflects the transform properly
(S M S with S = diag(1, -1, 1)) and is meant for new rigs and models trained with it.

Whether the Fisheye3DOD fisheyes are pitched (which would make the two conventions differ) is not
stated in the official code; the shipped rig's extrinsics settle it: every optical axis is within
0.1 degree of horizontal (tests/runtime/test_rig.py). For such a level mount the two conventions
give the same relative rotation; the translations differ only through the vehicle's own world
pitch and roll (spec camera-data-metric.md §2.3).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from fisheye_infer.errors import RigError

__all__ = [
    "CarlaPose",
    "Convention",
    "parse_sensor_metadata",
    "read_sensor_metadata",
    "pose_matrix",
    "cam2lidar_from_poses",
    "CAM_TO_SENSOR",
]

Convention = Literal["compat", "exact"]

#: Camera (OpenCV: x right, y down, z forward) to sensor (x forward, y left, z up) axes.
CAM_TO_SENSOR = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

_NUMBER = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_RECORD = re.compile(
    r"frame=(\d+),.*?Transform\(Location\(x=" + _NUMBER + r",\s*y=" + _NUMBER + r",\s*z=" + _NUMBER + r"\),\s*"
    r"Rotation\(pitch=" + _NUMBER + r",\s*yaw=" + _NUMBER + r",\s*roll=" + _NUMBER + r"\)\)"
)


@dataclass(frozen=True)
class CarlaPose:
    """A sensor's world pose as CARLA prints it: metres and degrees, left-handed frame."""

    x: float
    y: float
    z: float
    pitch: float
    yaw: float
    roll: float


def parse_sensor_metadata(text: str) -> dict[str, CarlaPose]:
    """Frame id (zero-padded to 8 digits) -> pose, for every record in a ``sensor_metadata.txt``."""
    poses: dict[str, CarlaPose] = {}
    for m in _RECORD.finditer(text):
        frame, *values = m.groups()
        x, y, z, pitch, yaw, roll = (float(v) for v in values)
        poses[f"{int(frame):08d}"] = CarlaPose(x, y, z, pitch, yaw, roll)
    return poses


def read_sensor_metadata(path: str | Path) -> dict[str, CarlaPose]:
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RigError(f"sensor metadata {path}: cannot be read ({exc.strerror})") from exc
    poses = parse_sensor_metadata(text)
    if not poses:
        raise RigError(f"sensor metadata {path}: no 'frame=..., Transform(Location(...), Rotation(...))' record found")
    return poses


def _rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def pose_matrix(pose: CarlaPose, convention: Convention = "compat") -> np.ndarray:
    """4x4 sensor-to-world in the right-handed (y-flipped) frame.

    compat: R = Rz(-yaw) Ry(pitch) Rx(-roll), as Fisheye3DOD computes it.
    exact:  R = Rz(-yaw) Ry(-pitch) Rx(roll), the true reflection of CARLA's transform.
    """
    roll, pitch, yaw = np.radians([pose.roll, pose.pitch, pose.yaw])
    if convention == "compat":
        rot = _rot_z(-yaw) @ _rot_y(pitch) @ _rot_x(-roll)
    elif convention == "exact":
        rot = _rot_z(-yaw) @ _rot_y(-pitch) @ _rot_x(roll)
    else:
        raise RigError(f"convention: expected 'compat' or 'exact', got {convention!r}")
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = (pose.x, -pose.y, pose.z)
    return m


def cam2lidar_from_poses(camera: CarlaPose, lidar: CarlaPose, convention: Convention = "compat") -> np.ndarray:
    """cam2lidar = inv(lidar2world) . cam2world . [CAM_TO_SENSOR 0; 0 1], float64."""
    to_sensor = np.eye(4)
    to_sensor[:3, :3] = CAM_TO_SENSOR
    return np.linalg.inv(pose_matrix(lidar, convention)) @ pose_matrix(camera, convention) @ to_sensor
