"""Every figure of a trained model's card, measured on held-out synthetic frames.

    .venv/bin/python benchmarks/model_card.py [--ckpt runs/compact/model.pth] [--frames 200] [--out artifacts/model_card]

Defaults: the shipped compact FisheyeBEVDet (``fisheye_infer.models.pretrained``). Steps:

1. write ``--frames`` frames of the validation stream (``fisheye-infer synth --stream val``; the
   training command never draws from it) in the Fisheye3DOD layout, for the model's own rig;
2. export the checkpoint (verified) and its int8 file (``fisheye-infer export --int8``, kept
   whatever its own check says, since it is measured here);
3. evaluate with the official metric, every class at 0-30 m and 0-48 m:
   - the ONNX file with all four cameras;
   - the PyTorch model on the same frames, through the same decoding (``TorchDetector``);
   - the paper's sensor-failure study in run-time degraded mode (no retraining): front+rear,
     left+right, and each single camera missing;
   - the int8 file: its FDS, and the share of the fp32 file's top-50 boxes it finds again
     (0.5 m, same label).

Prints Markdown tables (the model card's) and writes them with every number to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.detector import Detector, FrameDetector
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results
from fisheye_infer.eval.metrics import EvalConfig, MetricsReport
from fisheye_infer.export.quantize import SCORE_BANDS, match_top, per_score_band
from fisheye_infer.rig import Rig
from fisheye_infer.synth_splits import SyntheticFrames, write_split

FRONT, LEFT, REAR, RIGHT = "fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_rear", "fisheye_camera_right"
#: The paper's layout study (Table 4 of the paper: FisheyeBEVDet FDS on its own data), beside ours.
PAPER_FDS = {"all four cameras": 0.485, "front + rear": 0.454, "left + right": 0.431}
RANGES = ("0-30 m", "0-48 m")


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
    print(f"wrote {frames} held-out frames to {root} in {time.perf_counter() - t0:.0f} s")
    return root


def run(detector: FrameDetector, data: Path, cameras: list[str]) -> tuple[MetricsReport, tuple[dict[str, Any], dict[str, Any]]]:
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
        """"all" and the classes with boxes, in the file's class order."""
        return [name for name in self.considered if name not in SCORE_BANDS]


def top50_kept(fp32: Detector, candidate: Detector, data: Path, pixel_noise: bool = False) -> Kept:
    """The fp32 file's top-50 boxes per frame that ``candidate`` finds again (0.5 m, same label).

    ``pixel_noise``: ``candidate`` sees every pixel moved by -1, 0 or +1 grey level (seeded per
    frame). With the fp32 file as ``candidate`` that is the criterion's floor: how many boxes the
    model itself moves for the smallest change of its input.
    """
    from fisheye_infer.preprocess import load_frame, stack_frames

    pairs = []
    for k, frame in enumerate(Fisheye3DOD(data, "val")):
        images, valid = stack_frames([load_frame(dict(frame.image_paths), fp32.info.cameras, fp32.info.image_size)], fp32.info.image_size)
        seen = images
        if pixel_noise:
            step = np.random.default_rng(k).integers(-1, 2, images.shape)
            seen = np.clip(images.astype(np.int16) + step, 0, 255).astype(np.uint8)
        pairs += match_top(fp32.run_arrays(images, valid), candidate.run_arrays(seen, valid))
    per_class = {name: [p for p in pairs if p.label == label] for label, name in enumerate(fp32.info.classes)}
    groups = {"all": pairs} | {name: group for name, group in per_class.items() if group} | per_score_band(pairs)
    return Kept({name: sum(p.matched for p in group) for name, group in groups.items()}, {name: len(group) for name, group in groups.items()})


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """The trained model a benchmark measures and the held-out frames it is measured on."""
    from fisheye_infer.models.pretrained import COMPACT_BEVDET

    parser.add_argument("--ckpt", default=str(COMPACT_BEVDET.checkpoint), help="checkpoint (default: the shipped compact FisheyeBEVDet)")
    parser.add_argument("--config", help="its config file (default: config.py beside --ckpt)")
    parser.add_argument("--rig", help="its rig file (default: rig.json beside --ckpt)")
    parser.add_argument("--frames", type=int, default=200, help="held-out frames (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the validation stream (the training run's --seed; default 0)")


def trained_model(args: argparse.Namespace) -> tuple[Path, Path, Rig]:
    """(checkpoint, config file, rig) from ``add_model_arguments``' options."""
    ckpt = Path(args.ckpt)
    return ckpt, Path(args.config or ckpt.with_name("config.py")), Rig.load(Path(args.rig or ckpt.with_name("rig.json")))


def summary_row(report: MetricsReport) -> dict[str, float]:
    row = {}
    for label in RANGES:
        s = report.distance[label]
        row.update({f"FDS {label}": s.FDS, f"mAP {label}": s.mAP})
    return row


def class_table(report: MetricsReport) -> str:
    lines = ["| class | AP 0-30 m | AP 0-48 m | AP@2m 0-30 m | ATE 0-30 m | ASE 0-30 m | AOE 0-30 m |", "|---|---|---|---|---|---|---|"]
    near, far = report.distance[RANGES[0]], report.distance[RANGES[1]]
    for name, c in near.classes.items():
        lines.append(f"| {name} | {c.ap:.3f} | {far.classes[name].ap:.3f} | {c.ap_by_threshold['2.0']:.3f} | "
                     f"{c.trans_err:.3f} | {c.scale_err:.3f} | {c.orient_err:.3f} |")
    for label in RANGES:
        s = report.distance[label]
        lines.append(f"| **all, {label}** | mAP {s.mAP:.3f} | FDS {s.FDS:.3f} | | mATE {s.mATE:.3f} | mASE {s.mASE:.3f} | mAOE {s.mAOE:.3f} |")
    return "\n".join(lines)


