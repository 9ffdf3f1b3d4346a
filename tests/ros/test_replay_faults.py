"""Replay of hostile and damaged bags: written with ``rosbags`` (rosbag2 MCAP and ROS 1), then corrupted.

Each bad message is a counted, named drop (the reason, and where it first occurred); a bag whose structure
or compression is damaged, or that holds no messages on the cameras' topics, is a ``BagError`` naming the
bag, exit 1; nothing ends in a traceback, and a decompression bomb is refused before it is decoded.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")
pytest.importorskip("mcap")

from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from fisheye_infer.cli import main
from fisheye_infer.errors import BagError, OptionError
from fisheye_infer.ros.messages import typestore
from fisheye_infer.ros.replay import replay
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.codec import MAX_JPEG_SCANS

PERIOD_NS = 100_000_000
START_NS = 10**18
COMPRESSED, RAW = "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/Image"


def _picture(size: tuple[int, int], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return cv2.GaussianBlur(rng.integers(0, 256, (size[1], size[0], 3), dtype=np.uint8), (9, 9), 3)


def _jpeg(image: np.ndarray, *flags: int) -> bytes:
    return cv2.imencode(".jpg", image, list(flags))[1].tobytes()


def claiming(data: bytes, width: int, height: int) -> bytes:
    """A JPEG whose frame header (SOF0) states ``width`` x ``height``: a decompression bomb for a plain decoder."""
    sof = data.index(b"\xff\xc0")
    return data[: sof + 5] + struct.pack(">HH", height, width) + data[sof + 9 :]


def many_scans(image: np.ndarray, copies: int) -> bytes:
    """A progressive JPEG whose first scan is repeated ``copies`` times."""
    data = _jpeg(image, cv2.IMWRITE_JPEG_PROGRESSIVE, 1)
    first = data.index(b"\xff\xda")
    second = data.index(b"\xff\xda", first + 2)
    return data[:second] + data[first:second] * copies + data[second:]


def _header(store, stamp: int, ros1: bool):
    types = store.types
    sec, nanosec = divmod(stamp, 10**9)
    time = types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    extra = {"seq": 0} if ros1 else {}
    return types["std_msgs/msg/Header"](stamp=time, frame_id="cam", **extra)


def compressed(store, stamp: int, data: bytes, fmt: str = "jpeg", ros1: bool = False):
    return store.types[COMPRESSED](header=_header(store, stamp, ros1), format=fmt, data=np.frombuffer(data, np.uint8))


def raw_image(store, stamp: int, width: int, height: int, encoding: str, step: int, data: bytes, ros1: bool = False):
    return store.types[RAW](
        header=_header(store, stamp, ros1),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=np.frombuffer(data, np.uint8),
    )


def write_bag(path: Path, cameras: list[str], messages: list, ros1: bool = False, compression=None) -> Path:
    """``messages``: (camera, log time, message or raw bytes), each camera's topic ``/<camera>/image``; the
    left camera records ``sensor_msgs/Image``, the others ``CompressedImage``."""
    store = get_typestore(Stores.ROS1_NOETIC) if ros1 else typestore()
    writer = Writer1(path) if ros1 else Writer2(path, version=9, storage_plugin=StoragePlugin.MCAP)
    if compression is not None:
        writer.set_compression(compression)
    with writer:
        connections = {
            c: writer.add_connection(f"/{c}/image", RAW if "left" in c else COMPRESSED, typestore=store)
            for c in cameras
        }
        for camera, stamp, msg in messages:
            if not isinstance(msg, bytes):
                msgtype = RAW if "left" in camera else COMPRESSED
                msg = store.serialize_ros1(msg, msgtype) if ros1 else store.serialize_cdr(msg, msgtype)
            writer.write(connections[camera], stamp, msg)
    return path


def good_frames(cameras: list[str], size: tuple[int, int], frames: range, ros1: bool = False) -> list:
    store = get_typestore(Stores.ROS1_NOETIC) if ros1 else typestore()
    messages = []
    for i in frames:
        stamp = START_NS + i * PERIOD_NS
        for k, camera in enumerate(cameras):
            image = _picture(size, 10 * i + k)
            if "left" in camera:
                msg = raw_image(store, stamp, size[0], size[1], "bgr8", size[0] * 3, image.tobytes(), ros1)
            else:
                msg = compressed(store, stamp, _jpeg(image), ros1=ros1)
            messages.append((camera, stamp, msg))
    return messages


@pytest.fixture(scope="module")
def model(small_export) -> tuple[Path, list[str], tuple[int, int]]:
    meta = read_meta(small_export.onnx)
    return Path(small_export.onnx), list(meta.rig.names), tuple(meta.image_size)


def _topics(cameras: list[str]) -> dict[str, str]:
    return {c: f"/{c}/image" for c in cameras}


def _args(model: Path, bag: Path, cameras: list[str], out: Path) -> list[str]:
    return ["replay", str(model), str(bag), *(f"--camera={c}=/{c}/image" for c in cameras), "--out", str(out)]


#: Frame -> (camera kind, what replaces that camera's message, the reason it is counted under).
FAULTS = {
    1: ("front", "bomb", "wrong size"),
    2: ("front", "640x480", "wrong size"),
    3: ("front", "webp", "format jpeg holding WebP bytes"),
    4: ("front", "scans", "JPEG does not decode"),
    5: ("front", "truncated", "JPEG does not decode"),
    6: ("front", "tiff", "format tiff"),
    7: ("left", "16UC1", "encoding 16UC1"),
    8: ("left", "bayer_rggb8", "encoding bayer_rggb8"),
    9: ("left", "0x0", "wrong size"),
    10: ("left", "short data", "data shorter than its size"),
    11: ("left", "step 0", "step shorter than a row"),
}
GOOD = (0, 12)  # frames with no fault
DROPPED = {13: "does not deserialize", 14: "stamp before 1970"}  # the front camera's message, then frame 15


def _fault(store, kind: str, stamp: int, size: tuple[int, int]):
    w, h = size
    picture = _picture(size, 99)
    return {
        "bomb": lambda: compressed(store, stamp, claiming(_jpeg(picture), 30000, 30000)),
        "640x480": lambda: compressed(store, stamp, _jpeg(_picture((640, 480), 1))),
        "webp": lambda: compressed(store, stamp, cv2.imencode(".webp", picture)[1].tobytes()),
        "scans": lambda: compressed(store, stamp, many_scans(picture, 10_000)),
        "truncated": lambda: compressed(store, stamp, _jpeg(picture)[:-400]),
        "tiff": lambda: compressed(store, stamp, cv2.imencode(".tiff", picture)[1].tobytes(), fmt="tiff"),
        "16UC1": lambda: raw_image(store, stamp, w, h, "16UC1", w * 2, bytes(w * h * 2)),
        "bayer_rggb8": lambda: raw_image(store, stamp, w, h, "bayer_rggb8", w, bytes(w * h)),
        "0x0": lambda: raw_image(store, stamp, 0, 0, "bgr8", 0, b""),
        "short data": lambda: raw_image(store, stamp, w, h, "bgr8", w * 3, bytes(100)),
        "step 0": lambda: raw_image(store, stamp, w, h, "bgr8", 0, bytes(w * h * 3)),
    }[kind]()


@pytest.fixture(scope="module")
def hostile_bag(model, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames 0-15 of four cameras; each frame of ``FAULTS`` with one bad image, 13 with a front message that
    does not deserialize, 14 with a front header stamp of negative seconds."""
    _, cameras, size = model
    store = typestore()
    messages = []
    for camera, stamp, msg in good_frames(cameras, size, range(16)):
        i = (stamp - START_NS) // PERIOD_NS
        if i in FAULTS and FAULTS[i][0] in camera:
            msg = _fault(store, FAULTS[i][1], stamp, size)
        elif i == 13 and "front" in camera:
            msg = b"\x00\x01\x00\x00\x07"  # a CDR header, then nothing
        elif i == 14 and "front" in camera:
            msg = compressed(store, -(10**9), _jpeg(_picture(size, 5)))
        messages.append((camera, stamp, msg))
    return write_bag(tmp_path_factory.mktemp("hostile") / "drive", cameras, messages)


