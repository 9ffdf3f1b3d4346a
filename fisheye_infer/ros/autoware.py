"""Autoware's ``autoware_perception_msgs/TrackedObjects``: the tracks as a robot stack's planner consumes them.

    store = typestore()                                            # the definitions registered (``messages``)
    msg = tracked_objects(tracks, stamp, "base_link")

Each track becomes a ``TrackedObject``: its id as a ``unique_identifier_msgs/UUID`` (uuid5 of the track id, so the
same track keeps the same UUID in every message and every replay), its score as the existence probability, its class
as Autoware's label, its gravity centre and yaw as the pose, its velocity over ground turned into the box's own axes
as the twist (Autoware's convention: x along the box's heading), and its box as a ``BOUNDING_BOX`` shape. The
pose's and the twist's covariances hold the tracker's bird's-eye-view covariances of the centre and of the
velocity (the twist's in the box's axes), the other entries 0; all 0 for a tracker that keeps none.
"""

from __future__ import annotations

import uuid
from typing import Any

import numpy as np

from fisheye_infer.runtime.box_geometry import centres
from fisheye_infer.runtime.records import yaw_to_quaternion
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["TRACKED_OBJECTS", "AUTOWARE_LABELS", "AUTOWARE_MSGS", "track_uuid", "tracked_objects"]

TRACKED_OBJECTS = "autoware_perception_msgs/msg/TrackedObjects"
#: The project's classes as ``ObjectClassification`` labels (UNKNOWN 0, CAR 1, TRUCK 2, BUS 3, TRAILER 4,
#: MOTORCYCLE 5, BICYCLE 6, PEDESTRIAN 7).
AUTOWARE_LABELS = {"Car": 1, "Van": 1, "Truck": 2, "Bus": 3, "Pedestrian": 7, "Cyclist": 6}
_NAMESPACE = uuid.UUID("5f2b8a36-6d1e-4f55-9c1a-0e3f6a2d7b41")

#: The message definitions (autoware_perception_msgs, unique_identifier_msgs) the ROS 2 type stores lack.
AUTOWARE_MSGS = {
    "unique_identifier_msgs/msg/UUID": "uint8[16] uuid\n",
    "autoware_perception_msgs/msg/ObjectClassification": (
        "uint8 UNKNOWN=0\nuint8 CAR=1\nuint8 TRUCK=2\nuint8 BUS=3\nuint8 TRAILER=4\nuint8 MOTORCYCLE=5\n"
        "uint8 BICYCLE=6\nuint8 PEDESTRIAN=7\nuint8 label\nfloat32 probability\n"
    ),
    "autoware_perception_msgs/msg/TrackedObjectKinematics": (
        "uint8 UNAVAILABLE=0\nuint8 SIGN_UNKNOWN=1\nuint8 AVAILABLE=2\n"
        "geometry_msgs/PoseWithCovariance pose_with_covariance\nuint8 orientation_availability\n"
        "geometry_msgs/TwistWithCovariance twist_with_covariance\n"
        "geometry_msgs/AccelWithCovariance acceleration_with_covariance\nbool is_stationary\n"
    ),
    "autoware_perception_msgs/msg/Shape": (
        "uint8 BOUNDING_BOX=0\nuint8 CYLINDER=1\nuint8 POLYGON=2\nuint8 type\ngeometry_msgs/Polygon footprint\n"
        "geometry_msgs/Vector3 dimensions\n"
    ),
    "autoware_perception_msgs/msg/TrackedObject": (
        "unique_identifier_msgs/UUID object_id\nfloat32 existence_probability\n"
        "autoware_perception_msgs/ObjectClassification[] classification\n"
        "autoware_perception_msgs/TrackedObjectKinematics kinematics\nautoware_perception_msgs/Shape shape\n"
    ),
    TRACKED_OBJECTS: "std_msgs/Header header\nautoware_perception_msgs/TrackedObject[] objects\n",
}


def track_uuid(track_id: int) -> bytes:
    """The 16 bytes of a track's UUID: uuid5 of its id, the same in every message.

    Args:
        track_id: The tracker's id of the track.

    Returns:
        bytes: 16 bytes.
    """
    return uuid.uuid5(_NAMESPACE, str(int(track_id))).bytes