def main() -> None:
    from fisheye_infer.export.exporter import export, export_int8, open_checkpoint
    from fisheye_infer.export.torch_detector import TorchDetector

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_model_arguments(parser)
    parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads (default 2)")
    parser.add_argument("--out", default="artifacts/model_card", help="folder for the frames, the files and the figures")
    args = parser.parse_args()

    ckpt, config, rig = trained_model(args)
    out = Path(args.out)
    data = heldout(rig, out / "heldout", args.frames, args.seed)
    onnx_path = out / "model.onnx"
    result = export(ckpt, onnx_path, config=config, rig=rig, progress=lambda _: None)
    print(result.summary())
    quant = export_int8(onnx_path, force=True, progress=lambda _: None)  # kept whatever its own check says: measured below
    print(quant.summary())

    fp32 = Detector(onnx_path, threads=args.threads)
    figures: dict[str, Any] = {"checkpoint": str(ckpt), "frames": args.frames, "seed": args.seed}
    t0 = time.perf_counter()
    full, (gt, pred) = run(fp32, data, list(fp32.info.cameras))
    print(f"\n## Held-out frames ({args.frames}), ONNX Runtime, all four cameras ({time.perf_counter() - t0:.0f} s)\n")
    print(class_table(full))
    figures["onnx"] = json.loads(full.to_json())
    # The renderer draws no front on its boxes: a heading is defined up to half a turn only.
    half_turn = EvalConfig(orientation_period={name: math.pi for name in EvalConfig().class_names})
    symmetric = evaluate_results(gt, pred, half_turn)
    print("\nyaw compared modulo pi (the synthetic boxes have no front): "
          + ", ".join(f"{label}: mAOE {symmetric.distance[label].mAOE:.3f}, FDS {symmetric.distance[label].FDS:.3f}" for label in RANGES))
    figures["onnx_yaw_mod_pi"] = {label: {"mAOE": symmetric.distance[label].mAOE, "FDS": symmetric.distance[label].FDS} for label in RANGES}

    loaded = open_checkpoint(ckpt, config=config, rig=rig)
    torch_report, _ = run(TorchDetector(loaded.model, onnx_path), data, list(fp32.info.cameras))
    diffs = {label: abs(torch_report.distance[label].FDS - full.distance[label].FDS) for label in RANGES}
    print("\n## ONNX vs PyTorch on the same frames\n")
    print("| range | FDS ONNX | FDS PyTorch | difference |\n|---|---|---|---|")
    for label in RANGES:
        print(f"| {label} | {full.distance[label].FDS:.4f} | {torch_report.distance[label].FDS:.4f} | {diffs[label]:.1e} |")
    figures["pytorch"] = {"report": json.loads(torch_report.to_json()), "fds_abs_diff": diffs}

    print("\n## Sensor failure at run time (degraded mode, no retraining)\n")
    print("| cameras | FDS 0-30 m | mAP 0-30 m | FDS 0-48 m | mAP 0-48 m | paper FDS (FisheyeBEVDet) |\n|---|---|---|---|---|---|")
    figures["layouts"] = {}
    for name, cameras in layouts(fp32.info.cameras).items():
        report = full if len(cameras) == len(fp32.info.cameras) else run(fp32, data, cameras)[0]
        row = summary_row(report)
        figures["layouts"][name] = {"cameras": cameras, **row}
        paper = PAPER_FDS.get(name)
        print(f"| {name} | {row['FDS 0-30 m']:.3f} | {row['mAP 0-30 m']:.3f} | {row['FDS 0-48 m']:.3f} | {row['mAP 0-48 m']:.3f} | "
              f"{'' if paper is None else f'{paper:.3f}'} |")

    int8 = Detector(quant.path or onnx_path, threads=args.threads)
    int8_report, _ = run(int8, data, list(fp32.info.cameras))
    kept = top50_kept(fp32, int8, data)
    print(f"\n## int8 ({quant.meta.quantization.scope if quant.meta.quantization else ''}) against the fp32 file\n")
    print("| range | FDS fp32 | FDS int8 | difference | top-50 kept (0.5 m, same label) |\n|---|---|---|---|---|")
    for label in RANGES:
        a, b = full.distance[label].FDS, int8_report.distance[label].FDS
        print(f"| {label} | {a:.3f} | {b:.3f} | {b - a:+.3f} | {kept.share():.1%} |")
    print("\ntop-50 kept per class: " + ", ".join(f"{name} {kept.share(name):.1%} of {kept.considered[name]}" for name in kept.classes if name != "all"))
    print("top-50 kept by the fp32 box's score: " + ", ".join(f"{band} {kept.share(band):.1%} of {kept.considered[band]}" for band in SCORE_BANDS))
    figures["int8"] = {"top50_kept": kept.share(), "top50_kept_per_class": {name: kept.share(name) for name in kept.classes},
                       "top50_kept_per_score": {band: kept.share(band) for band in SCORE_BANDS},
                       **{f"FDS {label}": int8_report.distance[label].FDS for label in RANGES}}
    path = out / "figures.json"
    path.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
