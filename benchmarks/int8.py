"""int8 against fp32 on a trained model: accuracy on held-out frames and speed, in one run.

    .venv/bin/python benchmarks/int8.py                       # the shipped compact FisheyeBEVDet, 200 held-out frames
    .venv/bin/python benchmarks/int8.py --frames 50 --repeat 10
    .venv/bin/python benchmarks/int8.py --keep-float "" --keep-float bbox_head.shared_conv,bbox_head.heatmap_head   # what may stay int8
    .venv/bin/python benchmarks/int8.py --weight-bits 8                          # what the 7-bit weights cost

1. export the checkpoint (fp32, verified) and, from that file, the int8 files of both scopes
   (``network``, the default, and ``trunk``) with the exporter's own calibration (``--calib-frames``
   seeded renders of the rig; add ``--calib-images`` for frames of your own);
2. on ``--frames`` frames of the validation stream (``fisheye-infer synth --stream val``): FDS and
   mAP of each file, and the share of the fp32 top-50 boxes per frame each int8 file finds again
   (0.5 m, same label; the export's own criterion is 95%), over all boxes, per class and per band
   of the fp32 box's score, beside the criterion's floor: the fp32 file against itself with every
   pixel moved by -1, 0 or +1 grey level;
3. latency of ``Detector.run_arrays`` on one frame, the files alternated round by round so drift of
   a shared machine falls on all of them alike; medians and the ratio to fp32 at each thread count.

Prints the CPU's name and its VNNI / AVX-512 flags: the int8 gain depends on them (u8 x s8
dot products in one instruction with VNNI; several without, see ``openvino_isa.py`` for the ratio
with the instruction set capped). Writes ``figures.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from compare import timed  # noqa: E402
from model_card import RANGES, SCORE_BANDS, Kept, add_model_arguments, heldout, run, top50_kept, trained_model  # noqa: E402

from fisheye_infer.bench import machine  # noqa: E402
from fisheye_infer.detector import Detector  # noqa: E402
from fisheye_infer.eval.dataset import Fisheye3DOD  # noqa: E402
from fisheye_infer.preprocess import load_frame, stack_frames  # noqa: E402

#: The per-class table's last row: the fp32 file against itself, every pixel moved by -1, 0 or +1 grey level.
PIXEL_NOISE = "fp32, pixels +-1"


def latency(paths: dict[str, Path], images: np.ndarray, valid: np.ndarray, threads: int, rounds: int, repeat: int) -> dict[str, float]:
    """Median ms per ``run_arrays`` call for each file, the files alternated round by round.

    Each round's first call of a file is not timed: it pays for the previous file's threads, which
    spin for a while after their last call (as ``make bench``'s rounds).
    """
    detectors = {name: Detector(path, threads=threads) for name, path in paths.items()}
    times: dict[str, list[float]] = {name: [] for name in paths}
    for detector in detectors.values():
        detector.run_arrays(images, valid)
    for _ in range(rounds):
        for name, detector in detectors.items():
            times[name] += timed(lambda d=detector: d.run_arrays(images, valid), repeat, warmup=1)  # type: ignore[misc]
    return {name: float(np.median(t)) for name, t in times.items()}


def print_kept(kept: dict[str, Kept], columns: list[str], title: str) -> None:
    """A markdown table of the share of the fp32 top-50 boxes each file kept in each group of ``columns``."""
    print(f"\n## top-50 kept {title}\n")
    print("| file | " + " | ".join(columns) + " |\n" + "|---" * (len(columns) + 1) + "|")
    print("| fp32 boxes | " + " | ".join(str(kept[PIXEL_NOISE].considered[c]) for c in columns) + " |")
    for name, k in kept.items():
        print(f"| {name} | " + " | ".join(f"{k.share(c):.1%}" for c in columns) + " |")


def main() -> None:
    from fisheye_infer.export.exporter import export, export_int8
    from fisheye_infer.export.quantize import WEIGHT_BITS

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    add_model_arguments(parser)
    parser.add_argument("--calib-frames", type=int, default=8, help="the exporter's seeded calibration renders (default 8)")
    parser.add_argument("--calib-images", help="folder with frames of your own for calibration")
    parser.add_argument("--keep-float", action="append", default=[], metavar="MODULES",
                        help="also measure the network scope with these modules float32 instead of the architecture's "
                             "(comma-separated state-dict prefixes, '' for none; repeatable): how int8_float was chosen")
    parser.add_argument("--weight-bits", type=int, choices=(8,),
                        help="also measure the network scope with 8-bit weights instead of 7 (which every x86 CPU adds alike)")
    parser.add_argument("--threads", default="1,2", help="thread counts to time (default 1,2)")
    parser.add_argument("--rounds", type=int, default=5, help="alternated timing rounds (default 5)")
    parser.add_argument("--repeat", type=int, default=10, help="calls per file per round (default 10)")
    parser.add_argument("--out", default="artifacts/int8", help="folder for the frames, the files and the figures")
    args = parser.parse_args()

    ckpt, config, rig = trained_model(args)
    out = Path(args.out)
    host = machine()
    print(f"CPU: {host['cpu']}, {host['cpu_count']} cores; AVX2: {host['avx2']}, AVX-512: {host['avx512']}, VNNI: {host['vnni']}; "
          f"onnxruntime {host['onnxruntime']}")
    data = heldout(rig, out / "heldout", args.frames, args.seed)
    fp32_path = export(ckpt, out / "model.onnx", config=config, rig=rig, progress=lambda _: None).path
    if fp32_path is None:
        raise SystemExit("the fp32 export wrote no file")
    paths: dict[str, Path] = {"fp32": fp32_path}
    variants = [("network", "network", None, WEIGHT_BITS), ("trunk", "trunk", None, WEIGHT_BITS)]
    variants += [(f"network, float: {m or 'none'}", "network", tuple(p for p in m.split(",") if p), WEIGHT_BITS) for m in args.keep_float]
    if args.weight_bits:
        variants.append((f"network, {args.weight_bits}-bit weights", "network", None, args.weight_bits))
    for i, (name, scope, keep_float, bits) in enumerate(variants):
        t0 = time.perf_counter()
        result = export_int8(fp32_path, out / f"model.int8-{i}.onnx", scope=scope, keep_float=keep_float, calib_frames=args.calib_frames,
                             calib_images=args.calib_images, force=True, weight_bits=bits, progress=lambda _: None)
        if result.path is None:
            raise SystemExit(f"int8 {name}: no file written")
        paths[name] = result.path
        print(f"int8 {name}: {result.meta.quantization.scope if result.meta.quantization else ''} ({time.perf_counter() - t0:.0f} s; "
              f"its own check on {result.parity.frames} frames: {result.parity.top_matched_fraction:.1%} +- "
              f"{result.parity.top_matched_standard_error or 0.0:.1%} of top-50 -> {'passed' if result.parity.passed else 'refused without --force'})")

    figures: dict[str, Any] = {"machine": host, "checkpoint": str(ckpt), "frames": args.frames, "files": {}}
    reports = {name: run(Detector(path, threads=1), data, list(rig.names))[0] for name, path in paths.items()}
    fp32 = Detector(paths["fp32"], threads=1)
    print(f"\n## Accuracy on {args.frames} held-out frames\n")
    print("| file | FDS 0-30 m | mAP 0-30 m | FDS 0-48 m | mAP 0-48 m | FDS vs fp32 (0-30 m) | top-50 kept |\n|---|---|---|---|---|---|---|")
    kept = {name: top50_kept(fp32, Detector(path, threads=1), data) for name, path in paths.items() if name != "fp32"}
    for name, report in reports.items():
        near, far = (report.distance[label] for label in RANGES)
        share = kept[name].share() if name in kept else 1.0
        per_class = {c: kept[name].share(c) for c in kept[name].classes} if name in kept else {}
        per_score = {band: kept[name].share(band) for band in SCORE_BANDS} if name in kept else {}
        delta = near.FDS - reports["fp32"].distance[RANGES[0]].FDS
        print(f"| {name} | {near.FDS:.4f} | {near.mAP:.4f} | {far.FDS:.4f} | {far.mAP:.4f} | {delta:+.4f} | {share:.1%} |")
        figures["files"][name] = {"path": str(paths[name]), "MB": paths[name].stat().st_size / 1e6, "top50_kept": share,
                                  "top50_kept_per_class": per_class, "top50_kept_per_score": per_score,
                                  **{f"{m} {label}": getattr(report.distance[label], m) for label in RANGES for m in ("FDS", "mAP")}}

    kept[PIXEL_NOISE] = top50_kept(fp32, fp32, data, pixel_noise=True)
    floor = kept[PIXEL_NOISE]
    figures["top50_kept_fp32_pixel_noise"] = {c: floor.share(c) for c in floor.classes}
    figures["top50_kept_fp32_pixel_noise_per_score"] = {band: floor.share(band) for band in SCORE_BANDS}
    print_kept(kept, floor.classes, f"per class (the fp32 boxes of each class over {args.frames} frames; last row: the criterion's floor)")
    print_kept(kept, list(SCORE_BANDS), "by the fp32 box's score (what a detection threshold keeps; same boxes)")

    frame = next(iter(Fisheye3DOD(data, "val")))
    images, valid = stack_frames([load_frame(dict(frame.image_paths), fp32.info.cameras, fp32.info.image_size)], fp32.info.image_size)
    print(f"\n## Latency, one frame ({host['cpu']}, {host['cpu_count']} cores; median of {args.rounds} x {args.repeat} calls per file, files alternated)\n")
    print("| threads | " + " | ".join(f"{name} ms" for name in paths) + " | " + " | ".join(f"{name} speed-up" for name in paths if name != "fp32") + " |")
    print("|---" * (2 * len(paths)) + "|")
    figures["latency_ms"] = {}
    for threads in (int(t) for t in args.threads.split(",")):
        ms = latency(paths, images, valid, threads, args.rounds, args.repeat)
        figures["latency_ms"][threads] = ms
        print(f"| {threads} | " + " | ".join(f"{ms[n]:.1f}" for n in paths) + " | "
              + " | ".join(f"{ms['fp32'] / ms[n]:.2f}x" for n in paths if n != "fp32") + " |")
    path = out / "figures.json"
    path.write_text(json.dumps(figures, indent=1) + "\n")
    print(f"\nwrote {path}")


if __name__ == "__main__":
    main()