def tracked_objects(tracks: Tracks, stamp: int, frame_id: str, store: Any) -> Any:
    """``autoware_perception_msgs/TrackedObjects`` of one frame's tracks.

    Args:
        tracks: The frame's tracks (boxes bottom-centred; velocities over ground in the boxes' frame).
        stamp: The frame's stamp, integer nanoseconds.
        frame_id: The frame of the boxes.
        store: A rosbags type store with ``AUTOWARE_MSGS`` registered.

    Returns:
        Any: The message.
    """
    t = store.types
    vector, point, quaternion = (t[f"geometry_msgs/msg/{n}"] for n in ("Vector3", "Point", "Quaternion"))
    pose, twist, accel = (t[f"geometry_msgs/msg/{n}"] for n in ("Pose", "Twist", "Accel"))
    header = t["std_msgs/msg/Header"](
        stamp=t["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000),
        frame_id=frame_id,
    )
    q = yaw_to_quaternion(tracks.boxes[:, 6].astype(np.float64))  # (w, x, y, z)
    pose_cov, twist_cov = _covariances(tracks)
    objects = []
    for track_id, c, r, box, v, score, label, pc, tc in zip(
        tracks.ids.tolist(),
        centres(tracks.boxes).tolist(),
        q.tolist(),
        tracks.boxes.astype(np.float64),
        tracks.velocities.astype(np.float64),
        tracks.scores.tolist(),
        tracks.labels.tolist(),
        pose_cov,
        twist_cov,
    ):
        yaw = float(box[6])
        along = float(np.cos(yaw) * v[0] + np.sin(yaw) * v[1])  # R(-yaw) (vx, vy): the box's own axes
        across = float(-np.sin(yaw) * v[0] + np.cos(yaw) * v[1])
        kinematics = t["autoware_perception_msgs/msg/TrackedObjectKinematics"](
            pose_with_covariance=t["geometry_msgs/msg/PoseWithCovariance"](
                pose=pose(
                    position=point(x=c[0], y=c[1], z=c[2]), orientation=quaternion(x=r[1], y=r[2], z=r[3], w=r[0])
                ),
                covariance=pc,
            ),
            orientation_availability=2,
            twist_with_covariance=t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist(linear=vector(x=along, y=across, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)),
                covariance=tc,
            ),
            acceleration_with_covariance=t["geometry_msgs/msg/AccelWithCovariance"](
                accel=accel(linear=vector(x=0.0, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36, np.float64),
            ),
            is_stationary=bool(np.hypot(v[0], v[1]) < 0.5),
        )
        objects.append(
            t["autoware_perception_msgs/msg/TrackedObject"](
                object_id=t["unique_identifier_msgs/msg/UUID"](uuid=np.frombuffer(track_uuid(track_id), np.uint8)),
                existence_probability=float(score),
                classification=[
                    t["autoware_perception_msgs/msg/ObjectClassification"](
                        label=AUTOWARE_LABELS.get(tracks.class_names[label], 0), probability=1.0
                    )
                ],
                kinematics=kinematics,
                shape=t["autoware_perception_msgs/msg/Shape"](
                    type=0,
                    footprint=t["geometry_msgs/msg/Polygon"](points=[]),
                    dimensions=vector(x=float(box[3]), y=float(box[4]), z=float(box[5])),
                ),
            )
        )
    return t[TRACKED_OBJECTS](header=header, objects=objects)


def _covariances(tracks: Tracks) -> tuple[np.ndarray, np.ndarray]:
    """(K, 36) row-major 6x6 covariances of each pose (x, y in the boxes' frame) and twist (linear x, y in the box's
    own axes, as the twist is given), the rest 0; all 0 where the tracker keeps none."""
    k = len(tracks)
    pose, twist = np.zeros((k, 6, 6)), np.zeros((k, 6, 6))
    if tracks.position_covariances is not None and tracks.velocity_covariances is not None:
        yaw = tracks.boxes[:, 6].astype(np.float64)
        c, s = np.cos(yaw), np.sin(yaw)
        to_box = np.stack([np.column_stack([c, s]), np.column_stack([-s, c])], axis=1)  # R(-yaw), (K, 2, 2)
        pose[:, :2, :2] = tracks.position_covariances
        twist[:, :2, :2] = to_box @ tracks.velocity_covariances.astype(np.float64) @ to_box.transpose(0, 2, 1)
    return pose.reshape(k, 36), twist.reshape(k, 36)
