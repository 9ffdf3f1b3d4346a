"""``fisheye-infer eval``: FDS/mAP of a model on Fisheye3DOD-layout data, or of two results files.

    fisheye-infer eval --results pred.json --ground-truth gt.json --out report.json
    fisheye-infer eval model.onnx --data ROOT --split val [--limit N] [--cameras front,rear] --out report.json
    fisheye-infer eval model.onnx --data seqs/ --tracking [--track-score 0.3] [--smooth 1] [--hota] --out report.json

Writes the report JSON, a Markdown report beside it (same name, ``.md``) and prints the tables.
The model form runs the ONNX runtime ``Detector`` on every frame of the split and evaluates its
unthresholded output, as the official numbers are computed. With ``--tracking`` it runs the detector and
a ``Tracker`` over each sequence of the split (``fisheye-infer synth --sequences``) and reports
nuScenes' tracking metrics (AMOTA, AMOTP, MOTA, MOTP, IDS, FRAG, recall) at 0-30 and 0-48 m, and with
``--hota`` TrackEval's HOTA, DetA, AssA and LocA. ``--smooth`` re-fits the saved tracks' velocities from the
frames either side (``smooth_velocities``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from fisheye_infer.commands.common import csv_list

if TYPE_CHECKING:
    from fisheye_infer.eval.metrics import EvalConfig, MetricsReport

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``fisheye-infer eval``."""
    parser.add_argument(
        "model", nargs="?", help="exported model (.onnx) to run on --data; omit to evaluate saved results"
    )
    files = parser.add_argument_group("saved results")
    files.add_argument("--results", help='predictions: {"results": {sample_token: [record, ...]}}')
    files.add_argument("--ground-truth", help="ground truth in the same format (detection_score optional, ignored)")
    files.add_argument(
        "--allow-missing",
        action="store_true",
        help="count ground-truth samples absent from --results as frames with no detections",
    )
    data = parser.add_argument_group("running a model")
    data.add_argument("--data", help="Fisheye3DOD-layout root (calib_results.txt, ImageSets-2hz/, scenes)")
    data.add_argument("--split", default="val", help="split file in ImageSets-2hz (default: val)")
    data.add_argument("--limit", type=int, help="evaluate the first N samples of the split")
    data.add_argument("--scenes", type=csv_list, help="comma-separated scene names to keep")
    data.add_argument(
        "--cameras", type=csv_list, help="cameras to feed (e.g. front,rear); the others are marked missing"
    )
    data.add_argument("--threads", type=int, help="ONNX Runtime intra-op threads")
    data.add_argument(
        "--save-results",
        help="also write the predictions to this JSON file and the ground truth beside it (pred.json -> pred.gt.json); "
        "with --tracking the predictions are nuScenes tracking results, and pred.detections.json holds them as "
        "detection records with the velocity from the track",
    )
    track = parser.add_argument_group("tracking")
    track.add_argument(
        "--tracking", action="store_true", help="track each sequence of --data and report the tracking metrics"
    )
    track.add_argument(
        "--track-score", type=float, default=0.3, help="score from which detections start tracks (default: 0.3)"
    )
    track.add_argument(
        "--track-low",
        type=float,
        help="score from which detections keep tracks alive (default: a third of --track-score)",
    )
    track.add_argument(
        "--smooth",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="fit each track's velocities after the fact to its detections SECONDS either side, for the saved "
        "results (offline: smooth_velocities); default 0: the tracker's own, as reported online",
    )
    track.add_argument(
        "--hota",
        action="store_true",
        help="also HOTA, DetA, AssA and LocA, by TrackEval's own HOTA (pip install --no-deps trackeval)",
    )
    parser.add_argument("--config", help="metric settings as JSON (default: the official Fisheye3DOD settings)")
    parser.add_argument(
        "--ref-range", type=float, help="scale every class range by REF_RANGE/48 (the paper's 0-30 m is 30)"
    )
    parser.add_argument("--out", required=True, help="report JSON to write; the Markdown report goes beside it")
    parser.set_defaults(run=run)


def _config(args: argparse.Namespace) -> EvalConfig:
    from fisheye_infer.eval.metrics import EvalConfig

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


