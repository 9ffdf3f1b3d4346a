"""The ROS 2 messages ``replay`` writes for every box, encoded as CDR directly.

    data = detection_array_cdr(detections, stamp, "lidar")   # vision_msgs/msg/Detection3DArray, CDR bytes
    data = marker_array_cdr(detections, stamp, "lidar")      # visualization_msgs/msg/MarkerArray, CDR bytes

A message of a hundred boxes is some two thousand nested messages; building each as a ``rosbags`` object
and serialising it walks them twice (size, then bytes) in Python. Here each box's fields are written in
declaration order by a small CDR writer (little-endian, ROS 2's encapsulation, every field aligned to its
size from the start of the payload), from arrays computed once for all boxes. The bytes are those
``rosbags`` writes for the same message, and deserialise with it (or ``rclpy``) as usual.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from fisheye_infer.runtime.box_geometry import centres
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.records import yaw_to_quaternion
from fisheye_infer.tools.viz import class_colour

__all__ = ["CdrWriter", "detection_array_cdr", "marker_array_cdr"]

#: ``visualization_msgs/Marker`` constants.
_CUBE, _ADD, _DELETEALL = 1, 0, 3
#: A ``PoseWithCovariance``'s covariance: unknown, all zeros.
_COVARIANCE = bytes(36 * 8)
#: A pose at the origin without rotation: position x, y, z, orientation x, y, z, w.
_ORIGIN = struct.pack("<7d", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)


class CdrWriter:
    """A little-endian CDR payload written field by field; each field is aligned to its own size from the start
    of the payload, as CDR asks. ``offset``: where in the payload this writer's bytes go (a piece written on its
    own to be copied in there later); each method returns where in ``data`` its value begins."""

    def __init__(self, offset: int = 0) -> None:
        """An empty piece of payload.

        Args:
            offset (int): where in the payload it goes (only its remainder modulo 8 counts).
        """
        self.offset = offset
        self.data = bytearray()

    def _align(self, size: int) -> int:
        self.data += bytes(-(self.offset + len(self.data)) % size)
        return len(self.data)

    def payload(self) -> bytes:
        """The message: ROS 2's encapsulation header (``CDR_LE``), then the payload.

        Returns:
            bytes: what ``rosbags``' ``serialize_cdr`` or ``rclpy``'s ``serialize_message`` gives.
        """
        return b"\x00\x01\x00\x00" + self.data

    def int32(self, *values: int) -> int:
        """Signed 32-bit integers (``int32``, a ``Time``'s seconds), one after another.

        Args:
            *values (int): the integers.

        Returns:
            int: where the first begins.
        """
        at = self._align(4)
        self.data += struct.pack(f"<{len(values)}i", *values)
        return at

    def uint32(self, value: int) -> int:
        """An unsigned 32-bit integer (``uint32``, a sequence's length).

        Args:
            value (int): 0 to 2**32 - 1.

        Returns:
            int: where it begins.
        """
        at = self._align(4)
        self.data += struct.pack("<I", value)
        return at

    def boolean(self, value: bool) -> int:
        """A ``bool``, one byte.

        Args:
            value (bool): the flag.

        Returns:
            int: where it is.
        """
        self.data.append(1 if value else 0)
        return len(self.data) - 1

    def string(self, text: str) -> int:
        """A ``string``: its length with the terminating NUL, its UTF-8 bytes, the NUL.

        Args:
            text (str): the text.

        Returns:
            int: where its bytes begin (after the length).
        """
        raw = text.encode()
        at = self.uint32(len(raw) + 1) + 4
        self.data += raw + b"\x00"
        return at

    def float64s(self, raw: bytes) -> int:
        """``float64`` fields one after another (a ``Pose``, a ``Vector3``, a fixed array), already packed.

        Args:
            raw (bytes): little-endian doubles.

        Returns:
            int: where the first begins.
        """
        at = self._align(8)
        self.data += raw
        return at

    def float32s(self, *values: float) -> int:
        """``float32`` fields one after another (a ``ColorRGBA``).

        Args:
            *values (float): the values.

        Returns:
            int: where the first begins.
        """
        at = self._align(4)
        self.data += struct.pack(f"<{len(values)}f", *values)
        return at

    def header(self, stamp: int, frame_id: str) -> None:
        """A ``std_msgs/Header``.

        Args:
            stamp (int): nanoseconds since the epoch, 0 or more.
            frame_id (str): the frame.
        """
        self.int32(stamp // 1_000_000_000)
        self.uint32(stamp % 1_000_000_000)
        self.string(frame_id)


def _poses(detections: Detections) -> np.ndarray:
    """(K, 7) little-endian doubles: each box's gravity centre and yaw as a ``geometry_msgs/Pose`` (x, y, z,
    then the quaternion's x, y, z, w)."""
    q = yaw_to_quaternion(detections.boxes[:, 6].astype(np.float64))  # (w, x, y, z)
    return np.ascontiguousarray(np.concatenate([centres(detections.boxes), q[:, 1:], q[:, :1]], axis=1), "<f8")


def _sizes(detections: Detections) -> np.ndarray:
    """(K, 3) little-endian doubles: each box's l, w, h as a ``geometry_msgs/Vector3``."""
    return np.ascontiguousarray(detections.boxes[:, 3:6], "<f8")


def _detection(stamp: int, frame_id: str, name: str, ident: str, offset: int) -> tuple[bytes, int, int, int, int]:
    """A ``Detection3D`` with zeros for its numbers, at ``offset`` in the payload: its bytes, and where its id,
    score, hypothesis pose and bounding box (centre, then size) begin in them."""
    out = CdrWriter(offset)
    out.header(stamp, frame_id)
    out.uint32(1)  # one hypothesis
    out.string(name)
    score = out.float64s(bytes(8))
    pose = out.float64s(bytes(7 * 8) + _COVARIANCE)
    box = out.float64s(bytes(10 * 8))
    at_id = out.string(ident)
    return bytes(out.data), at_id, score, pose, box


def detection_array_cdr(detections: Detections, stamp: int, frame_id: str, ids: Sequence[int] | None = None) -> bytes:
    """``vision_msgs/msg/Detection3DArray`` in CDR: one ``Detection3D`` per box at its gravity centre and yaw,
    the class name as hypothesis id with the box's score, the covariance unknown (zeros).

    Boxes of one class (and id length) share their bytes but for the numbers, which are written into a copy.

    Args:
        detections (Detections): the boxes.
        stamp (int): the frame's stamp in nanoseconds, every header's.
        frame_id (str): the frame the boxes are in, every header's.
        ids (Sequence[int] | None): each detection's ``id``, a track's; by default its index.

    Returns:
        bytes: the serialised message, encapsulation header first.
    """
    out = CdrWriter()
    out.header(stamp, frame_id)
    out.uint32(len(detections))
    poses, sizes, scores = _poses(detections), _sizes(detections), detections.scores.astype("<f8")
    templates: dict[tuple[str, int, int], tuple[bytes, int, int, int, int]] = {}
    data = out.data
    for i, name in enumerate(detections.names):
        ident = str(i if ids is None else ids[i]).encode()
        shape = (name, len(ident), len(data) % 8)
        if shape not in templates:
            templates[shape] = _detection(stamp, frame_id, name, ident.decode(), len(data))
        raw, at_id, at_score, at_pose, at_box = templates[shape]
        base = len(data)
        data += raw
        pose = poses[i].tobytes()
        data[base + at_id : base + at_id + len(ident)] = ident
        data[base + at_score : base + at_score + 8] = scores[i].tobytes()
        data[base + at_pose : base + at_pose + 56] = pose
        data[base + at_box : base + at_box + 80] = pose + sizes[i].tobytes()
    return out.payload()


def _marker(
    stamp: int, frame_id: str, ns: str, action: int, colour: tuple[float, float, float, float], offset: int
) -> tuple[bytes, int, int]:
    """A ``visualization_msgs/Marker`` of type CUBE with zeros for its id, pose and scale, at ``offset`` in the
    payload, with no lifetime, points, texture, text or mesh: its bytes, and where its id and pose (then scale)
    begin in them."""
    out = CdrWriter(offset)
    out.header(stamp, frame_id)
    out.string(ns)
    ident = out.int32(0, _CUBE, action)
    pose = out.float64s(bytes(10 * 8))
    out.float32s(*colour)
    out.int32(0, 0)  # lifetime: forever
    out.boolean(False)  # frame_locked
    out.uint32(0)  # points
    out.uint32(0)  # colors
    out.string("")  # texture_resource
    out.header(stamp, frame_id)  # texture: an empty CompressedImage
    out.string("")
    out.uint32(0)
    out.uint32(0)  # uv_coordinates
    out.string("")  # text
    out.string("")  # mesh_resource
    out.string("")  # mesh_file: no file name, no data
    out.uint32(0)
    out.boolean(False)  # mesh_use_embedded_materials
    return bytes(out.data), ident, pose


def marker_array_cdr(detections: Detections, stamp: int, frame_id: str) -> bytes:
    """``visualization_msgs/msg/MarkerArray`` in CDR: a DELETEALL marker, then one CUBE per box at its gravity
    centre and yaw, l x w x h, its namespace its class, coloured by class at half opacity.

    Markers of one class share their bytes but for the id, pose and scale, which are written into a copy.

    Args:
        detections (Detections): the boxes.
        stamp (int): the frame's stamp in nanoseconds, every header's.
        frame_id (str): the frame the boxes are in, every header's.

    Returns:
        bytes: the serialised message, encapsulation header first.
    """
    out = CdrWriter()
    out.uint32(len(detections) + 1)
    data = out.data
    base = len(data)
    raw, _, at_pose = _marker(stamp, frame_id, "", _DELETEALL, (0.0, 0.0, 0.0, 0.0), base)
    data += raw
    data[base + at_pose : base + at_pose + 56] = _ORIGIN
    boxes = np.ascontiguousarray(np.concatenate([_poses(detections), _sizes(detections)], axis=1))
    templates: dict[tuple[str, int], tuple[bytes, int, int]] = {}
    for i, name in enumerate(detections.names):
        shape = (name, len(data) % 8)
        if shape not in templates:
            b, g, r = (v / 255 for v in class_colour(name))
            templates[shape] = _marker(stamp, frame_id, name, _ADD, (r, g, b, 0.5), len(data))
        raw, at_id, at_pose = templates[shape]
        base = len(data)
        data += raw
        data[base + at_id : base + at_id + 4] = struct.pack("<i", i)
        data[base + at_pose : base + at_pose + 80] = boxes[i].tobytes()
    return out.payload()