def test_bad_images_are_counted_drops_named_by_reason(model, hostile_bag: Path, tmp_path: Path, capsys) -> None:
    onnx, cameras, _ = model
    report = replay(onnx, [hostile_bag], _topics(cameras), tmp_path / "out.mcap", threads=1, batch=3)
    assert report.unread == Counter(reason for _, _, reason in FAULTS.values())
    assert report.dropped["does not deserialize"] == 1 and report.dropped["stamp before 1970"] == 1
    assert report.frames == len(GOOD) + 1  # frame 15 too: the synchroniser drops 13's and 14's other cameras
    assert json.loads(report.records.read_text())["results"].keys() == {
        str(START_NS + i * PERIOD_NS) for i in (*GOOD, 15)
    }
    examples = report.examples
    assert examples["wrong size"].startswith(f"bag {hostile_bag}, /{cameras[0]}/image at 1000000000.100000000 s")
    assert "image is 30000x30000, model expects 160x160" in examples["wrong size"]
    assert "(CompressedImage, format 'jpeg')" in examples["wrong size"]
    scans = f"(CompressedImage, format 'jpeg'): /{cameras[0]}/image: JPEG with more than {MAX_JPEG_SCANS} scans"
    assert scans in examples["JPEG does not decode"]
    assert "format 'jpeg' declared, the" in examples["format jpeg holding WebP bytes"]
    assert "bytes are WebP data" in examples["format jpeg holding WebP bytes"]
    assert "(Image, encoding '16UC1')" in examples["encoding 16UC1"]
    assert "step 0 is shorter than a row of 160 bgr8 pixels" in examples["step shorter than a row"]
    assert "needs 76800 bytes, holds 100" in examples["data shorter than its size"]
    assert " at -1.000000000 s" in examples["stamp before 1970"]
    assert " logged at 1000000001.300000000 s (sensor_msgs/msg/CompressedImage): " in examples["does not deserialize"]

    code = main(_args(onnx, hostile_bag, cameras, tmp_path / "cli.mcap"))
    printed = capsys.readouterr().out
    assert code == 3
    assert "frames that did not decode: 11 (" in printed and "3 wrong size" in printed and "1 encoding 16UC1" in printed
    assert "first 'encoding bayer_rggb8': bag" in printed and "1 does not deserialize" in printed


