"""Every figure of a trained model's card, measured on held-out synthetic frames.

    python benchmarks/model_card.py [--model NAME | --ckpt runs/compact/model.pth] [--frames 200]
                                    [--threads 2] [--quick]

Defaults: the shipped compact FisheyeBEVDet (``fisheye_infer.models.pretrained``). Steps:

1. ``--frames`` frames of the validation stream (``fisheye-infer synth --stream val``; the training
   command never draws from it) in the Fisheye3DOD layout, for the model's own rig;
2. the checkpoint's export (verified), its int8 file and its fp16 file (each kept whatever its own
   check says);
3. the official metric, every class at 0-30 m and 0-48 m, of: the ONNX file with all four cameras;
   the PyTorch model on the same frames through the same decoding (``TorchDetector``); the paper's
   sensor-failure study in run-time degraded mode (no retraining): front+rear, left+right and each
   single camera missing; the int8 file and the fp16 file (in the CPU provider, which runs a float16
   graph as written), each with the share of the fp32 file's top-50 boxes it finds again (0.5 m,
   same label); and the recall and precision of the boxes above a score threshold
   (2 m, same class), the figures a model's display threshold is chosen from.

This module also holds what ``int8.py`` shares with it: the held-out frames and the kept boxes.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import harness
import numpy as np
import paper

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results
from fisheye_infer.eval.metrics import EvalConfig, MetricsReport
from fisheye_infer.eval.top_match import SCORE_BANDS, match_top, per_score_band
from fisheye_infer.runtime.detector import Detector, FrameDetector
from fisheye_infer.scenes.streams import SyntheticFrames, write_split

FRONT, LEFT, REAR, RIGHT = "fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_rear", "fisheye_camera_right"
RANGES = ("0-30 m", "0-48 m")
#: Score thresholds of the recall / precision table.
THRESHOLDS = (0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5)
#: Centre distance within which a box finds a labelled object (the metric's 2 m threshold).
MATCH_RADIUS_M = 2.0
Row = dict[str, Any]


def layouts(cameras: tuple[str, ...]) -> dict[str, list[str]]:
    """The rows of the sensor-failure study: which cameras feed the model."""
    rows = {"all four cameras": list(cameras), "front + rear": [FRONT, REAR], "left + right": [LEFT, RIGHT]}
    for missing in cameras:
        rows[f"{missing.removeprefix('fisheye_camera_')} missing"] = [c for c in cameras if c != missing]
    return rows


def heldout(rig: Rig, root: Path, frames: int, seed: int) -> Path:
    """The validation stream's first ``frames`` frames under ``root`` (written once, reused after)."""
    split = root / "ImageSets-2hz" / "val.json"
    if split.is_file() and len(json.loads(split.read_text())) == frames:
        return root
    t0 = time.perf_counter()
    write_split(SyntheticFrames(rig, "val", seed), root, range(frames))
    print(f"wrote {frames} held-out frames to {root} in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return root


def run(
    detector: FrameDetector, data: Path, cameras: list[str]
) -> tuple[MetricsReport, tuple[dict[str, Any], dict[str, Any]]]:
    """The metric's report of ``detector`` on the held-out frames seen by ``cameras``, and the records it scored."""
    gt, pred = detect_dataset(detector, Fisheye3DOD(data, "val", cameras=cameras), progress=False)
    return evaluate_results(gt, pred), (gt, pred)


@dataclass(frozen=True)
class Kept:
    """How many of the fp32 file's top-50 boxes another file found again: over all boxes ("all"),
    per class (by name) and per band of the fp32 box's score (``SCORE_BANDS``)."""

    matched: dict[str, int]
    considered: dict[str, int]

    def share(self, name: str = "all") -> float:
        return self.matched[name] / max(self.considered[name], 1)

    @property
    def classes(self) -> list[str]:
        """ "all" and the classes with boxes, in the file's class order."""
        return [name for name in self.considered if name not in SCORE_BANDS]


def top50_kept(fp32: Detector, candidate: Detector, data: Path, pixel_noise: bool = False) -> Kept:
    """The fp32 file's top-50 boxes per frame that ``candidate`` finds again (0.5 m, same label).

    ``pixel_noise``: ``candidate`` sees every pixel moved by -1, 0 or +1 grey level (seeded per
    frame). With the fp32 file as ``candidate`` that is the criterion's floor: how many boxes the
    model itself moves for the smallest change of its input.
    """
    from fisheye_infer.runtime.preprocess import load_frame, stack_frames

    size = fp32.info.image_size
    pairs = []
    for k, frame in enumerate(Fisheye3DOD(data, "val")):
        images, valid = stack_frames([load_frame(dict(frame.image_paths), fp32.info.cameras, size)], size)
        seen = images
        if pixel_noise:
            step = np.random.default_rng(k).integers(-1, 2, images.shape)
            seen = np.clip(images.astype(np.int16) + step, 0, 255).astype(np.uint8)
        pairs += match_top(fp32.run_arrays(images, valid), candidate.run_arrays(seen, valid))
    per_class = {name: [p for p in pairs if p.label == label] for label, name in enumerate(fp32.info.classes)}
    groups = {"all": pairs} | {name: group for name, group in per_class.items() if group} | per_score_band(pairs)
    return Kept(
        {name: sum(p.matched for p in group) for name, group in groups.items()},
        {name: len(group) for name, group in groups.items()},
    )


def threshold_rows(gt: dict[str, list[dict[str, Any]]], pred: dict[str, list[dict[str, Any]]]) -> list[Row]:
    """Recall, precision and F1 of the boxes scoring at least each of ``THRESHOLDS``: greedy by score, same class,
    bird's-eye centres within ``MATCH_RADIUS_M``, every labelled object of the frames."""
    rows = []
    for threshold in THRESHOLDS:
        found = shown = 0
        for token, records in gt.items():
            boxes = sorted(
                (p for p in pred[token] if p["detection_score"] >= threshold), key=lambda p: -p["detection_score"]
            )
            used = [False] * len(records)
            for box in boxes:
                near = [
                    (math.dist(box["translation"][:2], rec["translation"][:2]), i)
                    for i, rec in enumerate(records)
                    if not used[i] and rec["detection_name"] == box["detection_name"]
                ]
                best = min(near, default=(math.inf, -1))
                if best[0] <= MATCH_RADIUS_M:
                    used[best[1]] = True
                    found += 1
            shown += len(boxes)
        labelled = sum(len(records) for records in gt.values())
        recall, precision = found / max(labelled, 1), found / max(shown, 1)
        f1 = 2 * recall * precision / (recall + precision) if recall + precision else 0.0
        rows.append({"score from": threshold, "recall": recall, "precision": precision, "F1": f1})
    return rows


def reduced_rows(
    name: str, fp32: Detector, candidate: Detector, full: MetricsReport, data: Path
) -> tuple[list[Row], list[Row]]:
    """A reduced-precision file against the fp32 file: FDS at both ranges with the share of the fp32
    top-50 boxes it finds again, and that share per class and per band of the fp32 box's score."""
    report, _ = run(candidate, data, list(fp32.info.cameras))
    kept = top50_kept(fp32, candidate, data)
    ranges = [
        {
            "range": label,
            "FDS fp32": full.distance[label].FDS,
            f"FDS {name}": report.distance[label].FDS,
            "difference": report.distance[label].FDS - full.distance[label].FDS,
            "top-50 kept": kept.share(),
        }
        for label in RANGES
    ]
    groups = [*(group for group in kept.classes if group != "all"), *SCORE_BANDS]
    by_group = [
        {"boxes of": group, "fp32 boxes": kept.considered[group], "top-50 kept": kept.share(group)} for group in groups
    ]
    return ranges, by_group


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """The trained model a benchmark measures and the held-out frames it is measured on."""
    from fisheye_infer.models.pretrained import PRETRAINED

    parser.add_argument(
        "--model",
        choices=[m.name for m in PRETRAINED],
        help="a shipped model (default: fisheye-bevdet-compact, unless --ckpt names another checkpoint)",
    )
    parser.add_argument("--ckpt", help="checkpoint of a trained model (with config.py and rig.json beside it)")
    parser.add_argument("--config", help="its config file (default: config.py beside --ckpt)")
    parser.add_argument("--rig", help="its rig file (default: rig.json beside --ckpt)")
    parser.add_argument("--frames", type=int, default=200, help="held-out frames (default 200)")
    parser.add_argument(
        "--seed", type=int, default=0, help="seed of the validation stream (the training run's --seed; default 0)"
    )


def trained_model(args: argparse.Namespace) -> tuple[Path, Path, Rig]:
    """(checkpoint, config file, rig) from ``add_model_arguments``' options."""
    from fisheye_infer.models.pretrained import COMPACT_BEVDET, pretrained

    if args.model and args.ckpt:
        raise SystemExit("--model and --ckpt name two models: give one")
    shipped = pretrained(args.model) if args.model else COMPACT_BEVDET
    ckpt = Path(args.ckpt or shipped.checkpoint)
    rig = Rig.load(Path(args.rig or ckpt.with_name("rig.json")))
    return ckpt, Path(args.config or ckpt.with_name("config.py")), rig


def summary_row(report: MetricsReport) -> Row:
    return {f"{m} {label}": getattr(report.distance[label], m) for label in RANGES for m in ("FDS", "mAP")}


def class_rows(report: MetricsReport) -> list[Row]:
    """Per class: AP at both ranges, AP at 2 m and the true-positive errors at 0-30 m."""
    near, far = report.distance[RANGES[0]], report.distance[RANGES[1]]
    return [
        {
            "class": name,
            "AP 0-30 m": c.ap,
            "AP 0-48 m": far.classes[name].ap,
            "AP@2m 0-30 m": c.ap_by_threshold["2.0"],
            "ATE 0-30 m": c.trans_err,
            "ASE 0-30 m": c.scale_err,
            "AOE 0-30 m": c.orient_err,
        }
        for name, c in near.classes.items()
    ]


def mean_rows(report: MetricsReport) -> list[Row]:
    """Over all classes, per range: mAP, FDS and the mean true-positive errors."""
    return [
        {"range": label, "mAP": s.mAP, "FDS": s.FDS, "mATE": s.mATE, "mASE": s.mASE, "mAOE": s.mAOE}
        for label, s in ((label, report.distance[label]) for label in RANGES)
    ]


def main(argv: list[str] | None = None) -> int:
    from fisheye_infer.export.exporter import export, export_fp16, export_int8, open_checkpoint
    from fisheye_infer.export.torch_detector import TorchDetector

    bench = harness.Benchmark(__file__, __doc__, quick="20 held-out frames")
    add_model_arguments(bench.parser)
    bench.parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads (default 2)")
    bench.parser.add_argument("--work-dir", default="artifacts/model_card", help="folder for the frames and the files")
    args = bench.parse(argv)
    if args.quick:
        args.frames = 20

    ckpt, config, rig = trained_model(args)
    work = Path(args.work_dir)
    data = heldout(rig, work / "heldout", args.frames, args.seed)
    onnx_path = work / "model.onnx"
    export(ckpt, onnx_path, config=config, rig=rig, progress=lambda _: None)
    quant = export_int8(onnx_path, force=True, progress=lambda _: None)  # kept whatever its own check says
    half = export_fp16(onnx_path, force=True, progress=lambda _: None)
    fp32 = Detector(onnx_path, threads=args.threads)
    cameras = list(fp32.info.cameras)
    full, (gt, pred) = run(fp32, data, cameras)
    # The renderer draws no front on its boxes: a heading is defined up to half a turn only.
    half_turn_period = dict.fromkeys(EvalConfig().class_names, math.pi)
    half_turn = evaluate_results(gt, pred, EvalConfig(orientation_period=half_turn_period))
    yaw = [
        {"range": label, "mAOE": half_turn.distance[label].mAOE, "FDS": half_turn.distance[label].FDS}
        for label in RANGES
    ]

    opened = open_checkpoint(ckpt, config=config, rig=rig)
    arch = opened.entry.name
    torch_report, _ = run(TorchDetector(opened.model, onnx_path), data, cameras)
    versus = [
        {
            "range": label,
            "FDS ONNX": full.distance[label].FDS,
            "FDS PyTorch": torch_report.distance[label].FDS,
            "difference": abs(torch_report.distance[label].FDS - full.distance[label].FDS),
        }
        for label in RANGES
    ]

    failure = []
    for name, used in layouts(fp32.info.cameras).items():
        report = full if len(used) == len(cameras) else run(fp32, data, used)[0]
        figures = paper.TABLE3.get(arch, {}).get("all" if name == "all four cameras" else name)
        method = paper.METHOD.get(arch, (arch,))[0]
        failure.append(
            {"cameras": name, **summary_row(report), f"paper FDS ({method})": figures[0] if figures else None}
        )

    int8, int8_kept = reduced_rows("int8", fp32, Detector(quant.path or onnx_path, threads=args.threads), full, data)
    fp16, _ = reduced_rows("fp16", fp32, Detector(half.path or onnx_path, threads=args.threads), full, data)
    scope = quant.meta.quantization.scope if quant.meta.quantization else ""
    bench.save(
        args,
        {
            f"Held-out frames ({args.frames}), ONNX Runtime, all four cameras: per class": class_rows(full),
            f"Held-out frames ({args.frames}), ONNX Runtime, all four cameras: all classes": mean_rows(full),
            "Yaw compared modulo pi (the synthetic boxes have no front)": yaw,
            "ONNX vs PyTorch on the same frames": versus,
            "Sensor failure at run time (degraded mode, no retraining)": failure,
            f"int8 ({scope}) against the fp32 file": int8,
            "int8: top-50 kept per class and by the fp32 box's score": int8_kept,
            "fp16 against the fp32 file (both in ONNX Runtime's CPU provider)": fp16,
            "Boxes from a score threshold: recall and precision (2 m, same class)": threshold_rows(gt, pred),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
