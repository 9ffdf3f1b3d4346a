"""Bag replay: bags written with ``rosbags`` itself (rosbag2 MCAP and sqlite3, ROS 1) from rendered frames with
per-camera stamp jitter, replayed through a real model; the output read back with the ``mcap`` reader, the
ROS 2 messages deserialised with ``rosbags`` and the Foxglove ones with their protobuf classes."""

from __future__ import annotations

import json
import os
import sys
import threading
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap")

from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from fisheye_infer.cli import main
from fisheye_infer.errors import BagError, FrameError, OptionError
from fisheye_infer.eval.evaluate import load_results
from fisheye_infer.ros.foxglove import OVERLAY_PIXELS_PER_SAMPLE
from fisheye_infer.ros.messages import image_from_message, typestore
from fisheye_infer.ros.replay import replay
from fisheye_infer.ros.sync import Synchroniser
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.box_geometry import project_boxes
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene

FRAMES = 6
PERIOD_NS = 100_000_000  # 10 Hz
#: How each camera is recorded: (message type, encoding or compressed format).
RECORDING = {
    "fisheye_camera_front": ("sensor_msgs/msg/CompressedImage", "png"),
    "fisheye_camera_left": ("sensor_msgs/msg/Image", "bgr8"),
    "fisheye_camera_right": ("sensor_msgs/msg/Image", "rgb8"),
    "fisheye_camera_rear": ("sensor_msgs/msg/CompressedImage", "jpeg"),
}


@dataclass(frozen=True)
class Recording:
    """A drive recorded three ways, and what replaying it must give."""

    mcap: Path
    sqlite: Path
    ros1: Path
    images: list[dict[str, np.ndarray]]  # the complete frames, decoded as the replay decodes them
    stamps: list[int]  # each complete frame's front camera stamp
    dropped: Counter[str]
    undecodable: int


