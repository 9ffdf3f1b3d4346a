"""Foxglove messages (the official protobuf schemas): the boxes in 3D, and drawn on each camera's image
through that camera's own model.

    scene = scene_update(detections, stamp, "lidar")          # encoded foxglove.SceneUpdate: one cube per box
    scene = track_scene(tracks, paths, stamp, "lidar")        # one entity per track: box, velocity, path
    overlays = image_annotations(detections, rig, stamp)      # {camera: encoded foxglove.ImageAnnotations}

Visualisers project 3D boxes onto images with a pinhole model, which is wrong for a fisheye lens. Here
each box edge is sampled and projected through the camera's model
(``fisheye_infer.runtime.box_geometry.project_edges``, the one projection ``viz`` draws with; one point per
``OVERLAY_PIXELS_PER_SAMPLE`` pixels of the edge, up to 16), cut where it leaves the field of view or the
image: straight edges curve as the lens bends them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from foxglove_schemas_protobuf.ArrowPrimitive_pb2 import ArrowPrimitive
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.LinePrimitive_pb2 import LinePrimitive
from foxglove_schemas_protobuf.Point3_pb2 import Point3
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.runtime.box_geometry import Polylines, centres, project_edges
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.records import yaw_to_quaternion
from fisheye_infer.tools.viz import class_colour
from fisheye_infer.tracking.tracks import Tracks

from .wire import COLOR, POINT2, QUATERNION, VECTOR3, entries, key, length_delimited, length_delimited_parts, varint

__all__ = ["OVERLAY_PIXELS_PER_SAMPLE", "image_annotations", "scene_update", "track_scene"]

#: Pixels between an overlay edge's samples (``project_edges``): a far box's edges take a few points.
OVERLAY_PIXELS_PER_SAMPLE = 8.0

#: Field numbers: ``ImageAnnotations.points`` and ``.texts``, ``PointsAnnotation.points``,
#: ``TextAnnotation.position`` and ``.text``.
_ANNOTATIONS_POINTS, _ANNOTATIONS_TEXTS = 2, 3
_POINTS_POINTS = 3
_TEXT_POSITION, _TEXT_TEXT = 2, 3
_UPDATE_ENTITIES, _ENTITY_CUBES = 2, 8
#: ``CubePrimitive``: pose (position, orientation), size, color.
_CUBE = ((1, ((1, VECTOR3), (2, QUATERNION))), (2, VECTOR3), (3, COLOR))


def _timestamp(stamp: int) -> Timestamp:
    return Timestamp(seconds=stamp // 1_000_000_000, nanos=stamp % 1_000_000_000)


def _colour(name: str, alpha: float) -> Color:
    b, g, r = (v / 255 for v in class_colour(name))
    return Color(r=r, g=g, b=b, a=alpha)


def scene_update(detections: Detections, stamp: int, frame_id: str) -> bytes:
    """An encoded ``foxglove.SceneUpdate``: one ``SceneEntity`` holding a cube per box (gravity centre, yaw,
    l x w x h), coloured by class at half opacity; the cubes are written from arrays (``wire.entries``).

    Args:
        detections (Detections): the boxes.
        stamp (int): the frame's stamp in nanoseconds.
        frame_id (str): the frame the boxes are in.

    Returns:
        bytes: the serialised ``SceneUpdate``.
    """
    q = yaw_to_quaternion(detections.boxes[:, 6].astype(np.float64))  # (w, x, y, z)
    colours = {name: _colour(name, 0.5) for name in set(detections.names)}
    rgba = np.array([[c.r, c.g, c.b, c.a] for c in (colours[name] for name in detections.names)], np.float64)
    values = np.concatenate(
        [centres(detections.boxes), q[:, 1:], q[:, :1], detections.boxes[:, 3:6], rgba.reshape(-1, 4)], axis=1
    )
    cubes = entries(_ENTITY_CUBES, _CUBE, values)
    entity = SceneEntity(timestamp=_timestamp(stamp), frame_id=frame_id, id="detections").SerializeToString()
    return length_delimited(_UPDATE_ENTITIES, [entity], np.zeros(1, np.int64), cubes, np.array([0, len(cubes)]))


def track_scene(
    tracks: Tracks, paths: Mapping[int, Sequence[tuple[float, float, float]]], stamp: int, frame_id: str
) -> SceneUpdate:
    """One ``SceneEntity`` per track, keyed by its id (so the viewer follows an object).

    Each entity holds the track's box, an arrow of its velocity (one second ahead) and its recent path.

    Args:
        tracks: The tracks of one frame.
        paths: Track id -> its recent centres (x, y, z in ``frame_id``), oldest first.
        stamp: The frame's stamp, ns.
        frame_id: The frame the boxes are in.

    Returns:
        SceneUpdate: Foxglove's scene update.
    """
    q = yaw_to_quaternion(tracks.boxes[:, 6].astype(np.float64))
    entities = []
    for track_id, c, r, b, v, label in zip(
        tracks.ids.tolist(),
        centres(tracks.boxes),
        q.tolist(),
        tracks.boxes,
        tracks.velocities,
        tracks.labels,
        strict=True,
    ):
        colour = _colour(tracks.class_names[label], 0.5)
        cube = CubePrimitive(
            pose=Pose(
                position=Vector3(x=float(c[0]), y=float(c[1]), z=float(c[2])),
                orientation=Quaternion(w=r[0], x=r[1], y=r[2], z=r[3]),
            ),
            size=Vector3(x=float(b[3]), y=float(b[4]), z=float(b[5])),
            color=colour,
        )
        speed = float(np.hypot(v[0], v[1]))
        heading = float(np.arctan2(v[1], v[0]))
        arrow = ArrowPrimitive(
            pose=Pose(
                position=Vector3(x=float(c[0]), y=float(c[1]), z=float(c[2])),
                orientation=Quaternion(w=float(np.cos(heading / 2)), x=0.0, y=0.0, z=float(np.sin(heading / 2))),
            ),
            shaft_length=max(speed, 1e-3),
            shaft_diameter=0.1,
            head_length=0.3,
            head_diameter=0.3,
            color=_colour(tracks.class_names[label], 1.0),
        )
        path = [Point3(x=x, y=y, z=z) for x, y, z in paths.get(track_id, ())]
        lines = (
            [LinePrimitive(type=LinePrimitive.LINE_STRIP, points=path, thickness=0.1, color=colour)]
            if len(path) > 1
            else []
        )
        entities.append(
            SceneEntity(
                timestamp=_timestamp(stamp),
                frame_id=frame_id,
                id=f"track-{track_id}",
                cubes=[cube],
                arrows=[arrow],
                lines=lines,
            )
        )
    return SceneUpdate(entities=entities)


def image_annotations(detections: Detections, rig: Rig, stamp: int) -> dict[str, bytes]:
    """Per camera, an encoded ``foxglove.ImageAnnotations``: each box's visible edges as line strips in pixels
    (``project_edges``), and its class and score at the top left of its lines.

    The line strips' points are written from arrays (``wire``), so a frame of many boxes costs a few numpy
    calls per camera rather than a protobuf object per point; the bytes parse to the message
    ``ImageAnnotations(points=[PointsAnnotation(...), ...], texts=[TextAnnotation(...), ...])``.

    Args:
        detections (Detections): the boxes, their classes and scores.
        rig (Rig): the cameras the boxes are drawn through.
        stamp (int): the frame's stamp in nanoseconds, each annotation's timestamp.

    Returns:
        dict[str, bytes]: camera name -> the serialised ``ImageAnnotations``.
    """
    when = _timestamp(stamp)
    kinds = sorted(set(detections.names))
    kind_of = np.array([kinds.index(name) for name in detections.names], np.int64)
    line_heads = [
        PointsAnnotation(
            timestamp=when, type=PointsAnnotation.Type.LINE_STRIP, outline_color=_colour(name, 1.0), thickness=2.0
        ).SerializeToString()
        for name in kinds
    ]
    text_heads = [
        TextAnnotation(
            timestamp=when,
            font_size=12.0,
            text_color=_colour(name, 1.0),
            background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
        ).SerializeToString()
        for name in kinds
    ]
    labels = [f"{name} {score:.2f}".encode() for name, score in zip(detections.names, detections.scores.tolist())]
    label_heads = [  # each box's label with the fields of its class's labels
        text_heads[kind] + key(_TEXT_TEXT) + varint(len(label)) + label
        for kind, label in zip(kind_of.tolist(), labels, strict=True)
    ]
    per_camera = project_edges(detections.boxes, rig, pixels_per_sample=OVERLAY_PIXELS_PER_SAMPLE)
    lines, camera_of = _joined(list(per_camera.values()))
    points = entries(_POINTS_POINTS, POINT2, lines.points)
    line_parts = np.searchsorted(camera_of, np.arange(len(per_camera) + 1))  # each camera's first line
    drawn = length_delimited_parts(
        _ANNOTATIONS_POINTS, line_heads, kind_of[lines.boxes], points, lines.starts, line_parts
    )
    # each box's label at its lines' smallest u and v in each camera that draws it
    changes = (np.diff(lines.boxes) != 0) | (np.diff(camera_of) != 0)
    first = np.flatnonzero(np.r_[True, changes])[: len(lines.boxes)]  # each box's first line in each camera
    corner = np.minimum.reduceat(lines.points, lines.starts[first], axis=0) if len(first) else np.zeros((0, 2))
    positions = entries(_TEXT_POSITION, POINT2, corner)
    text_parts = np.searchsorted(camera_of[first], np.arange(len(per_camera) + 1))
    labelled = length_delimited_parts(
        _ANNOTATIONS_TEXTS, label_heads, lines.boxes[first], positions, np.arange(len(first) + 1), text_parts
    )
    return {camera: d + t for camera, d, t in zip(per_camera, drawn, labelled, strict=True)}


def _joined(per_camera: Sequence[Polylines]) -> tuple[Polylines, np.ndarray]:
    """The cameras' polylines as one, and the camera (its index) of each line."""
    sizes = [len(p.boxes) for p in per_camera]
    offsets = np.cumsum([0] + [len(p.points) for p in per_camera])
    starts = np.concatenate([p.starts[:-1] + o for p, o in zip(per_camera, offsets)] + [offsets[-1:]])
    joined = Polylines(
        np.concatenate([p.points for p in per_camera]).reshape(-1, 2),
        starts.astype(np.int64),
        np.concatenate([p.boxes for p in per_camera]).astype(np.int64),
    )
    return joined, np.repeat(np.arange(len(per_camera)), sizes)
