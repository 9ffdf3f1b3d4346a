"""A recorded drive through a detector: ROS bags in, an MCAP file and nuScenes-style records out.

    report = replay("model.onnx", ["drive.mcap"], {"fisheye_camera_front": "/front/image/compressed", ...},
                    "detections.mcap")

Reads rosbag2 (MCAP or sqlite3) and ROS 1 bags (``rosbags.highlevel.AnyReader``), synchronises the
cameras' messages by header stamp (``sync.Synchroniser``), decodes them (``messages.image_from_message``,
on the ``Detector``'s decode threads), runs the ``Detector`` on batches of frames (its threads sleeping between
calls rather than spinning, so that the writing thread has the cores), and writes one MCAP file
(the ``mcap`` library; each batch on a thread of its own while the next one runs, in order, at the lowest
scheduling priority so that it takes only the cores the model leaves idle) with, per
synchronised frame and stamped with its first camera's header stamp:

- ``/detections`` (``vision_msgs/msg/Detection3DArray``) and ``/detections/markers``
  (``visualization_msgs/msg/MarkerArray``), ROS 2 messages in CDR;
- ``/detections/scene`` (``foxglove.SceneUpdate``) and ``/<camera>/detections`` (``foxglove.ImageAnnotations``:
  the boxes drawn through that camera's model), Foxglove's protobuf schemas;
- with ``images``, each camera's input message again, on its own topic, as recorded;
- with ``track``, tracks instead of boxes, and ``/tracks`` (``autoware_perception_msgs/msg/TrackedObjects``).

``score_threshold`` thins the messages' boxes; the records keep every box. Without ``foxglove`` the file
holds the ROS 2 channels only.

Beside it, ``<out>.json``: the nuScenes-style records of every frame (``{"results": {stamp: [...]}}``), which
``fisheye-infer eval --results`` reads. Messages and frames that could not be read, synchronised or decoded
are counted by reason in the ``ReplayReport``, with where each reason first occurred; images are decoded
only at the model's size (``messages.image_from_message``), so what a bag's images claim costs nothing.
A bag that cannot be read (damaged structure or compression, no messages on a camera's topic) is a
``BagError`` naming it, and nothing is written.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.highlevel import AnyReader

from fisheye_infer.errors import BagError, OptionError
from fisheye_infer.eval.evaluate import save_results
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.options import check_score_threshold
from fisheye_infer.tools.files import pending_file
from fisheye_infer.tracking import Tracker, TrackerConfig

from .mcap_output import DETECTIONS_TOPIC, McapOutput
from .messages import (
    IMAGE_TYPES,
    ImageRefused,
    image_from_message,
    stamp_ns,
    typestore,
)
from .sync import SyncedSet, Synchroniser

__all__ = ["DETECTIONS_TOPIC", "ReplayReport", "replay"]


@dataclass
class ReplayReport:
    """What a replay read, ran and wrote.

    Attributes:
        frames: Frames the model ran.
        messages: Camera messages read.
        dropped: Camera messages left out, by reason (the synchroniser's, ``does not deserialize``,
            ``stamp before 1970``).
        unread: Frames whose images did not give the model an image, by reason (``encoding 16UC1``,
            ``wrong size``, ``JPEG does not decode``, ...).
        examples: Where each reason first occurred (bag, topic, stamp, type) and why.
        seconds: Wall time of the replay.
        out: The MCAP file written.
        records: The nuScenes-style records written.
    """

    frames: int = 0
    messages: int = 0
    dropped: Counter[str] = field(default_factory=Counter)
    unread: Counter[str] = field(default_factory=Counter)
    examples: dict[str, str] = field(default_factory=dict)
    seconds: float = 0.0
    out: Path | None = None
    records: Path | None = None

    @property
    def undecodable(self) -> int:
        """Frames dropped because an image of theirs did not give the model an image."""
        return sum(self.unread.values())

    @property
    def complete(self) -> bool:
        """Whether every camera message became part of a frame that ran."""
        return not self.dropped and not self.unread

    def note(self, counter: Counter[str], reason: str, where: str) -> None:
        """Count one drop for ``reason``, keeping the first example.

        Args:
            counter: ``dropped`` or ``unread``.
            reason: Why the message or frame was left out.
            where: Where it happened (bag, topic, stamp), kept for the first drop of ``reason``.
        """
        counter[reason] += 1
        self.examples.setdefault(reason, where)

    def summary(self) -> str:
        """The counts and each reason's first example, as the command prints them."""
        rate = self.frames / self.seconds if self.seconds else 0.0
        lost = ", ".join(f"{n} {reason}" for reason, n in sorted(self.dropped.items())) or "none"
        unread = ", ".join(f"{n} {reason}" for reason, n in sorted(self.unread.items()))
        lines = [
            f"replayed {self.frames} frame(s) from {self.messages} camera message(s) in {self.seconds:.1f} s "
            f"({rate:.1f} frames/s)",
            f"camera messages dropped: {lost}; frames that did not decode: {self.undecodable}"
            + (f" ({unread})" if unread else ""),
        ]
        lines += [f"  first '{reason}': {where}" for reason, where in self.examples.items()]
        lines.append(f"wrote {self.out} and {self.records}")
        return "\n".join(lines)