def _message(store, msgtype: str, fmt: str, image: np.ndarray, stamp: int, ros1: bool):
    types = store.types
    time = types["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
    header = (
        types["std_msgs/msg/Header"](seq=0, stamp=time, frame_id="cam")
        if ros1
        else types["std_msgs/msg/Header"](stamp=time, frame_id="cam")
    )
    if msgtype.endswith("CompressedImage"):
        data = np.frombuffer(cv2.imencode(f".{fmt}", image)[1].tobytes(), np.uint8)
        return types[msgtype](header=header, format=fmt, data=data)
    pixels = image[:, :, ::-1] if fmt == "rgb8" else image
    h, w = image.shape[:2]
    return types[msgtype](
        header=header, height=h, width=w, encoding=fmt, is_bigendian=0, step=w * 3, data=pixels.reshape(-1).copy()
    )


@pytest.fixture(scope="module")
def recording(small_export, tmp_path_factory: pytest.TempPathFactory) -> Recording:
    """``FRAMES`` rendered frames at 10 Hz, each camera's stamp jittered by up to 5 ms; then three faults:
    the rear camera's frame 2 stamped 50 ms late (unsynchronised), the front camera's frame 4 not decodable,
    and the left camera's last frame missing (the others incomplete at the end)."""
    rig = read_meta(small_export.onnx).rig
    folder = tmp_path_factory.mktemp("bags")
    rng = np.random.default_rng(7)
    renderer = Renderer(texture_seed=3)
    ros2, ros1 = typestore(), get_typestore(Stores.ROS1_NOETIC)
    messages = []  # (camera, stamp, image or None for undecodable)
    for i in range(FRAMES):
        frame = renderer.render(rig, random_scene(np.random.default_rng(100 + i)))
        for camera in rig.names:
            if camera == "fisheye_camera_left" and i == FRAMES - 1:
                continue
            stamp = 10**18 + i * PERIOD_NS + int(rng.integers(0, 5_000_000))
            if camera == "fisheye_camera_rear" and i == 2:
                stamp += 50_000_000
            messages.append((camera, stamp, frame[camera], i == 4 and camera == "fisheye_camera_front"))
    messages.sort(key=lambda m: m[1])

    paths = {"mcap": folder / "drive_mcap", "sqlite": folder / "drive_sqlite", "ros1": folder / "drive.bag"}
    for kind, path in paths.items():
        writer = (
            Writer1(path)
            if kind == "ros1"
            else Writer2(
                path, version=9, storage_plugin=StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
            )
        )
        store = ros1 if kind == "ros1" else ros2
        with writer:
            connections = {c: writer.add_connection(f"/{c}/image", RECORDING[c][0], typestore=store) for c in rig.names}
            for camera, stamp, image, broken in messages:
                msgtype, fmt = RECORDING[camera]
                msg = _message(store, msgtype, fmt, image, stamp, kind == "ros1")
                if broken:
                    msg = store.types[msgtype](header=msg.header, format=fmt, data=np.zeros(16, np.uint8))
                raw = store.serialize_ros1(msg, msgtype) if kind == "ros1" else store.serialize_cdr(msg, msgtype)
                writer.write(connections[camera], stamp, raw)

    # what the replay must find: frames 0, 1, 3 complete; 2 loses its rear camera; 4 does not decode; 5 lacks left
    images, stamps = [], []
    for i in (0, 1, 3):
        frame = {}
        for camera, stamp, image, _ in messages:
            if (stamp - 10**18) // PERIOD_NS == i and not (camera == "fisheye_camera_rear" and i == 2):
                msgtype, fmt = RECORDING[camera]
                frame[camera] = image_from_message(_message(ros2, msgtype, fmt, image, stamp, False))
                if camera == "fisheye_camera_front":
                    stamps.append(stamp)
        images.append(frame)
    # frame 2: front, left, right dropped as unsynchronised when the late rear arrives, and that rear too when
    # frame 3's cameras come; frame 5: front, right, rear wait for a left camera that never comes
    dropped = Counter({"unsynchronised": 4, "incomplete at the end": 3})
    return Recording(paths["mcap"], paths["sqlite"], paths["ros1"], images, stamps, dropped, 1)


def _topics(rig_names) -> dict[str, str]:
    return {c: f"/{c}/image" for c in rig_names}


def _read_mcap(path: Path) -> dict[str, list[tuple[int, bytes]]]:
    by_topic: dict[str, list[tuple[int, bytes]]] = {}
    with path.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            by_topic.setdefault(channel.topic, []).append((message.log_time, message.data))
    return by_topic


def test_replay_matches_the_detector_frame_by_frame(small_export, recording: Recording, tmp_path: Path) -> None:
    rig = read_meta(small_export.onnx).rig
    out = tmp_path / "out.mcap"
    report = replay(small_export.onnx, [recording.mcap], _topics(rig.names), out, images=True, batch=2, threads=1)
    assert report.frames == 3 and report.dropped == recording.dropped and report.undecodable == 1
    assert not report.complete and report.messages == FRAMES * 4 - 1

    store = typestore()
    written = _read_mcap(out)
    arrays = [store.deserialize_cdr(data, "vision_msgs/msg/Detection3DArray") for _, data in written["/detections"]]
    assert [t for t, _ in written["/detections"]] == recording.stamps
    detector = Detector(small_export.onnx, threads=1)
    for array, images, stamp in zip(arrays, recording.images, recording.stamps, strict=True):
        expected = detector.detect(images)
        assert array.header.stamp.sec * 10**9 + array.header.stamp.nanosec == stamp and array.header.frame_id == "lidar"
        assert len(array.detections) == len(expected)
        got = np.array(
            [
                [
                    d.bbox.center.position.x,
                    d.bbox.center.position.y,
                    d.bbox.center.position.z - d.bbox.size.z / 2,  # the gravity centre -> the bottom
                    d.bbox.size.x,
                    d.bbox.size.y,
                    d.bbox.size.z,
                    2 * np.arctan2(d.bbox.center.orientation.z, d.bbox.center.orientation.w),
                ]
                for d in array.detections
            ]
        )
        yaw = np.angle(np.exp(1j * (got[:, 6] - expected.boxes[:, 6])))  # the same yaw up to a full turn
        assert np.abs(got[:, :6] - expected.boxes[:, :6]).max() < 1e-5 and np.abs(yaw).max() < 1e-5
        assert [d.results[0].hypothesis.class_id for d in array.detections] == expected.names
        assert np.allclose([d.results[0].hypothesis.score for d in array.detections], expected.scores, atol=1e-6)
    markers = store.deserialize_cdr(written["/detections/markers"][0][1], "visualization_msgs/msg/MarkerArray")
    assert markers.markers[0].action == 3 and len(markers.markers) == len(arrays[0].detections) + 1  # DELETEALL
    scene = SceneUpdate.FromString(written["/detections/scene"][0][1])
    assert len(scene.entities[0].cubes) == len(arrays[0].detections)
    assert len(written["/fisheye_camera_front/image"]) == 3  # the images of the frames that ran

    # the overlays are the project's own projection of the same boxes
    first = detector.detect(recording.images[0])
    lines = project_boxes(first.boxes, rig, pixels_per_sample=OVERLAY_PIXELS_PER_SAMPLE)
    for camera in rig.names:
        overlay = ImageAnnotations.FromString(written[f"/{camera}/detections"][0][1])
        drawn = [np.array([[p.x, p.y] for p in a.points]) for a in overlay.points]
        want = [line for per_box in lines[camera] for line in per_box]
        assert len(drawn) == len(want) and all(np.abs(a - b).max() < 1e-4 for a, b in zip(drawn, want, strict=True))

    records = load_results(report.records)
    assert sorted(records) == sorted(str(s) for s in recording.stamps)
    assert json.loads(report.records.read_text())["meta"]["model_id"] == detector.info.meta.model_id


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="per-thread priorities are Linux's")
def test_the_writing_thread_takes_only_the_cores_the_model_leaves(
    small_export, recording: Recording, tmp_path: Path
) -> None:
    """Frames are written (and progress reported) on a thread at the lowest scheduling priority, 19."""
    rig = read_meta(small_export.onnx).rig
    niceness: list[int] = []
    progress = lambda done, most: niceness.append(os.getpriority(os.PRIO_PROCESS, threading.get_native_id()))
    before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    replay(small_export.onnx, [recording.mcap], _topics(rig.names), tmp_path / "o.mcap", threads=1, progress=progress)
    assert niceness and set(niceness) == {19}
    assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == before  # the caller's is its own