def test_the_decode_bomb_stays_within_the_services_bound(model, tmp_path: Path) -> None:
    """A 30000x30000 JPEG header (2.7 GB of pixels) is refused from its header: the replay's peak RSS is that of
    the model and a few frames, measured in a fresh process (5.3 GB when the bytes went to cv2.imdecode). The
    high-water mark of the process's own memory (``VmHWM``): ``ru_maxrss`` would carry pytest's across the fork."""
    if not Path("/proc/self/status").exists():
        pytest.skip("reads the peak RSS from Linux's /proc/self/status")
    onnx, cameras, size = model
    store = typestore()
    messages = [
        (c, stamp, _fault(store, "bomb", stamp, size) if "front" in c and stamp == START_NS else msg)
        for c, stamp, msg in good_frames(cameras, size, range(3))
    ]
    bag = write_bag(tmp_path / "bomb", cameras, messages)
    script = (
        "import re, sys\n"
        "from fisheye_infer.ros.replay import replay\n"
        "topics = dict(a.split('=') for a in sys.argv[4:])\n"
        "r = replay(sys.argv[1], [sys.argv[2]], topics, sys.argv[3], threads=1)\n"
        "peak = re.search(r'VmHWM:\\s*(\\d+)', open('/proc/self/status').read()).group(1)\n"
        "print(r.frames, dict(r.unread), peak)\n"
    )
    topics = [f"{c}=/{c}/image" for c in cameras]
    done = subprocess.run(
        [sys.executable, "-c", script, str(onnx), str(bag), str(tmp_path / "o.mcap"), *topics],
        capture_output=True,
        text=True,
        timeout=300,
        check=True,
    )
    words = done.stdout.strip().splitlines()[-1]
    peak_kib = int(words.rsplit(" ", 1)[1])
    assert words.startswith("2 {'wrong size': 1}")
    assert peak_kib < 512 * 1024, f"peak RSS {peak_kib / 1024:.0f} MiB"
    print(f"replay of a 30000x30000 JPEG header: peak RSS {peak_kib / 1024:.0f} MiB")


