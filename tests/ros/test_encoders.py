"""The messages replay writes, encoded from arrays, against the same messages built field by field: the Foxglove
overlays against ``foxglove_schemas_protobuf`` objects of each box edge projected through the camera model
point by point, and the ROS 2 arrays against ``rosbags``' own serialisation of message objects."""

from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("foxglove_schemas_protobuf")

from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.CubePrimitive_pb2 import CubePrimitive
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.Point2_pb2 import Point2
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
from foxglove_schemas_protobuf.SceneEntity_pb2 import SceneEntity
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation
from foxglove_schemas_protobuf.Vector3_pb2 import Vector3
from google.protobuf.timestamp_pb2 import Timestamp

from fisheye_infer.cameras.camera_models import DoubleSphere, KannalaBrandt, Pinhole
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.ros.cdr import detection_array_cdr, marker_array_cdr
from fisheye_infer.ros.foxglove import OVERLAY_PIXELS_PER_SAMPLE, image_annotations, scene_update
from fisheye_infer.ros.messages import typestore
from fisheye_infer.ros.wire import _varints, length_delimited, length_delimited_parts, varint
from fisheye_infer.runtime.box_geometry import BOX_EDGES, centres, corners, project_boxes, project_edges
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.records import yaw_to_quaternion
from fisheye_infer.tools.viz import class_colour

CLASSES = ("car", "truck", "pedestrian", "bicycle")
STAMP = 1_700_000_000_123_456_789


def _detections(count: int, seed: int = 0) -> Detections:
    """``count`` boxes all around the car, some across a camera's field of view, of every class."""
    rng = np.random.default_rng(seed)
    boxes = np.c_[
        rng.uniform(-25, 25, (count, 2)), rng.uniform(-2, 1, count), rng.uniform(0.5, 6, (count, 3)),
        rng.uniform(-4, 4, count),
    ]  # fmt: skip
    return Detections(
        boxes.astype(np.float32), rng.uniform(0, 1, count).astype(np.float32), rng.integers(0, 4, count), CLASSES
    )


def _edge_pieces(
    boxes: np.ndarray, rig: Rig, samples: int, pixels_per_sample: float | None = None
) -> dict[str, list[list[np.ndarray]]]:
    """Each box's edges, one edge at a time: its samples through the camera model, cut into runs of valid points;
    with ``pixels_per_sample``, an edge whose corners both project takes one sample per that many pixels between
    them (at least 2, at most ``samples``)."""
    out: dict[str, list[list[np.ndarray]]] = {}
    for cam, lidar2cam in zip(rig.cameras, rig.lidar2cam()):
        per_box = []
        for box_corners in corners(boxes):
            pieces = []
            for i, j in BOX_EDGES:
                n = samples
                if pixels_per_sample is not None:
                    ends, seen = cam.model.project(box_corners[[i, j]] @ lidar2cam[:3, :3].T + lidar2cam[:3, 3])
                    if seen.all():
                        n = min(max(math.ceil(float(np.hypot(*(ends[0] - ends[1]))) / pixels_per_sample) + 1, 2), n)
                points = box_corners[i] + (box_corners[j] - box_corners[i]) * np.linspace(0.0, 1.0, n)[:, None]
                uv, valid = cam.model.project(points @ lidar2cam[:3, :3].T + lidar2cam[:3, 3])
                run: list[int] = []
                for s in [*range(n), None]:
                    if s is not None and valid[s]:
                        run.append(s)
                        continue
                    if len(run) > 1 or len(run) == n:
                        pieces.append(uv[run])
                    run = []
            per_box.append(pieces)
        out[cam.name] = per_box
    return out


def _colour(name: str, alpha: float) -> Color:
    b, g, r = (v / 255 for v in class_colour(name))
    return Color(r=r, g=g, b=b, a=alpha)


