"""``fisheye-infer eval`` and ``fisheye-infer synth``: argparse wiring around the reader, the metric and the renderer.

    fisheye-infer eval --results pred.json --ground-truth gt.json --out report.json
    fisheye-infer eval model.onnx --data ROOT --split val [--limit N] [--cameras front,rear] --out report.json
    fisheye-infer synth --rig default --frames 4 --out data/synth [--seed 0] [--scale 0.25]
    fisheye-infer synth --stream val --rig runs/compact/rig.json --frames 200 --out data/heldout

Each command writes the report JSON, a Markdown report beside it (same name, ``.md``) and prints
the tables. The model form runs the ONNX runtime ``Detector`` on every frame of the split and
evaluates its unthresholded output, as the official numbers are computed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results, load_results, save_results
from fisheye_infer.eval.metrics import EvalConfig, MetricsReport
from fisheye_infer.rig import Rig

__all__ = ["configure_eval", "run_eval", "configure_synth", "run_synth"]

def _csv(text: str) -> list[str]:
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    return items

def _int_pair(text: str) -> tuple[int, int]:
    try:
        lo, hi = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN,MAX (two integers), got {text!r}") from None
    if not 0 <= lo <= hi:
        raise argparse.ArgumentTypeError(f"expected 0 <= MIN <= MAX, got {text!r}")
    return lo, hi

def configure_eval(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``fisheye-infer eval``."""
    parser.add_argument("model", nargs="?", help="exported model (.onnx) to run on --data; omit to evaluate saved results")
    files = parser.add_argument_group("saved results")
    files.add_argument("--results", help='predictions: {"results": {sample_token: [record, ...]}}')
    files.add_argument("--ground-truth", help="ground truth in the same format (detection_score optional, ignored)")
    files.add_argument("--allow-missing", action="store_true", help="count ground-truth samples absent from --results as frames with no detections")
    data = parser.add_argument_group("running a model")
    data.add_argument("--data", help="Fisheye3DOD-layout root (calib_results.txt, ImageSets-2hz/, scenes)")
    data.add_argument("--split", default="val", help="split file in ImageSets-2hz (default: val)")
    data.add_argument("--limit", type=int, help="evaluate the first N samples of the split")
    data.add_argument("--scenes", type=_csv, help="comma-separated scene names to keep")
    data.add_argument("--cameras", type=_csv, help="cameras to feed (e.g. front,rear); the others are marked missing")
    data.add_argument("--threads", type=int, help="ONNX Runtime intra-op threads")
    data.add_argument("--save-results", help="also write the predictions and ground truth (<name>.json, <name>.gt.json)")
    parser.add_argument("--config", help="metric settings as JSON (default: the official Fisheye3DOD settings)")
    parser.add_argument("--ref-range", type=float, help="scale every class range by REF_RANGE/48 (the paper's 0-30 m is 30)")
    parser.add_argument("--out", required=True, help="report JSON to write; the Markdown report goes beside it")
    parser.set_defaults(run=run_eval)

def _config(args: argparse.Namespace) -> EvalConfig:
    config = EvalConfig.load(args.config) if args.config else EvalConfig()
    if args.ref_range is not None:
        config = EvalConfig.from_dict({**config.serialize(), "ref_range": args.ref_range}, source="--ref-range")
    return config

def _write_report(report: MetricsReport, out: str | Path) -> None:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(report.to_json() + "\n")
    markdown = report.to_markdown()
    out.with_suffix(".md").write_text(markdown)
    print(markdown)
    print(f"wrote {out} and {out.with_suffix('.md')}")

def _fail(message: str) -> int:
    print(f"fisheye-infer eval: error: {message}", file=sys.stderr)
    return 2

def run_eval(args: argparse.Namespace) -> int:
    """Evaluate saved results, or run a model over a split and evaluate its output."""
    config = _config(args)
    if Path(args.out).suffix.lower() == ".md":
        return _fail(f"--out names the report JSON; the Markdown report is written beside it (got {args.out})")
    if args.model is None:
        if not (args.results and args.ground_truth):
            return _fail("give --results and --ground-truth, or a MODEL with --data")
        if args.data:
            return _fail("--data needs a MODEL to run; saved results are evaluated with --results/--ground-truth only")
        report = evaluate_results(load_results(args.ground_truth), load_results(args.results), config, allow_missing=args.allow_missing)
        _write_report(report, args.out)
        return 0
    if args.results or args.ground_truth:
        return _fail("a MODEL is evaluated on --data; --results/--ground-truth are for saved results")
    if not args.data:
        return _fail("a MODEL needs --data ROOT (a Fisheye3DOD-layout folder)")
    from fisheye_infer.detector import Detector
    from fisheye_infer.eval.dataset import Fisheye3DOD, camera_name

    detector = Detector(args.model, threads=args.threads)
    if tuple(detector.info.classes) != tuple(config.class_names):
        return _fail(f"the model's classes {list(detector.info.classes)} differ from the metric's {list(config.class_names)}")
    cameras = [camera_name(c) for c in args.cameras] if args.cameras else list(detector.info.cameras)
    dataset = Fisheye3DOD(args.data, args.split, cameras=cameras, scenes=args.scenes, limit=args.limit, class_names=config.class_names)
    gt, pred = detect_dataset(detector, dataset)
    if args.save_results:
        path = Path(args.save_results)
        meta = {"model": str(args.model), "data": str(args.data), "split": args.split, "cameras": cameras}
        save_results(path, pred, meta)
        save_results(path.with_suffix(".gt.json"), gt, meta)
    _write_report(evaluate_results(gt, pred, config), args.out)
    return 0

