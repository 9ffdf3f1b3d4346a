"""``fisheye-infer detect``: run a model on frames from files, write results JSON and pictures.

    fisheye-infer detect model.onnx --images frame_dir/ --out result.json --viz result.png
    fisheye-infer detect --result result.json --images frame_dir/ --viz result.png   # draw a saved result
    fisheye-infer detect model.onnx --ray --data ROOT --split val --out pred.json    # many frames with Ray Data
                                                                                     # (fisheye_infer.deploy.ray_batch)

The results file holds the model id, classes, the rig, and per frame the detections (the
runtime's records), the cameras used and the stage timings, so it can be drawn later on its own.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fisheye_infer.commands.common import PROVIDERS_HELP, positive_int, providers_arg
from fisheye_infer.errors import ConfigError, FrameError, OptionError

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig
    from fisheye_infer.runtime.detections import Detections

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", nargs="?", help="ONNX file written by fisheye-infer export")
    parser.add_argument(
        "--images",
        nargs="+",
        help="a folder (camera-named images, or one sub-folder per camera) or one file per camera in model order",
    )
    parser.add_argument("--result", help="draw this saved results file instead of running a model")
    parser.add_argument("--out", help="results JSON to write")
    parser.add_argument("--viz", help="PNG to write: fisheye images with projected boxes and a bird's-eye view")
    parser.add_argument(
        "--score-threshold", type=float, help="drop boxes below this score (default: keep all, as the official output)"
    )
    parser.add_argument("--classes", help="comma-separated class names to keep")
    parser.add_argument("--nms", choices=("rotated", "circle"), help="optional NMS (the official output has none)")
    parser.add_argument("--threads", type=positive_int, help="ONNX Runtime intra-op threads (default: all cores)")
    parser.add_argument("--providers", type=providers_arg, help=PROVIDERS_HELP)
    _configure_ray(parser)
    parser.set_defaults(run=run)


def _viz_paths(viz: Path, names: list[str]) -> list[Path]:
    return [viz] if len(names) == 1 else [viz.with_name(f"{viz.stem}_{n}{viz.suffix}") for n in names]


def _draw(viz: str, rig: Rig, frames: list[tuple[str, dict]], results: list[Detections]) -> None:
    import cv2

    from fisheye_infer.tools.viz import draw_detections, save_png

    for path, (_, files), dets in zip(_viz_paths(Path(viz), [n for n, _ in frames]), frames, results):
        images = {c: cv2.imread(str(p)) for c, p in files.items()} if files else None
        print(f"wrote {save_png(path, draw_detections(dets, rig, images))}")


def _draw_saved(args: argparse.Namespace) -> int:
    from fisheye_infer.cameras.rig import Rig
    from fisheye_infer.runtime.detections import Detections
    from fisheye_infer.runtime.preprocess import frames_from_paths

    try:
        doc = json.loads(Path(args.result).read_text())
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not UTF-8, not JSON, 4300+ digits
        raise FrameError(
            f"--result {args.result}: cannot be read as JSON ({str(exc)[:200] or 'nested too deep'})"
        ) from None
    missing = [k for k in ("rig", "classes", "frames") if not isinstance(doc, dict) or k not in doc]
    if missing:
        raise FrameError(
            f"--result {args.result}: missing {', '.join(missing)}; "
            "expected a file written by 'fisheye-infer detect --out'"
        )
    rig = Rig.from_dict(doc["rig"], source=f"results file {args.result}")
    classes = tuple(doc["classes"])
    frames = frames_from_paths(args.images, rig.names) if args.images else [(f["name"], {}) for f in doc["frames"]]
    results = []
    for i, f in enumerate(doc["frames"]):
        try:
            results.append(Detections.from_json(json.dumps(f), classes))
        except FrameError as exc:
            raise FrameError(f"--result {args.result}, frames[{i}]: {exc}") from None
    if len(frames) != len(results):
        raise FrameError(f"--images gives {len(frames)} frame(s), the results file holds {len(results)}")
    _draw(args.viz, rig, frames, results)
    return 0


def run(args: argparse.Namespace) -> int:
    if getattr(args, "ray", False):
        return _run_ray(args)
    if getattr(args, "data", None):
        raise FrameError("--data runs over a Fisheye3DOD split with --ray; without it, give --images")
    if args.result:
        if not args.viz:
            raise FrameError("--result needs --viz: drawing is all there is to do with a saved result")
        return _draw_saved(args)
    if not args.model or not args.images:
        raise FrameError("give a model and --images (or --result and --viz to draw a saved result)")
    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.runtime.nms import NmsConfig
    from fisheye_infer.runtime.preprocess import frames_from_paths

    nms = NmsConfig(kind=args.nms) if args.nms else None
    detector = Detector(
        args.model, threads=args.threads, providers=args.providers, score_threshold=args.score_threshold, nms=nms
    )
    frames = frames_from_paths(args.images, detector.info.cameras)
    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    unknown = sorted(set(classes or ()) - set(detector.info.classes))
    if unknown:
        raise OptionError(f"--classes: unknown {unknown}; the model's classes are {', '.join(detector.info.classes)}")
    results = [detector.detect(files, classes=classes) for _, files in frames]
    doc = {
        "model_id": detector.info.model_id,
        "classes": list(detector.info.classes),
        "rig": detector.info.rig.model_dump(mode="json"),
        "frames": [
            {"name": name, **json.loads(dets.to_json()), "records": dets.to_nuscenes()}
            for (name, _), dets in zip(frames, results)
        ],
    }
    for (name, _), dets in zip(frames, results):
        t = dets.timings_ms
        print(
            f"{name}: {len(dets)} boxes from {len(dets.cameras_used)} cameras in {sum(t.values()):.0f} ms "
            f"(decode {t['decode']:.0f}, preprocess {t['preprocess']:.0f}, "
            f"inference {t['inference']:.0f}, postprocess {t['postprocess']:.0f})"
        )
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(doc, indent=1))
        print(f"wrote {args.out}")
    if args.viz:
        _draw(args.viz, detector.info.rig, frames, results)
    return 0


# -- --ray: many frames with Ray Data (fisheye_infer.deploy.ray_batch) ------------------------------------------


def _configure_ray(parser: argparse.ArgumentParser) -> None:
    """The ``--ray`` group of ``fisheye-infer detect``."""
    group = parser.add_argument_group("batch inference with Ray Data (--ray; needs the [ray] extra)")
    group.add_argument(
        "--ray",
        action="store_true",
        help="run over many frames with Ray Data; --out is then one results file for 'eval --results'",
    )
    group.add_argument(
        "--data",
        help="Fisheye3DOD-layout root to run over (with --split); or give --images with one sub-folder per camera",
    )
    group.add_argument("--split", default="val", help="split file in ImageSets-2hz (default: val)")
    group.add_argument("--batch-size", type=int, default=2, help="frames per detect_batch call (default 2)")
    group.add_argument(
        "--concurrency", type=int, default=1, help="Detector actors, each with its own session (default 1)"
    )
    group.add_argument(
        "--cpus-per-actor",
        type=float,
        default=1.0,
        help="CPUs Ray reserves per actor (default 1); also its threads unless --threads",
    )


def _run_ray(args: argparse.Namespace) -> int:
    """``fisheye-infer detect MODEL --ray (--data ROOT | --images DIR) --out pred.json``."""
    from fisheye_infer.deploy.ray_batch import NEEDS_RAY, BatchOptions, dataset_frames, detect_frames
    from fisheye_infer.tools.progress import Progress

    refused = [
        flag
        for flag, value in (
            ("--result", args.result),
            ("--viz", args.viz),
            ("--score-threshold", args.score_threshold),
            ("--classes", args.classes),
            ("--nms", args.nms),
        )
        if value
    ]
    if refused:
        raise ConfigError(
            "--ray writes the official unthresholded output for evaluation; "
            f"{', '.join(refused)} cannot be combined with it"
        )
    if args.providers:
        raise ConfigError(
            "--providers: the --ray actors run on CPU (Ray reserves CPUs for them, not GPUs); "
            "run without --ray on a GPU"
        )
    if not args.model or not args.out or bool(args.data) == bool(args.images):
        raise ConfigError("--ray needs a MODEL, --out and exactly one of --data ROOT or --images")
    try:
        options = BatchOptions(
            batch_size=args.batch_size,
            concurrency=args.concurrency,
            cpus_per_actor=args.cpus_per_actor,
            threads=args.threads,
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    try:
        import ray
    except ImportError as exc:
        print(f"{NEEDS_RAY} ({exc})", file=sys.stderr)
        return 1
    from fisheye_infer.runtime.artifact import read_meta

    cameras = read_meta(args.model).cameras
    if args.data:
        from fisheye_infer.eval.dataset import Fisheye3DOD

        frames = dataset_frames(Fisheye3DOD(args.data, args.split, cameras=cameras))
        source = {"data": str(args.data), "split": args.split}
    else:
        from fisheye_infer.runtime.preprocess import frames_from_paths

        frames = [(name, files) for name, files in frames_from_paths(args.images, cameras)]
        source = {"images": [str(p) for p in args.images]}
    if not frames:
        raise FrameError("no frames to run")
    if not ray.is_initialized():
        ray.init(include_dashboard=False, configure_logging=False)  # RAY_ADDRESS, when set, joins that cluster
    print(
        f"running {len(frames)} frame(s) on {options.concurrency} actor(s), batches of {options.batch_size}",
        file=sys.stderr,
    )
    bar = Progress(len(frames), every=max(1, len(frames) // 20))
    result = detect_frames(args.model, frames, options, progress=lambda done, _: bar.update(done))
    path = result.save(args.out, {"model": str(args.model), **source})
    print(
        f"wrote {path}: {len(result.results)} frame(s) in {result.seconds:.1f} s "
        f"({result.frames_per_second:.2f} frames/s)"
    )
    for token, reason in result.failed.items():
        print(f"failed: {token}: {reason}", file=sys.stderr)
    if result.failed:
        print(f"{len(result.failed)} frame(s) failed; they are listed under meta.failed in {path}", file=sys.stderr)
        return 1
    return 0
