"""``fisheye-infer detect``: run a model on frames from files, write results JSON and pictures.

    fisheye-infer detect model.onnx --images frame_dir/ --out result.json --viz result.png
    fisheye-infer detect --result result.json --images frame_dir/ --viz result.png   # draw a saved result
    fisheye-infer detect model.onnx --ray --data ROOT --split val --out pred.json    # many frames with Ray Data (fisheye_infer.batch)

The results file holds the model id, classes, the rig, and per frame the detections (the
runtime's records), the cameras used and the stage timings, so it can be drawn later on its own.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2

from fisheye_infer.batch import configure_ray_flags, run_ray
from fisheye_infer.detections import Detections
from fisheye_infer.errors import FrameError
from fisheye_infer.nms import NmsConfig
from fisheye_infer.preprocess import frames_from_paths
from fisheye_infer.rig import Rig
from fisheye_infer.viz import draw_detections, save_png

__all__ = ["configure_detect", "run_detect"]


def configure_detect(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", nargs="?", help="ONNX file written by fisheye-infer export")
    parser.add_argument("--images", nargs="+", help="a folder (camera-named images, or one sub-folder per camera) or one file per camera in model order")
    parser.add_argument("--result", help="draw this saved results file instead of running a model")
    parser.add_argument("--out", help="results JSON to write")
    parser.add_argument("--viz", help="PNG to write: fisheye images with projected boxes and a bird's-eye view")
    parser.add_argument("--score-threshold", type=float, help="drop boxes below this score (default: keep all, as the official output)")
    parser.add_argument("--classes", help="comma-separated class names to keep")
    parser.add_argument("--nms", choices=("rotated", "circle"), help="optional NMS (the official output has none)")
    parser.add_argument("--threads", type=_positive_int, help="ONNX Runtime intra-op threads (default: all cores)")
    configure_ray_flags(parser)
    parser.set_defaults(run=run_detect)


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def _viz_paths(viz: Path, names: list[str]) -> list[Path]:
    return [viz] if len(names) == 1 else [viz.with_name(f"{viz.stem}_{n}{viz.suffix}") for n in names]


def _draw(viz: str, rig: Rig, frames: list[tuple[str, dict]], results: list[Detections]) -> None:
    for path, (_, files), dets in zip(_viz_paths(Path(viz), [n for n, _ in frames]), frames, results):
        images = {c: cv2.imread(str(p)) for c, p in files.items()} if files else None
        print(f"wrote {save_png(path, draw_detections(dets, rig, images))}")


def _draw_saved(args: argparse.Namespace) -> int:
    try:
        doc = json.loads(Path(args.result).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise FrameError(f"--result {args.result}: cannot be read as JSON ({exc})") from None
    missing = [k for k in ("rig", "classes", "frames") if not isinstance(doc, dict) or k not in doc]
    if missing:
        raise FrameError(f"--result {args.result}: missing {', '.join(missing)}; expected a file written by 'fisheye-infer detect --out'")
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


def run_detect(args: argparse.Namespace) -> int:
    if getattr(args, "ray", False):
        return run_ray(args)
    if getattr(args, "data", None):
        raise FrameError("--data runs over a Fisheye3DOD split with --ray; without it, give --images")
    if args.result:
        if not args.viz:
            raise FrameError("--result needs --viz: drawing is all there is to do with a saved result")
        return _draw_saved(args)
    if not args.model or not args.images:
        raise FrameError("give a model and --images (or --result and --viz to draw a saved result)")
    from fisheye_infer.detector import Detector

    nms = NmsConfig(kind=args.nms) if args.nms else None
    detector = Detector(args.model, threads=args.threads, score_threshold=args.score_threshold, nms=nms)
    frames = frames_from_paths(args.images, detector.info.cameras)
    classes = [c.strip() for c in args.classes.split(",") if c.strip()] if args.classes else None
    unknown = sorted(set(classes or ()) - set(detector.info.classes))
    if unknown:
        raise FrameError(f"--classes: unknown {unknown}; the model's classes are {', '.join(detector.info.classes)}")
    results = [detector.detect(files, classes=classes) for _, files in frames]
    doc = {
        "model_id": detector.info.model_id,
        "classes": list(detector.info.classes),
        "rig": detector.info.rig.model_dump(mode="json"),
        "frames": [{"name": name, **json.loads(dets.to_json()), "records": dets.to_nuscenes()} for (name, _), dets in zip(frames, results)],
    }
    for (name, _), dets in zip(frames, results):
        t = dets.timings_ms
        print(f"{name}: {len(dets)} boxes from {len(dets.cameras_used)} cameras in {sum(t.values()):.0f} ms "
              f"(decode {t['decode']:.0f}, preprocess {t['preprocess']:.0f}, inference {t['inference']:.0f}, postprocess {t['postprocess']:.0f})")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(doc, indent=1))
        print(f"wrote {args.out}")
    if args.viz:
        _draw(args.viz, detector.info.rig, frames, results)
    return 0