def test_a_corrupt_bz2_chunk_is_a_named_refusal(model, tmp_path: Path, capsys) -> None:
    onnx, cameras, size = model
    bag = write_bag(
        tmp_path / "bz2.bag",
        cameras,
        good_frames(cameras, size, range(2), ros1=True),
        True,
        Writer1.CompressionFormat.BZ2,
    )
    data = bytearray(bag.read_bytes())
    at = data.index(b"BZh") + 40
    data[at : at + 20] = bytes(20)
    bag.write_bytes(bytes(data))
    with pytest.raises(BagError, match=rf"bag {bag}: damaged, reading stopped \(Invalid data stream\)"):
        replay(onnx, [bag], _topics(cameras), tmp_path / "a.mcap", threads=1)
    assert main(_args(onnx, bag, cameras, tmp_path / "b.mcap")) == 1
    assert f"bag {bag}: damaged, reading stopped" in capsys.readouterr().err
    assert not (tmp_path / "b.mcap").exists()


def _records(data: bytes, start: int, end: int) -> list[tuple[int, int, int]]:
    """(offset, header length, op) of the ROS 1 records between ``start`` and ``end``."""
    found = []
    while start < end:
        header = struct.unpack_from("<I", data, start)[0]
        op = data[start + 4 : start + 4 + header].split(b"op=", 1)[1][0]
        found.append((start, header, op))
        start += 8 + header + struct.unpack_from("<I", data, start + 4 + header)[0]
    return found


@pytest.mark.parametrize(
    "where, value, expected",
    [
        ("message header", 0x7FFFFFF0, "damaged, reading stopped (Header could not be read"),
        ("message data", 0x7FFFFFF0, "damaged, reading stopped (Got only"),
        ("message header", 0, "damaged, reading stopped (Could not read uint8 field 'op'"),
        ("chunk data", 0x7FFFFFF0, "cannot be read as a rosbag2 or ROS 1 bag"),
        ("chunk data", 0, "cannot be read as a rosbag2 or ROS 1 bag"),
        ("index", 0x7FFFFFF0, "cannot be read as a rosbag2 or ROS 1 bag"),
    ],
)
def test_damaged_record_lengths_are_named_refusals(
    model, tmp_path: Path, where: str, value: int, expected: str
) -> None:
    """ROS 1 record lengths set to 0x7FFFFFF0 or 0: in a message record inside a chunk (met while reading), in
    the chunk record or the index (met when the bag is opened)."""
    onnx, cameras, size = model
    bag = write_bag(tmp_path / "d.bag", cameras, good_frames(cameras, size, range(2), ros1=True), ros1=True)
    data = bytearray(bag.read_bytes())
    records = _records(bytes(data), 13, len(data))
    chunk_at, chunk_header, _ = next(r for r in records if r[2] == 0x05)
    body = chunk_at + 8 + chunk_header
    inner = _records(bytes(data), body, body + struct.unpack_from("<I", data, chunk_at + 4 + chunk_header)[0])
    message_at, message_header, _ = next(r for r in inner if r[2] == 0x02)
    offset = {
        "message header": message_at,
        "message data": message_at + 4 + message_header,
        "chunk data": chunk_at + 4 + chunk_header,
        "index": next(r for r in records if r[2] == 0x07)[0],
    }[where]
    struct.pack_into("<I", data, offset, value)
    bag.write_bytes(bytes(data))
    with pytest.raises(BagError, match=f"bag {bag}: " + expected.replace("(", r"\(")):
        replay(onnx, [bag], _topics(cameras), tmp_path / "a.mcap", threads=1)


