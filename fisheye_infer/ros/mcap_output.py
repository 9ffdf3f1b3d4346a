"""The MCAP file ``replay`` writes: ROS 2 channels (CDR, ``ros2msg`` schemas) and Foxglove channels (protobuf).

Chunks are LZ4-compressed: the overlays' doubles are most of the bytes, and LZ4 packs them three times
faster than zstd does, at a fifth more size; MCAP readers (Foxglove, ``ros2 bag``, the ``mcap`` library)
read both.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from typing import Any

import mcap.writer
from mcap_protobuf.schema import register_schema

from fisheye_infer.runtime.box_geometry import centres
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.tracking import Tracks

from .autoware import TRACKED_OBJECTS, tracked_objects
from .cdr import detection_array_cdr, marker_array_cdr
from .foxglove import image_annotations, scene_update, track_scene
from .messages import DETECTION_ARRAY, MARKER_ARRAY, ros2_image, stamp_ns, typestore
from .sync import SyncedSet

__all__ = ["DETECTIONS_TOPIC", "TRACKS_TOPIC", "McapOutput"]

DETECTIONS_TOPIC = "/detections"
TRACKS_TOPIC = "/tracks"  # autoware_perception_msgs/TrackedObjects, with --track
#: Centres kept of each track's recent path (2 s at 10 Hz), and the most tracks whose paths are kept.
PATH_POINTS = 20
MAX_PATHS = 1000


class McapOutput:
    """The output MCAP: ROS 2 channels (CDR, ``ros2msg`` schemas) and Foxglove channels (protobuf)."""

    def __init__(
        self, stream: Any, image_connections: Sequence[Any], detector: Detector, foxglove: bool, track: bool
    ) -> None:
        self.writer = mcap.writer.Writer(stream, compression=mcap.writer.CompressionType.LZ4)
        self.writer.start(profile="ros2", library="fisheye-infer")
        self.store = typestore()
        self.rig = detector.info.meta.rig
        self.channels: dict[str, int] = {}
        self.channels[DETECTIONS_TOPIC] = self._ros_channel(DETECTIONS_TOPIC, DETECTION_ARRAY)
        self.channels[DETECTIONS_TOPIC + "/markers"] = self._ros_channel(DETECTIONS_TOPIC + "/markers", MARKER_ARRAY)
        self.foxglove = foxglove
        if foxglove:
            from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
            from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

            scene = register_schema(self.writer, SceneUpdate)
            annotations = register_schema(self.writer, ImageAnnotations)
            self.channels[DETECTIONS_TOPIC + "/scene"] = self.writer.register_channel(
                DETECTIONS_TOPIC + "/scene", "protobuf", scene
            )
            for camera in self.rig.names:
                topic = f"/{camera}/detections"
                self.channels[topic] = self.writer.register_channel(topic, "protobuf", annotations)
        self.image_topics = {c.topic: self._ros_channel(c.topic, c.msgtype) for c in image_connections}
        self.paths: dict[int, deque[tuple[float, float, float]]] = {}  # track id -> recent centres
        if track:
            self.channels[TRACKS_TOPIC] = self._ros_channel(TRACKS_TOPIC, TRACKED_OBJECTS)

    def _ros_channel(self, topic: str, msgtype: str) -> int:
        text, _ = self.store.generate_msgdef(msgtype, ros_version=2)
        schema = self.writer.register_schema(msgtype, "ros2msg", text.encode())
        return self.writer.register_channel(topic, "cdr", schema)

    def _write(self, topic: str, data: bytes | memoryview, stamp: int) -> None:
        self.writer.add_message(self.channels[topic], stamp, bytes(data), stamp)

    def write_frame(
        self,
        synced: SyncedSet,
        detections: Detections,
        frame_id: str,
        ids: list[int] | None = None,
        scene: bytes | None = None,
    ) -> None:
        """A frame's boxes: the detection array, markers, the Foxglove scene (``scene``, encoded, or one cube per
        box) and overlays, and the frame's images when they are written.

        Args:
            synced (SyncedSet): the frame's camera messages and stamp.
            detections (Detections): the boxes to write.
            frame_id (str): the frame the boxes are in.
            ids (list[int] | None): each detection's id, a track's; by default its index.
            scene (bytes | None): the encoded ``SceneUpdate`` to write instead of the boxes' cubes.
        """
        stamp = synced.stamp
        self._write(DETECTIONS_TOPIC, detection_array_cdr(detections, stamp, frame_id, ids), stamp)
        self._write(DETECTIONS_TOPIC + "/markers", marker_array_cdr(detections, stamp, frame_id), stamp)
        if self.foxglove:
            scene = scene if scene is not None else scene_update(detections, stamp, frame_id)
            self._write(DETECTIONS_TOPIC + "/scene", scene, stamp)
            for camera, overlay in image_annotations(detections, self.rig, stamp).items():
                self._write(f"/{camera}/detections", overlay, stamp)
        for connection, msg in synced.items:
            if connection.topic in self.image_topics:
                cdr = self.store.serialize_cdr(ros2_image(msg), connection.msgtype)
                when = stamp_ns(msg.header)
                self.writer.add_message(self.image_topics[connection.topic], when, bytes(cdr), when)

    def write_tracks(self, synced: SyncedSet, tracks: Tracks, frame_id: str) -> None:
        """A frame's tracks: the detection array (track ids), markers, the Foxglove scene keyed by track, the
        overlays and the images, as ``write_frame`` writes boxes."""
        for track_id, (x, y, z) in zip(tracks.ids.tolist(), centres(tracks.boxes).tolist()):
            self.paths.setdefault(track_id, deque(maxlen=PATH_POINTS)).append((x, y, z))
        if len(self.paths) > MAX_PATHS:  # bounded: the paths of tracks not seen at this frame go
            self.paths = {i: self.paths[i] for i in tracks.ids.tolist()}
        boxes = Detections(tracks.boxes, tracks.scores, tracks.labels, tracks.class_names)
        scene = track_scene(tracks, self.paths, synced.stamp, frame_id).SerializeToString() if self.foxglove else None
        self.write_frame(synced, boxes, frame_id, ids=tracks.ids.tolist(), scene=scene)
        message = tracked_objects(tracks, synced.stamp, frame_id, self.store)
        self._write(TRACKS_TOPIC, self.store.serialize_cdr(message, TRACKED_OBJECTS), synced.stamp)

    def finish(self) -> None:
        self.writer.finish()