def test_sqlite3_and_ros1_bags_replay_to_the_same_detections(
    small_export, recording: Recording, tmp_path: Path
) -> None:
    rig = read_meta(small_export.onnx).rig
    outputs = []
    for bag in (recording.mcap, recording.sqlite, recording.ros1):
        out = tmp_path / f"{bag.stem}.mcap"
        report = replay(small_export.onnx, [bag], _topics(rig.names), out, threads=1)
        assert report.frames == 3 and report.dropped == recording.dropped
        outputs.append([data for _, data in _read_mcap(out)["/detections"]])
    assert outputs[0] == outputs[1] == outputs[2]
    ros_only = tmp_path / "ros_only.mcap"
    replay(small_export.onnx, [recording.mcap], _topics(rig.names), ros_only, foxglove=False, threads=1)
    with ros_only.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and {c.message_encoding for c in summary.channels.values()} == {"cdr"}


def test_cli_exit_code_says_whether_messages_were_dropped(
    small_export, recording: Recording, tmp_path: Path, capsys
) -> None:
    rig = read_meta(small_export.onnx).rig
    cameras = [f"--camera={c}=/{c}/image" for c in rig.names]
    code = main(["replay", str(small_export.onnx), str(recording.mcap), *cameras, "--out", str(tmp_path / "o.mcap")])
    printed = capsys.readouterr().out
    assert code == 3 and "4 unsynchronised" in printed and "3 incomplete at the end" in printed
    assert (
        main(["replay", str(small_export.onnx), str(recording.mcap), *cameras[:3], "--out", str(tmp_path / "p.mcap")])
        != 0
    )


def test_a_missing_topic_or_camera_is_named(small_export, recording: Recording, tmp_path: Path) -> None:
    rig = read_meta(small_export.onnx).rig
    topics = _topics(rig.names)
    with pytest.raises(OptionError, match="no topic given for fisheye_camera_rear"):
        replay(
            small_export.onnx,
            [recording.mcap],
            {k: v for k, v in topics.items() if "rear" not in k},
            tmp_path / "a.mcap",
        )
    with pytest.raises(OptionError, match="topic /fisheye_camera_front/image is given for more than one camera"):
        replay(
            small_export.onnx,
            [recording.mcap],
            {**topics, "fisheye_camera_rear": topics["fisheye_camera_front"]},
            tmp_path / "c.mcap",
        )
    with pytest.raises(OptionError, match="no such file or folder"):
        replay(small_export.onnx, [tmp_path / "none.mcap"], topics, tmp_path / "d.mcap")
    (tmp_path / "junk.bag").write_bytes(b"junk")
    with pytest.raises(BagError, match="cannot be read as a rosbag2 or ROS 1 bag"):
        replay(small_export.onnx, [tmp_path / "junk.bag"], topics, tmp_path / "e.mcap")
    with pytest.raises(OptionError, match=r"/nowhere: no such topic in the bag \(image topics: /fisheye_camera_front"):
        replay(small_export.onnx, [recording.mcap], {**topics, "fisheye_camera_rear": "/nowhere"}, tmp_path / "b.mcap")