def _yield_to_the_model() -> None:
    """Lower the calling thread's scheduling priority to the least (Linux; elsewhere nothing): the write thread then
    runs on the cores the model's threads leave idle, and never delays one of them, which would hold up the
    others at the end of each parallel step."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError):
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), 19)


def replay(
    model: str | Path,
    bags: Sequence[str | Path],
    topics: Mapping[str, str],
    out: str | Path,
    *,
    images: bool = False,
    foxglove: bool = True,
    score_threshold: float | None = None,
    frame_id: str = "lidar",
    tolerance_ms: float = 20.0,
    queue_size: int = 10,
    batch: int = 4,
    threads: int | None = None,
    track: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ReplayReport:
    """Replay recorded bags through a model into an MCAP file, and the detections as nuScenes-style records.

    See the module docstring for what the file holds; the records go to ``out`` with the suffix ``.json``.

    Args:
        model: An ONNX file written by ``fisheye-infer export``.
        bags: rosbag2 folders or files (MCAP or SQLite), read in order as one recording.
        topics: Each camera the model names -> its image topic (``sensor_msgs/Image`` or ``CompressedImage``).
        out: The MCAP file to write.
        images: Also write each camera's images (the overlays' background) to the file.
        foxglove: Also write the Foxglove channels (protobuf: the 3D scene and per-camera overlays); without them
            the file holds ROS 2 messages only.
        score_threshold: Keep the messages' boxes scoring at least this, in [0, 1] (the records keep every box,
            as evaluation needs); with ``track``, the tracker's birth threshold (default: the tracker's).
        frame_id: The frame the boxes are written in.
        tolerance_ms: How far apart (ms) the cameras' stamps of one frame may be.
        queue_size: Messages kept per camera while waiting for the others.
        batch: Frames run by the model at once.
        threads: ONNX Runtime intra-op threads (default: the CPUs this process may use).
        track: Write tracks instead of boxes: a [`Tracker`][fisheye_infer.tracking.tracker.Tracker] fed every box;
            each ``Detection3D`` id is the track id, one Foxglove entity per track with its velocity and recent
            path, and Autoware's ``TrackedObjects`` on ``/tracks``.
        progress: Called with the frames done and the most there can be (the fewest messages of one camera).

    Returns:
        ReplayReport: What was read, run, dropped and written.

    Raises:
        OptionError: An option is out of range, the topics do not name the model's cameras one to one, or a
            bag is missing.
        BagError: A bag cannot be read, or holds no message on the topics.
    """
    started = time.perf_counter()
    check_score_threshold(score_threshold)
    if not (isinstance(tolerance_ms, int | float) and math.isfinite(tolerance_ms) and tolerance_ms >= 0):
        raise OptionError(f"--tolerance-ms {tolerance_ms}: expected a finite number of milliseconds, 0 or more")
    for flag, value in (("--batch", batch), ("--queue", queue_size)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise OptionError(f"{flag} {value!r}: expected a whole number, 1 or more")
    tracker = None
    if track:
        score = TrackerConfig().score_threshold if score_threshold is None else score_threshold
        tracker = Tracker(TrackerConfig(score_threshold=score, low_score=score / 3))
    # the first batch warms it up; its threads sleep between calls, as the write and decode threads need the cores
    detector = Detector(model, threads=threads, warmup=False, spin=False)
    cameras = list(detector.info.cameras)
    missing = [c for c in cameras if c not in topics]
    extra = [c for c in topics if c not in cameras]
    if missing or extra:
        raise OptionError(
            f"--camera: the model's cameras are {', '.join(cameras)}; "
            + (f"no topic given for {', '.join(missing)}" if missing else f"{', '.join(extra)} is not one of them")
        )
    shared = sorted({t for t in topics.values() if list(topics.values()).count(t) > 1})
    if shared:
        raise OptionError(f"--camera: topic {', '.join(shared)} is given for more than one camera")
    missing_bags = [str(b) for b in bags if not Path(b).exists()]
    if missing_bags:
        raise OptionError(f"bag {', '.join(missing_bags)}: no such file or folder")
    out = Path(out)
    report = ReplayReport()
    sync = Synchroniser(cameras, int(tolerance_ms * 1e6), queue_size)
    camera_of = {topic: camera for camera, topic in topics.items()}
    store = typestore()
    results: dict[str, list[dict[str, Any]]] = {}
    named = ", ".join(map(str, bags))
    opened = contextlib.ExitStack()
    with _bag_errors(named, "cannot be read as a rosbag2 or ROS 1 bag"):
        reader = opened.enter_context(AnyReader([Path(b) for b in bags], default_typestore=store))
    with opened:
        connections = _camera_connections(reader, topics)
        expected = min(sum(c.msgcount for c in connections if c.topic == t) for t in topics.values())
        size_of = dict(zip(detector.info.cameras, detector.info.camera_sizes))  # each camera's own
        with (
            pending_file(out) as pending,
            open(pending.path, "wb") as stream,
            # done before the file closes
            ThreadPoolExecutor(1, thread_name_prefix="replay-write", initializer=_yield_to_the_model) as write_thread,
        ):
            writer = McapOutput(stream, connections if images else [], detector, foxglove, track)
            writing: Future[None] | None = None  # the batch being written while the next one runs
            pending_sets: list[SyncedSet] = []
            counted: Counter[str] = Counter()

            def decode(item: tuple[str, Any, Any]) -> np.ndarray | ImageRefused:
                cam, connection, msg = item
                try:
                    return image_from_message(msg, connection.topic, size_of[cam])
                except ImageRefused as exc:
                    return exc

            def run(sets: list[SyncedSet]) -> None:
                nonlocal writing
                items = [(cam, *item) for synced in sets for cam, item in zip(cameras, synced.items, strict=True)]
                decoded = iter(detector.map_images(decode, items))  # on the decode threads, in order
                frames, kept = [], []
                for synced in sets:
                    images = dict(zip(cameras, decoded))
                    refused = [(i, got) for i, got in enumerate(images.values()) if isinstance(got, ImageRefused)]
                    if refused:  # the first camera's reason, as a frame counts once
                        i, exc = refused[0]
                        connection, msg = synced.items[i]
                        report.note(report.unread, exc.reason, f"{_where(connection, msg)}: {exc}")
                        continue
                    frames.append(images)
                    kept.append(synced)
                if not frames:
                    return
                found = detector.detect_batch(frames)
                if writing is not None:
                    writing.result()  # the batch before is written (or its error raised) first
                writing = write_thread.submit(write, kept, found)

            def write(kept: list[SyncedSet], found: list[Detections]) -> None:
                for synced, detections in zip(kept, found, strict=True):
                    if tracker is None:
                        writer.write_frame(synced, detections.filter(min_score=score_threshold), frame_id)
                    else:
                        writer.write_tracks(synced, tracker.update(detections, synced.stamp / 1e9), frame_id)
                    results[str(synced.stamp)] = detections.to_nuscenes()
                    report.frames += 1
                    if progress is not None:
                        progress(report.frames, expected)

            for connection, logged, raw in _read(reader, connections, named):
                report.messages += 1
                counted[connection.topic] += 1
                try:
                    msg: Any = reader.deserialize(raw, connection.msgtype)
                except Exception as exc:  # rosbags' deserialisers raise what the damaged bytes provoke
                    where = f"bag {_bag(connection)}, {connection.topic} logged at {_seconds(logged)} s"
                    problem = f"{where} ({connection.msgtype}): {str(exc)[:200]}"
                    report.note(report.dropped, "does not deserialize", problem)
                    continue
                stamp = stamp_ns(msg.header)
                if stamp < 0:  # an MCAP log time is unsigned
                    report.note(report.dropped, "stamp before 1970", _where(connection, msg))
                    continue
                camera = camera_of[connection.topic]
                for synced in sync.push(camera, stamp, (connection, msg)):
                    pending_sets.append(synced)
                    if len(pending_sets) == batch:
                        run(pending_sets)
                        pending_sets = []
            run(pending_sets)
            if writing is not None:
                writing.result()
            silent = [t for t in topics.values() if not counted[t]]
            if silent:
                raise BagError(
                    f"bag {named}: no messages on {', '.join(silent)}"
                    + (" (nor on any camera topic)" if not report.messages else "")
                    + ", so no frame can be complete"
                )
            sync.flush()
            writer.finish()
            stream.close()
            report.out = pending.commit()
    report.dropped.update(sync.dropped)
    meta = {"model_id": detector.info.meta.model_id, "bags": [str(b) for b in bags], "topics": dict(topics)}
    report.records = save_results(out.with_suffix(".json"), results, meta)
    report.seconds = time.perf_counter() - started
    return report


@contextlib.contextmanager
def _bag_errors(named: str, problem: str) -> Iterator[None]:
    """Whatever the bag readers raise on damaged bytes, as a ``BagError`` naming the bags and the problem."""
    try:
        yield
    except BagError:
        raise
    except Exception as exc:  # rosbags raises its own errors, struct.error, AssertionError, OSError (bz2), ...
        reason = str(exc).strip()[:200] or type(exc).__name__
        raise BagError(f"bag {named}: {problem} ({reason})") from exc


def _read(reader: AnyReader, connections: Sequence[Any], named: str) -> Iterator[tuple[Any, int, bytes]]:
    """The cameras' messages in log-time order, (connection, log time in ns, raw bytes); a damaged bag is a
    ``BagError``."""
    messages = reader.messages(connections=connections)
    while True:
        with _bag_errors(named, "damaged, reading stopped"):
            item = next(messages, None)
        if item is None:
            return
        yield item


def _bag(connection: Any) -> str:
    return str(getattr(connection.owner, "path", "?"))


def _where(connection: Any, msg: Any) -> str:
    """Where a message is: its bag, topic, header stamp, type and encoding or format."""
    kind = f"encoding {msg.encoding!r}"[:60] if hasattr(msg, "encoding") else f"format {msg.format!r}"[:60]
    return (
        f"bag {_bag(connection)}, {connection.topic} at {_seconds(stamp_ns(msg.header))} s "
        f"({connection.msgtype.rsplit('/', 1)[-1]}, {kind})"
    )


def _seconds(ns: int) -> str:
    """Nanoseconds as seconds with all nine decimals, as ROS tools print stamps."""
    return f"{'-' if ns < 0 else ''}{abs(ns) // 10**9}.{abs(ns) % 10**9:09d}"


def _camera_connections(reader: AnyReader, topics: Mapping[str, str]) -> list[Any]:
    """The bags' connections of the cameras' topics (one per bag that records it); a missing topic or one of
    another type is refused."""
    by_topic: dict[str, list[Any]] = {}
    for c in reader.connections:
        by_topic.setdefault(c.topic, []).append(c)
    chosen = []
    for camera, topic in topics.items():
        found = by_topic.get(topic)
        if found is None:
            images = sorted(t for t, cs in by_topic.items() if cs[0].msgtype in IMAGE_TYPES) or ["none"]
            raise OptionError(
                f"--camera {camera}={topic}: no such topic in the bag (image topics: {', '.join(images)})"
            )
        for connection in found:
            if connection.msgtype not in IMAGE_TYPES:
                raise OptionError(
                    f"--camera {camera}={topic}: the topic holds {connection.msgtype}, not {' or '.join(IMAGE_TYPES)}"
                )
        chosen += found
    return chosen