def run(args: argparse.Namespace) -> int:
    """Evaluate saved results, or run a model over a split and evaluate its output."""
    from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results, load_results, save_results

    config = _config(args)
    if args.smooth and not args.tracking:
        return _fail("--smooth fits tracks' velocities; it goes with --tracking")
    if Path(args.out).suffix.lower() == ".md":
        return _fail(f"--out names the report JSON; the Markdown report is written beside it (got {args.out})")
    if args.model is None:
        if args.tracking:
            return _fail("--tracking runs a MODEL on --data (sequences written by `fisheye-infer synth --sequences`)")
        if not (args.results and args.ground_truth):
            return _fail("give --results and --ground-truth, or a MODEL with --data")
        if args.data:
            return _fail("--data needs a MODEL to run; saved results are evaluated with --results/--ground-truth only")
        report = evaluate_results(
            load_results(args.ground_truth), load_results(args.results), config, allow_missing=args.allow_missing
        )
        _write_report(report, args.out)
        return 0
    if args.results or args.ground_truth:
        return _fail("a MODEL is evaluated on --data; --results/--ground-truth are for saved results")
    if not args.data:
        return _fail("a MODEL needs --data ROOT (a Fisheye3DOD-layout folder)")
    if args.tracking:
        return _run_tracking(args, config)
    from fisheye_infer.eval.dataset import Fisheye3DOD, camera_name
    from fisheye_infer.runtime.detector import Detector

    detector = Detector(args.model, threads=args.threads)
    if tuple(detector.info.classes) != tuple(config.class_names):
        return _fail(
            f"the model's classes {list(detector.info.classes)} differ from the metric's {list(config.class_names)}"
        )
    cameras = [camera_name(c) for c in args.cameras] if args.cameras else list(detector.info.cameras)
    dataset = Fisheye3DOD(
        args.data, args.split, cameras=cameras, scenes=args.scenes, limit=args.limit, class_names=config.class_names
    )
    gt, pred = detect_dataset(detector, dataset)
    if args.save_results:
        path = Path(args.save_results)
        meta = {"model": str(args.model), "data": str(args.data), "split": args.split, "cameras": cameras}
        save_results(path, pred, meta)
        save_results(path.with_suffix(".gt.json"), gt, meta)
    _write_report(evaluate_results(gt, pred, config), args.out)
    return 0


def _run_tracking(args: argparse.Namespace, config: EvalConfig) -> int:
    """``--tracking``: detector + tracker over every sequence of the split, scored with the tracking metrics."""
    from fisheye_infer.eval.dataset import Fisheye3DOD, camera_name
    from fisheye_infer.eval.evaluate import save_results
    from fisheye_infer.eval.hota import hota_metric
    from fisheye_infer.eval.sequences import read_sequences
    from fisheye_infer.eval.track_run import run_on, track_sequences
    from fisheye_infer.eval.tracking import evaluate_tracking
    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.tools.progress import Progress
    from fisheye_infer.tracking import Tracker, TrackerConfig

    if args.limit is not None:
        return _fail("--limit cuts sequences short; choose whole sequences with --scenes")
    if not 0 <= args.smooth < float("inf"):
        return _fail(f"--smooth: expected seconds >= 0, got {args.smooth}")
    if args.hota:
        hota_metric()  # before the detector runs: refuses where TrackEval is not installed
    low = args.track_low if args.track_low is not None else args.track_score / 3
    tracker = Tracker(TrackerConfig(score_threshold=args.track_score, low_score=low))
    detector = Detector(args.model, threads=args.threads)
    if tuple(detector.info.classes) != tuple(config.class_names):
        return _fail(
            f"the model's classes {list(detector.info.classes)} differ from the metric's {list(config.class_names)}"
        )
    cameras = [camera_name(c) for c in args.cameras] if args.cameras else list(detector.info.cameras)
    dataset = Fisheye3DOD(args.data, args.split, cameras=cameras, scenes=args.scenes, class_names=config.class_names)
    sequences = read_sequences(args.data, args.split, config.class_names, scenes=args.scenes)
    bar = Progress(sum(len(s.frames) for s in sequences))
    results = track_sequences(run_on(detector, dataset), sequences, tracker, progress=bar.update, smooth=args.smooth)
    if args.save_results:
        path = Path(args.save_results)
        meta = {"model": str(args.model), "data": str(args.data), "split": args.split, "cameras": cameras}
        tokens = [f.token for s in sequences for f in s.frames]
        save_results(path, dict(zip(tokens, [r for s in results for r in s.pred])), {**meta, "use_tracking": True})
        save_results(path.with_suffix(".gt.json"), dict(zip(tokens, [r for s in results for r in s.gt])), meta)
        renamed = {"tracking_name": "detection_name", "tracking_score": "detection_score"}
        detections = [
            [{renamed.get(k, k): v for k, v in r.items() if k != "tracking_id"} for r in rs]
            for s in results
            for rs in s.pred
        ]
        save_results(path.with_suffix(".detections.json"), dict(zip(tokens, detections)), meta)
    report = evaluate_tracking(results, config, hota=args.hota)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(report.to_json(indent=1) + "\n")
    out.with_suffix(".md").write_text(report.to_markdown())
    print(report.to_markdown())
    print(f"wrote {out} and {out.with_suffix('.md')}")
    return 0