def configure_synth(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``fisheye-infer synth``."""
    parser.add_argument("--rig", default="default", help="rig file (.json/.yaml), folder with calib_results.txt + lidar2cam.json, or 'default'")
    parser.add_argument("--frames", type=int, default=1, help="frames to render (default: 1)")
    parser.add_argument("--out", required=True, help="dataset root to write (Fisheye3DOD layout; existing splits are extended)")
    parser.add_argument("--seed", type=int, default=0, help="scene seed (default: 0); the same seed writes the same files")
    parser.add_argument("--split", help="split file to add the frames to (default: val, or the --stream's name)")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale, e.g. 0.25 for 200x200 from an 800x800 rig")
    parser.add_argument("--objects", type=_int_pair, default=(6, 14), help="MIN,MAX objects per frame (default: 6,14)")
    parser.add_argument("--ground-height", type=float, default=2.0, help="ground plane below the lidar, metres (default: 2)")
    parser.add_argument("--scene", help="scene name (default: synth-Town00-ClearNoon-seed<SEED>)")
    parser.add_argument("--stream", choices=("train", "val"),
                        help="write frames of the randomised stream `fisheye-infer train` draws from (scenes, looks and seeds as it "
                             "renders them; 'val' is never trained on) instead of the plain scenes; the split file defaults to the stream's name")
    parser.add_argument("--first", type=int, default=0, help="with --stream: index of the first frame written (default 0)")
    parser.set_defaults(run=run_synth)

def run_synth(args: argparse.Namespace) -> int:
    """Render synthetic frames of a rig into a Fisheye3DOD-layout folder."""
    from fisheye_infer.rig import resolve_rig
    from fisheye_infer.synth import resized_rig, synthesize

    if args.frames < 1:
        print(f"fisheye-infer synth: error: --frames must be at least 1, got {args.frames}", file=sys.stderr)
        return 2
    rig = resolve_rig(args.rig)
    if args.scale != 1.0:
        rig = resized_rig(rig, args.scale)
    if args.stream:
        return _write_stream(args, rig)
    if args.first != 0:
        print("fisheye-infer synth: error: --first needs --stream", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    frames = synthesize(rig, args.out, frames=args.frames, seed=args.seed, split=args.split or "val", scene_name=args.scene, num_objects=args.objects, ground_height=args.ground_height)
    seconds = time.perf_counter() - t0
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    boxes = sum(len(f.boxes) for f in frames)
    print(f"wrote {len(frames)} frame(s) to {args.out}: {len(rig)} cameras at {width}x{height}, {boxes} boxes in all, {seconds / len(frames):.2f} s per frame")
    print(f"first token: {frames[0].token}")
    print(f"next: fisheye-infer eval MODEL --data {args.out} --split {args.split or 'val'} --out report.json")
    return 0

def _write_stream(args: argparse.Namespace, rig: Rig) -> int:
    """``--stream``: frames of the training command's randomised stream, in the Fisheye3DOD layout."""
    from fisheye_infer.synth_splits import SyntheticFrames, write_split

    fixed = [f"--{name}" for name, given in (("objects", args.objects != (6, 14)), ("ground-height", args.ground_height != 2.0),
                                               ("scene", args.scene is not None)) if given]
    if fixed or args.first < 0:
        what = f"{', '.join(fixed)} belong(s) to the plain scenes" if fixed else f"--first must be at least 0, got {args.first}"
        print(f"fisheye-infer synth: error: {what}; a --stream frame is fixed by its stream, --seed and index", file=sys.stderr)
        return 2
    split = args.split or args.stream
    t0 = time.perf_counter()
    frames = SyntheticFrames(rig, args.stream, args.seed)
    tokens = write_split(frames, args.out, range(args.first, args.first + args.frames), split=split)
    seconds = time.perf_counter() - t0
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    print(f"wrote {len(tokens)} frame(s) of the {args.stream} stream (seed {args.seed}) to {args.out}, split {split}: "
          f"{len(rig)} cameras at {width}x{height}, {seconds / len(tokens):.2f} s per frame")
    print(f"first token: {tokens[0]}")
    print(f"next: fisheye-infer eval MODEL --data {args.out} --split {split} --out report.json")
    return 0
