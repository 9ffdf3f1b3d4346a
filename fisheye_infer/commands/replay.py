"""``fisheye-infer replay``: a recorded bag through a model, into an MCAP file that ROS 2 tools and Foxglove open.

fisheye-infer replay model.onnx drive.mcap --camera fisheye_camera_front=/front/image/compressed ... --out out.mcap

Exit code 0 when every camera message became part of a frame that ran, 3 when some were dropped
(unsynchronised, out of order, a full queue, incomplete at the end, not deserialisable, stamped before
1970, or an image that does not decode at the model's size; the summary counts each reason and names
where it first occurred), 1 when a bag cannot be read (damaged, or no messages on a camera's topic).
"""

from __future__ import annotations

import argparse
import sys

from fisheye_infer.commands.common import missing_extra, positive_int

__all__ = ["DROPPED_EXIT", "configure", "run"]

#: The exit code of a replay that completed but dropped camera messages.
DROPPED_EXIT = 3
NEEDS_ROS = "fisheye-infer replay needs the ros extra: pip install 'fisheye-infer[ros]'"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="an ONNX file written by fisheye-infer export")
    parser.add_argument("bags", nargs="+", help="rosbag2 folders or .mcap/.db3 files, or ROS 1 .bag files")
    parser.add_argument(
        "--camera",
        action="append",
        required=True,
        metavar="NAME=TOPIC",
        help="a camera the model names and its sensor_msgs/Image or CompressedImage topic; one per camera",
    )
    parser.add_argument("--out", required=True, help="MCAP file to write; the records go beside it as .json")
    parser.add_argument("--images", action="store_true", help="also write the camera messages into the MCAP file")
    parser.add_argument(
        "--no-foxglove",
        dest="foxglove",
        action="store_false",
        help="leave out the Foxglove channels (protobuf): the file then holds ROS 2 messages only",
    )
    parser.add_argument(
        "--score-threshold",
        type=float,
        help="keep the messages' boxes scoring at least this (default: every box); the records keep every box",
    )
    parser.add_argument(
        "--track",
        action="store_true",
        help="write tracks instead of boxes: each Detection3D's id its track id, one Foxglove entity per track with "
        "its velocity and recent path; --score-threshold then starts tracks (default 0.3)",
    )
    parser.add_argument("--frame-id", default="lidar", help="frame id of the detections (default: lidar)")
    parser.add_argument(
        "--tolerance-ms",
        type=float,
        default=20.0,
        help="largest spread of the cameras' header stamps within one frame (default 20 ms)",
    )
    parser.add_argument("--queue", type=positive_int, default=10, help="messages held per camera (default 10)")
    parser.add_argument("--batch", type=positive_int, default=4, help="frames per detector call (default 4)")
    parser.add_argument("--threads", type=positive_int, help="ONNX Runtime intra-op threads (default: its own)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from fisheye_infer.ros.replay import replay
    except ImportError as exc:
        return missing_extra(NEEDS_ROS, exc)
    from fisheye_infer.tools.progress import Progress

    topics = {}
    for spec in args.camera:
        name, equals, topic = spec.partition("=")
        if not equals or not name or not topic:
            print(f"fisheye-infer replay: error: --camera {spec!r}: expected NAME=TOPIC", file=sys.stderr)
            return 2
        topics[name] = topic
    bar = Progress(total=0, every=50)

    def progress(done: int, expected: int) -> None:
        bar.total = expected
        bar.update(done)

    report = replay(
        args.model,
        args.bags,
        topics,
        args.out,
        images=args.images,
        foxglove=args.foxglove,
        score_threshold=args.score_threshold,
        frame_id=args.frame_id,
        tolerance_ms=args.tolerance_ms,
        queue_size=args.queue,
        batch=args.batch,
        threads=args.threads,
        track=args.track,
        progress=progress,
    )
    print(report.summary())
    return 0 if report.complete else DROPPED_EXIT