def test_synchroniser_counts_each_reason() -> None:
    sync = Synchroniser(["a", "b"], tolerance_ns=10, queue_size=2)
    assert [s.stamps for s in sync.push("a", 100, "a0")] == []
    assert [s.stamps for s in sync.push("b", 105, "b0")] == [(100, 105)]
    assert list(sync.push("a", 90, "late")) == []  # older than a's last
    list(sync.push("a", 200, "a1"))
    list(sync.push("a", 300, "a2"))
    list(sync.push("a", 400, "a3"))  # b silent: a's queue holds 2
    assert [s.items for s in sync.push("b", 395, "b1")] == [("a3", "b1")]  # a2 found no b within 10 ns
    list(sync.push("b", 500, "b2"))
    sync.flush()
    assert sync.dropped == Counter(
        {"out of order": 1, "queue full": 1, "unsynchronised": 1, "incomplete at the end": 1}
    )


def test_image_encodings_are_read_or_refused_by_name() -> None:
    store = typestore()
    image = np.arange(4 * 5 * 3, dtype=np.uint8).reshape(4, 5, 3)
    for fmt in ("bgr8", "rgb8"):
        msg = _message(store, "sensor_msgs/msg/Image", fmt, image, 0, False)
        assert np.array_equal(image_from_message(msg), image)
    gray = store.types["sensor_msgs/msg/Image"](
        header=msg.header,
        height=4,
        width=5,
        encoding="mono8",
        is_bigendian=0,
        step=8,
        data=np.arange(32, dtype=np.uint8),
    )
    assert np.array_equal(image_from_message(gray)[:, :, 1], np.arange(32, dtype=np.uint8).reshape(4, 8)[:, :5])
    for bad in ("bgra8", "16UC1"):
        with pytest.raises(FrameError, match=f"image encoding '{bad}' is not read"):
            image_from_message(
                store.types["sensor_msgs/msg/Image"](
                    header=msg.header,
                    height=1,
                    width=1,
                    encoding=bad,
                    is_bigendian=0,
                    step=4,
                    data=np.zeros(4, np.uint8),
                )
            )
    depth = store.types["sensor_msgs/msg/CompressedImage"](
        header=msg.header, format="16UC1; compressedDepth", data=np.zeros(4, np.uint8)
    )
    with pytest.raises(FrameError, match="compressed format '16UC1; compressedDepth' is not read"):
        image_from_message(depth)


def test_replay_track_writes_track_ids_and_one_entity_per_track(
    small_export, recording: Recording, tmp_path: Path
) -> None:
    from fisheye_infer.tracking import Tracker, TrackerConfig

    rig = read_meta(small_export.onnx).rig
    out = tmp_path / "tracks.mcap"
    replay(small_export.onnx, [recording.mcap], _topics(rig.names), out, threads=1, track=True, score_threshold=0.0)
    store, written = typestore(), _read_mcap(out)
    arrays = [store.deserialize_cdr(data, "vision_msgs/msg/Detection3DArray") for _, data in written["/detections"]]
    detector, tracker = (
        Detector(small_export.onnx, threads=1),
        Tracker(TrackerConfig(score_threshold=0.0, low_score=0.0)),
    )
    for n, (array, images, stamp) in enumerate(zip(arrays, recording.images, recording.stamps, strict=True)):
        tracks = tracker.update(detector.detect(images), stamp / 1e9)
        assert len(tracks.ids) > 0 and [d.id for d in array.detections] == [str(i) for i in tracks.ids]
        scene = SceneUpdate.FromString(written["/detections/scene"][n][1])
        assert [e.id for e in scene.entities] == [f"track-{i}" for i in tracks.ids]
        assert all(len(e.arrows) == 1 and len(e.cubes) == 1 for e in scene.entities)
    assert any(len(e.lines) == 1 for e in scene.entities)  # the recent path of a track seen in earlier frames
    from fisheye_infer.ros.autoware import AUTOWARE_LABELS, track_uuid

    last = store.deserialize_cdr(written["/tracks"][-1][1], "autoware_perception_msgs/msg/TrackedObjects")
    assert [bytes(o.object_id.uuid) for o in last.objects] == [track_uuid(i) for i in tracks.ids]
    names = [tracks.class_names[label] for label in tracks.labels]
    for obj, box, velocity, name in zip(last.objects, tracks.boxes, tracks.velocities, names, strict=True):
        assert obj.classification[0].label == AUTOWARE_LABELS[name]
        twist = obj.kinematics.twist_with_covariance.twist.linear
        yaw = box[6]  # the twist is the velocity over ground in the box's own axes
        assert np.allclose(
            [twist.x * np.cos(yaw) - twist.y * np.sin(yaw), twist.x * np.sin(yaw) + twist.y * np.cos(yaw)],
            velocity,
            atol=1e-5,
        )
        assert np.allclose(
            [obj.shape.dimensions.x, obj.shape.dimensions.y, obj.shape.dimensions.z], box[3:6], atol=1e-5
        )
