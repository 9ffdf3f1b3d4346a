"""Bag replay throughput: a recorded drive through a model into an MCAP file, with and without the images.

    python benchmarks/replay.py compact [--frames 100 --rounds 5 --threads 2] [--quick]

1. ``--frames`` synthetic frames of the model's rig at 10 Hz, each camera a ``sensor_msgs/CompressedImage``
   (JPEG) with its stamp jittered by up to 2 ms, written as a rosbag2 MCAP bag with ``rosbags``;
2. ``fisheye-infer replay``'s work (``fisheye_infer.ros.replay.replay``: read, synchronise, decode, detect in
   batches of 4, write detections, markers, the Foxglove scene and per-camera overlays) timed end to end,
   in turns: every box the model outputs, the same with ``--images``, and ``--score-threshold 0.3`` with
   ``--images`` (fewer boxes to draw): frames per second from start to end (opening the bag, loading the
   model and its first run on a batch, which allocates, included), and after the first batch (from its boxes
   written to the last frame's, as a long drive runs);
   and in the same turns the model's own frame rate: ``Detector.detect_batch`` on the bag's frames, decoded
   beforehand, in the batches replay runs (4 frames) with the same threads, timed alone after a warm-up batch.
   each setting's ``replay/model`` is the median over rounds of its rate after the first batch over the
   model's in the same round (a round runs every setting once, so a neighbour's load falls on both alike);
3. ``docs/assets/replay-overlay.png``: a frame's front camera image with the overlay read back from the
   MCAP file of the third setting (``/<camera>/detections``, drawn as written), beside
   ``fisheye-infer detect --viz``'s picture of the same frame and boxes.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np
from model_files import ARTIFACTS, MODEL_HELP, model_path

FRAMES_HZ = 10
#: Frames per model run, as ``fisheye-infer replay`` runs them by default.
BATCH = 4
#: The row of the model's own frame rate.
MODEL = "model alone (Detector.detect_batch)"
#: The score threshold of the third setting and of the picture.
SHOWN = 0.3
OVERLAY = Path(__file__).resolve().parents[1] / "docs" / "assets" / "replay-overlay.png"


def write_bag(model: Path, folder: Path, frames: int) -> dict[str, str]:
    """The rosbag2 MCAP bag of ``frames`` rendered frames; the camera -> topic map."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    from fisheye_infer.ros.messages import typestore
    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.scenes.render import Renderer, random_scene

    rig = read_meta(model).rig
    store = typestore().types
    topics = {camera: f"/{camera}/image/compressed" for camera in rig.names}
    rng = np.random.default_rng(0)
    renderer = Renderer(texture_seed=0)
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {
            c: writer.add_connection(t, "sensor_msgs/msg/CompressedImage", typestore=typestore())
            for c, t in topics.items()
        }
        for i in range(frames):
            frame = renderer.render(rig, random_scene(np.random.default_rng(5000 + i)))
            for camera, image in frame.items():
                stamp = 10**18 + i * 10**9 // FRAMES_HZ + int(rng.integers(0, 2_000_000))
                time = store["builtin_interfaces/msg/Time"](sec=stamp // 10**9, nanosec=stamp % 10**9)
                header = store["std_msgs/msg/Header"](stamp=time, frame_id=camera)
                data = np.frombuffer(cv2.imencode(".jpg", image)[1].tobytes(), np.uint8)
                msg = store["sensor_msgs/msg/CompressedImage"](header=header, format="jpeg", data=data)
                raw = typestore().serialize_cdr(msg, "sensor_msgs/msg/CompressedImage")
                writer.write(connections[camera], stamp, raw)
    return topics


def overlay_picture(model: Path, out_mcap: Path, camera: str, index: int = 0) -> np.ndarray:
    """The camera's image with the MCAP file's overlay for it, beside ``draw_detections`` of the same frame."""
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from mcap.reader import make_reader

    from fisheye_infer.ros.messages import image_from_message, typestore
    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.tools.viz import draw_detections

    images: dict[str, list[np.ndarray]] = {}
    overlays: list[ImageAnnotations] = []
    with out_mcap.open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if channel.topic.endswith("/image/compressed"):
                msg = typestore().deserialize_cdr(message.data, "sensor_msgs/msg/CompressedImage")
                images.setdefault(channel.topic.split("/")[1], []).append(image_from_message(msg))
            elif channel.topic == f"/{camera}/detections":
                overlays.append(ImageAnnotations.FromString(message.data))
    picture = images[camera][index].copy()
    for line in overlays[index].points:
        points = np.round([[p.x, p.y] for p in line.points]).astype(np.int32)
        c = line.outline_color
        cv2.polylines(picture, [points], False, (int(c.b * 255), int(c.g * 255), int(c.r * 255)), 2, cv2.LINE_AA)
    detector = Detector(model)
    frame = {name: stack[index] for name, stack in images.items()}
    viz = draw_detections(detector.detect(frame).filter(min_score=SHOWN), detector.info.meta.rig, frame)
    left = cv2.resize(picture, (viz.shape[0], viz.shape[0]), interpolation=cv2.INTER_AREA)
    return np.hstack([left, viz])


def decoded_batches(bag: Path, topics: dict[str, str], detector: Any, batch: int) -> list[list[dict[str, np.ndarray]]]:
    """The bag's frames (each camera's n-th message) decoded as replay decodes them, in batches of ``batch``."""
    from rosbags.highlevel import AnyReader

    from fisheye_infer.ros.messages import image_from_message, typestore

    size_of = dict(zip(detector.info.cameras, detector.info.camera_sizes))
    images: dict[str, list[np.ndarray]] = {camera: [] for camera in topics}
    camera_of = {topic: camera for camera, topic in topics.items()}
    with AnyReader([bag], default_typestore=typestore()) as reader:
        wanted = [c for c in reader.connections if c.topic in camera_of]
        for connection, _, raw in reader.messages(connections=wanted):
            camera = camera_of[connection.topic]
            msg = reader.deserialize(raw, connection.msgtype)
            images[camera].append(image_from_message(msg, connection.topic, size_of[camera]))
    frames = [dict(zip(images, row)) for row in zip(*images.values())]
    return [frames[i : i + batch] for i in range(0, len(frames), batch)]


def main(argv: list[str] | None = None) -> int:
    from fisheye_infer.ros.replay import replay
    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.tools.viz import save_png

    bench = harness.Benchmark(__file__, __doc__, quick="20 frames, 2 rounds")
    p = bench.parser
    p.add_argument("model", nargs="?", default="compact", help=MODEL_HELP)
    p.add_argument("--frames", type=int, default=100, help="frames in the bag (default 100)")
    p.add_argument("--rounds", type=int, default=5, help="replays per setting, settings in turns (default 5)")
    p.add_argument("--threads", type=int, default=2, help="ONNX Runtime intra-op threads (default 2)")
    args = bench.parse(argv)
    if args.quick:
        args.frames, args.rounds = 20, 2

    model = model_path(args.model)
    work = ARTIFACTS / "replay"
    bag = work / f"drive-{args.frames}"
    work.mkdir(parents=True, exist_ok=True)
    if not bag.exists():
        topics = write_bag(model, bag, args.frames)
    else:
        from fisheye_infer.runtime.artifact import read_meta

        topics = {camera: f"/{camera}/image/compressed" for camera in read_meta(model).rig.names}

    detector = Detector(model, threads=args.threads)
    batches = decoded_batches(bag, topics, detector, BATCH)

    def model_rate() -> float:
        detector.detect_batch(batches[0])
        started = time.perf_counter()
        for frames in batches:
            detector.detect_batch(frames)
        return sum(map(len, batches)) / (time.perf_counter() - started)

    def run(images: bool, threshold: float | None = None) -> tuple[float, float]:
        out = work / f"out-{images}-{threshold}.mcap"
        written: list[tuple[int, float]] = []
        report = replay(
            model,
            [bag],
            topics,
            out,
            images=images,
            score_threshold=threshold,
            batch=BATCH,
            threads=args.threads,
            progress=lambda done, _: written.append((done, time.perf_counter())),
        )
        if report.frames != args.frames or not report.complete:
            raise SystemExit(f"replay: {report.summary()}")
        (first, start), (last, end) = written[BATCH - 1], written[-1]
        return report.frames / report.seconds, (last - first) / (end - start)

    settings = {
        MODEL: lambda: (model_rate(),) * 2,
        "every box": lambda: run(False),
        "every box, with --images": lambda: run(True),
        "--score-threshold 0.3, with --images": lambda: run(True, SHOWN),
    }
    rates = harness.in_turns(settings, args.rounds, flip=True)
    model_rates = [steady for _, steady in rates[MODEL]]
    rows = [
        {
            "output": name,
            "frames": args.frames,
            "frames/s median": float(np.median([whole for whole, _ in r])),
            "frames/s min": min(whole for whole, _ in r),
            "after the first batch: frames/s median": float(np.median([steady for _, steady in r])),
            "replay/model": float(np.median(np.divide([steady for _, steady in r], model_rates))),
        }
        for name, r in rates.items()
    ]
    save_png(OVERLAY, overlay_picture(model, work / f"out-True-{SHOWN}.mcap", next(iter(topics))))
    bench.save(args, {f"Replay of {args.frames} frames, {args.threads} threads, batches of {BATCH}": rows})
    print(f"wrote {OVERLAY}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