def test_a_message_record_of_length_zero_is_a_counted_drop(model, tmp_path: Path) -> None:
    onnx, cameras, size = model
    bag = write_bag(tmp_path / "z.bag", cameras, good_frames(cameras, size, range(3), ros1=True), ros1=True)
    data = bytearray(bag.read_bytes())
    records = _records(bytes(data), 13, len(data))
    chunk_at, chunk_header, _ = next(r for r in records if r[2] == 0x05)
    body = chunk_at + 8 + chunk_header
    inner = _records(bytes(data), body, body + struct.unpack_from("<I", data, chunk_at + 4 + chunk_header)[0])
    message_at, message_header, _ = next(r for r in inner if r[2] == 0x02)
    length_at = message_at + 4 + message_header
    old = struct.unpack_from("<I", data, length_at)[0]
    # the message's data becomes empty; its bytes stay, read as the padding of a record of no known kind
    data[length_at : length_at + 4 + old] = struct.pack("<I", 0) + bytes(old)
    bag.write_bytes(bytes(data))
    report = replay(onnx, [bag], _topics(cameras), tmp_path / "a.mcap", threads=1)
    assert report.dropped["does not deserialize"] == 1 and not report.complete
    assert report.examples["does not deserialize"].startswith(f"bag {bag}, /")


def test_topics_without_messages_are_a_named_refusal(model, tmp_path: Path, capsys) -> None:
    onnx, cameras, size = model
    empty = write_bag(tmp_path / "empty", cameras, [])
    with pytest.raises(BagError, match=rf"bag {empty}: no messages on /{cameras[0]}/image.* \(nor on any camera"):
        replay(onnx, [empty], _topics(cameras), tmp_path / "a.mcap", threads=1)
    assert main(_args(onnx, empty, cameras, tmp_path / "b.mcap")) == 1
    assert "so no frame can be complete" in capsys.readouterr().err and not (tmp_path / "b.mcap").exists()
    one_silent = write_bag(
        tmp_path / "silent", cameras, [m for m in good_frames(cameras, size, range(2)) if "rear" not in m[0]]
    )
    with pytest.raises(BagError, match=rf"no messages on /{cameras[-1]}/image, so no frame"):
        replay(onnx, [one_silent], _topics(cameras), tmp_path / "c.mcap", threads=1)


def test_two_bags_are_read_whole(model, tmp_path: Path) -> None:
    """A drive split in two bags: each bag's messages of a topic are read (not the last bag's only)."""
    onnx, cameras, size = model
    first = write_bag(tmp_path / "one", cameras, good_frames(cameras, size, range(2)))
    second = write_bag(tmp_path / "two", cameras, good_frames(cameras, size, range(2, 4)))
    report = replay(onnx, [first, second], _topics(cameras), tmp_path / "a.mcap", threads=1)
    assert report.frames == 4 and report.messages == 16 and report.complete


@pytest.mark.parametrize(
    "options, words",
    [
        ({"tolerance_ms": float("nan")}, "--tolerance-ms nan: expected a finite number of milliseconds"),
        ({"tolerance_ms": -5.0}, "--tolerance-ms -5.0: expected a finite number"),
        ({"tolerance_ms": float("inf")}, "--tolerance-ms inf"),
        ({"score_threshold": 2.0}, r"score_threshold: expected a number in \[0, 1\], got 2.0"),
        ({"batch": 0}, "--batch 0: expected a whole number, 1 or more"),
        ({"queue_size": 1.5}, "--queue 1.5: expected a whole number"),
    ],
)
def test_options_are_refused_before_the_model_loads(tmp_path: Path, options: dict, words: str) -> None:
    """NaN or infinite tolerances were a ValueError or OverflowError traceback; the model path given does not
    exist, so a refusal that named it would mean the options were checked too late."""
    with pytest.raises(OptionError, match=words):
        replay(tmp_path / "none.onnx", [tmp_path], {"front": "/front"}, tmp_path / "a.mcap", **options)