def _annotations(detections: Detections, rig: Rig) -> dict[str, ImageAnnotations]:
    """The overlays as protobuf objects, a ``Point2`` per point."""
    when = Timestamp(seconds=STAMP // 10**9, nanos=STAMP % 10**9)
    out = {}
    for camera, per_box in _edge_pieces(detections.boxes, rig, 16, OVERLAY_PIXELS_PER_SAMPLE).items():
        points, texts = [], []
        for pieces, name, score in zip(per_box, detections.names, detections.scores.tolist(), strict=True):
            points += [
                PointsAnnotation(
                    timestamp=when,
                    type=PointsAnnotation.Type.LINE_STRIP,
                    points=[Point2(x=u, y=v) for u, v in piece.tolist()],
                    outline_color=_colour(name, 1.0),
                    thickness=2.0,
                )
                for piece in pieces
            ]
            if pieces:
                u, v = np.concatenate(pieces).min(axis=0)
                texts.append(
                    TextAnnotation(
                        timestamp=when,
                        position=Point2(x=float(u), y=float(v)),
                        text=f"{name} {score:.2f}",
                        font_size=12.0,
                        text_color=_colour(name, 1.0),
                        background_color=Color(r=0.0, g=0.0, b=0.0, a=0.5),
                    )
                )
        out[camera] = ImageAnnotations(points=points, texts=texts)
    return out


@pytest.mark.parametrize("count", [0, 1, 40])
def test_overlays_are_the_messages_built_point_by_point(rig: Rig, count: int) -> None:
    detections = _detections(count)
    expected = _annotations(detections, rig)
    encoded = image_annotations(detections, rig, STAMP)
    assert sorted(encoded) == sorted(expected)
    for camera, data in encoded.items():
        _assert_same(ImageAnnotations.FromString(data), expected[camera])
    assert sum(len(m.points) for m in expected.values()) >= count  # every box is seen by some camera
    if count > 1:
        assert any(len(a.points) < 16 for m in expected.values() for a in m.points)  # some cut at a view's edge


def _assert_same(got: ImageAnnotations, want: ImageAnnotations) -> None:
    """The same annotations, their pixels equal to float tolerance (a matrix product's rounding depends on how
    many points it multiplies at once)."""
    got, want = (
        ImageAnnotations.FromString(got.SerializeToString()),
        ImageAnnotations.FromString(want.SerializeToString()),
    )
    assert len(got.points) == len(want.points) and len(got.texts) == len(want.texts)
    for a, b in [*zip(got.points, want.points), *zip(got.texts, want.texts)]:
        field = "points" if isinstance(a, PointsAnnotation) else "position"
        pixels = [np.array([[p.x, p.y] for p in (c.points if field == "points" else [c.position])]) for c in (a, b)]
        assert pixels[0].shape == pixels[1].shape and np.allclose(pixels[0], pixels[1], rtol=0, atol=1e-9)
        a.ClearField(field)
        b.ClearField(field)
    assert got == want


@pytest.mark.parametrize("samples, pixels", [(1, None), (2, None), (16, None), (16, 8.0), (3, 2.0), (16, 50.0)])
def test_packed_edges_are_each_edge_projected_on_its_own(rig: Rig, samples: int, pixels: float | None) -> None:
    boxes = _detections(25, seed=1).boxes
    expected = _edge_pieces(boxes, rig, samples, pixels)
    packed = project_edges(boxes, rig, samples, pixels)
    split = project_boxes(boxes, rig, samples, pixels)
    for camera, per_box in expected.items():
        lines = [piece for pieces in per_box for piece in pieces]
        assert len(packed[camera].lines()) == len(lines) and packed[camera].starts[-1] == len(packed[camera].points)
        assert all(
            a.shape == b.shape and np.allclose(a, b, rtol=0, atol=1e-9)
            for a, b in zip(packed[camera].lines(), lines, strict=True)
        )
        assert packed[camera].boxes.tolist() == [k for k, pieces in enumerate(per_box) for _ in pieces]
        assert [len(p) for p in split[camera]] == [len(p) for p in per_box]


def _other_lenses(rig: Rig) -> Rig:
    """``rig`` with a lens of another model on each camera: a pinhole (no field of view but the image's), a
    150-degree and a 195-degree Kannala-Brandt, and a 180-degree double sphere."""
    lenses = [
        Pinhole(width=640, height=480, fx=300.0, fy=300.0, cx=320.0, cy=240.0),
        KannalaBrandt(width=512, height=512, fx=160.0, fy=160.0, cx=256.0, cy=256.0, k=(0.0, 0.0, 0.0, 0.0), fov=150.0),
        KannalaBrandt(width=512, height=512, fx=150.0, fy=150.0, cx=256.0, cy=256.0, k=(0.0, 0.0, 0.0, 0.0), fov=195.0),
        DoubleSphere(width=512, height=512, fx=160.0, fy=160.0, cx=256.0, cy=256.0, xi=-0.2, alpha=0.6, fov=180.0),
    ]
    cameras = tuple(c.model_copy(update={"model": lens}) for c, lens in zip(rig.cameras, lenses, strict=True))
    return rig.model_copy(update={"cameras": cameras})


@pytest.mark.parametrize("pixels", [None, 8.0])
def test_edges_through_other_lenses_are_each_edge_projected_on_its_own(rig: Rig, pixels: float | None) -> None:
    """Boxes all around the car through lenses with fields of view under, at and over 180 degrees: the boxes a
    camera cannot see are skipped, and what is drawn is what every edge projected alone gives."""
    other = _other_lenses(rig)
    boxes = _detections(60, seed=2).boxes
    expected = _edge_pieces(boxes, other, 16, pixels)
    packed = project_edges(boxes, other, 16, pixels)
    for camera, per_box in expected.items():
        lines = [piece for pieces in per_box for piece in pieces]
        assert packed[camera].boxes.tolist() == [k for k, pieces in enumerate(per_box) for _ in pieces]
        assert all(
            a.shape == b.shape and np.allclose(a, b, rtol=0, atol=1e-9)
            for a, b in zip(packed[camera].lines(), lines, strict=True)
        )
        assert 0 < len({k for k, pieces in enumerate(per_box) if pieces}) < len(boxes)  # some boxes unseen


def _distance_to_polyline(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Each point's distance (px) to the nearest segment of ``line``."""
    a, b = line[:-1], line[1:]
    ab = b - a
    t = np.clip(((points[:, None] - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points[:, None] - (a + t[..., None] * ab), axis=-1).min(axis=1)


def test_sparse_overlay_edges_follow_the_dense_curve(rig: Rig) -> None:
    """A car 6 m ahead, whole in the front camera: every edge is one polyline of a few points, and the dense
    projection of the same edge (256 samples) lies within half a pixel of it."""
    box = np.array([[6.0, 0.5, -1.6, 4.5, 1.9, 1.6, 0.4]])
    front = rig.cameras[0].name
    sparse = project_edges(box, rig, 16, OVERLAY_PIXELS_PER_SAMPLE)[front].lines()
    dense = project_edges(box, rig, 256)[front].lines()
    assert len(sparse) == len(dense) == len(BOX_EDGES)
    assert 2 * len(BOX_EDGES) <= sum(map(len, sparse)) < 16 * len(BOX_EDGES)
    for thin, full in zip(sparse, dense, strict=True):
        np.testing.assert_allclose(thin[[0, -1]], full[[0, -1]], atol=1e-6)  # the corners, exactly
        assert _distance_to_polyline(full, thin).max() < 0.5


@pytest.mark.parametrize("count", [0, 1, 30])
def test_the_scene_is_the_message_built_cube_by_cube(count: int) -> None:
    detections = _detections(count, seed=4)
    q = yaw_to_quaternion(detections.boxes[:, 6].astype(np.float64))
    cubes = [
        CubePrimitive(
            pose=Pose(position=Vector3(x=c[0], y=c[1], z=c[2]), orientation=Quaternion(w=r[0], x=r[1], y=r[2], z=r[3])),
            size=Vector3(x=float(b[3]), y=float(b[4]), z=float(b[5])),
            color=_colour(name, 0.5),
        )
        for c, r, b, name in zip(
            centres(detections.boxes).tolist(), q.tolist(), detections.boxes, detections.names, strict=True
        )
    ]
    when = Timestamp(seconds=STAMP // 10**9, nanos=STAMP % 10**9)
    expected = SceneUpdate(entities=[SceneEntity(timestamp=when, frame_id="lidar", id="detections", cubes=cubes)])
    assert SceneUpdate.FromString(scene_update(detections, STAMP, "lidar")) == expected


def test_messages_cut_into_parts_are_each_part_encoded_alone() -> None:
    """``length_delimited_parts``: each part (empty ones too) is ``length_delimited`` of its messages alone, and the
    parts in order are all the messages, whose bodies reach two-byte lengths."""
    rng = np.random.default_rng(5)
    heads = [b"", b"\x0a\x03abc", bytes(range(40))]
    counts = rng.integers(0, 30, 50)
    starts = np.r_[0, np.cumsum(counts)]
    rows = rng.integers(0, 256, (int(starts[-1]), 5)).astype(np.uint8)
    head_of = rng.integers(0, len(heads), 50)
    parts = np.array([0, 0, 7, 7, 31, 50, 50])
    cut = length_delimited_parts(3, heads, head_of, rows, starts, parts)
    assert b"".join(cut) == length_delimited(3, heads, head_of, rows, starts)
    for (a, b), data in zip(zip(parts[:-1], parts[1:]), cut, strict=True):
        assert data == length_delimited(
            3, heads, head_of[a:b], rows[starts[a] : starts[b]], starts[a : b + 1] - starts[a]
        )
    assert cut[0] == cut[2] == cut[5] == b"" and max(counts) * 5 > 127


def test_varints_are_protobufs() -> None:
    values = [0, 1, 127, 128, 300, 16_383, 16_384, 2**35 + 7]
    encoded, widths = _varints(np.array(values))
    assert [encoded[i, : widths[i]].tobytes() for i in range(len(values))] == [varint(v) for v in values]
    assert varint(300) == b"\xac\x02"


def _ros_arrays(detections: Detections, frame_id: str, ids: list[int] | None) -> tuple[bytes, bytes]:
    """Detection3DArray and MarkerArray as rosbags message objects, serialised by rosbags."""
    store = typestore()
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=STAMP // 10**9, nanosec=STAMP % 10**9)
    header = types["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)
    vector, point, quaternion = (types[f"geometry_msgs/msg/{n}"] for n in ("Vector3", "Point", "Quaternion"))
    q = yaw_to_quaternion(detections.boxes[:, 6].astype(np.float64))
    poses = [
        types["geometry_msgs/msg/Pose"](
            position=point(x=c[0], y=c[1], z=c[2]), orientation=quaternion(x=r[1], y=r[2], z=r[3], w=r[0])
        )
        for c, r in zip(centres(detections.boxes).tolist(), q.tolist(), strict=True)
    ]
    sizes = [vector(x=float(b[3]), y=float(b[4]), z=float(b[5])) for b in detections.boxes]
    items = [
        types["vision_msgs/msg/Detection3D"](
            header=header,
            results=[
                types["vision_msgs/msg/ObjectHypothesisWithPose"](
                    hypothesis=types["vision_msgs/msg/ObjectHypothesis"](class_id=name, score=score),
                    pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                )
            ],
            bbox=types["vision_msgs/msg/BoundingBox3D"](center=pose, size=size),
            id=str(i if ids is None else ids[i]),
        )
        for i, (pose, size, name, score) in enumerate(
            zip(poses, sizes, detections.names, detections.scores.tolist(), strict=True)
        )
    ]
    array = types["vision_msgs/msg/Detection3DArray"](header=header, detections=items)
    marker: type = types["visualization_msgs/msg/Marker"]
    origin = types["geometry_msgs/msg/Pose"](
        position=point(x=0.0, y=0.0, z=0.0), orientation=quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    )

    def cube(ns: str, ident: int, action: int, pose: object, scale: object, rgba: tuple[float, ...]) -> object:
        return marker(
            header=header,
            ns=ns,
            id=ident,
            type=marker.CUBE,
            action=action,
            pose=pose,
            scale=scale,
            color=types["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
            lifetime=types["builtin_interfaces/msg/Duration"](sec=0, nanosec=0),
            frame_locked=False,
            points=[],
            colors=[],
            texture_resource="",
            texture=types["sensor_msgs/msg/CompressedImage"](header=header, format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[],
            text="",
            mesh_resource="",
            mesh_file=types["visualization_msgs/msg/MeshFile"](filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False,
        )

    markers = [cube("", 0, marker.DELETEALL, origin, vector(x=0.0, y=0.0, z=0.0), (0.0, 0.0, 0.0, 0.0))]
    for i, (pose, size, name) in enumerate(zip(poses, sizes, detections.names, strict=True)):
        b, g, r = (v / 255 for v in class_colour(name))
        markers.append(cube(name, i, marker.ADD, pose, size, (r, g, b, 0.5)))
    marker_array = types["visualization_msgs/msg/MarkerArray"](markers=markers)
    return (
        bytes(store.serialize_cdr(array, "vision_msgs/msg/Detection3DArray")),
        bytes(store.serialize_cdr(marker_array, "visualization_msgs/msg/MarkerArray")),
    )


@pytest.mark.parametrize(
    ("count", "frame_id", "tracked"), [(0, "lidar", False), (1, "map", False), (30, "lidar", True)]
)
def test_ros_arrays_are_the_bytes_rosbags_writes(count: int, frame_id: str, tracked: bool) -> None:
    detections = _detections(count, seed=2)
    ids = [int(i) for i in np.random.default_rng(3).integers(0, 10**6, count)] if tracked else None
    array, markers = _ros_arrays(detections, frame_id, ids)
    assert detection_array_cdr(detections, STAMP, frame_id, ids) == array
    assert marker_array_cdr(detections, STAMP, frame_id) == markers
