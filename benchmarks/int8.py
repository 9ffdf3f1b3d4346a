"""int8 against fp32 on a trained model: accuracy on held-out frames and speed, in one run.

    python benchmarks/int8.py                       # the shipped compact FisheyeBEVDet, 200 held-out frames
    python benchmarks/int8.py --quick
    python benchmarks/int8.py --keep-float "" --keep-float bbox_head.shared_conv,bbox_head.heatmap_head
    python benchmarks/int8.py --weight-bits 8       # the network scope with 8-bit weights beside the 7-bit ones

1. the checkpoint's fp32 export (verified) and, from that file, the int8 file ``--int8`` writes (``auto``:
   the int8 search's choice) and those of both scopes chosen by hand (``network`` with the architecture's
   float32 modules, and ``trunk``), with the exporter's own calibration (``--calib-frames`` seeded renders
   of the rig; ``--calib-images`` adds frames of your own);
2. on ``--frames`` frames of the validation stream (``fisheye-infer synth --stream val``): FDS and
   mAP of each file, and the share of the fp32 top-50 boxes per frame each int8 file finds again
   (0.5 m, same label), over all boxes, per class and per band of the fp32 box's score, beside the
   criterion's floor: the fp32 file against itself with every pixel moved by -1, 0 or +1 grey level;
3. latency of ``Detector.run_arrays`` on one frame, the files timed in turns; medians and the
   speed-up over fp32 at each thread count. The gain depends on the CPU's VNNI and AVX-512 flags,
   which the result's machine lists (``openvino_isa.py`` caps the instruction set).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Any

import harness
from model_card import RANGES, SCORE_BANDS, Kept, add_model_arguments, heldout, run, top50_kept, trained_model

from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.preprocess import load_frame, stack_frames

#: The kept-boxes tables' last row: the fp32 file against itself, every pixel moved by -1, 0 or +1 grey level.
PIXEL_NOISE = "fp32, pixels +-1"
Row = dict[str, Any]


def kept_rows(kept: dict[str, Kept], groups: list[str]) -> list[Row]:
    """The share of the fp32 top-50 boxes each file kept in each group, under a row with the boxes considered."""
    rows: list[Row] = [{"file": "fp32 boxes", **{g: kept[PIXEL_NOISE].considered[g] for g in groups}}]
    return rows + [{"file": name, **{g: k.share(g) for g in groups}} for name, k in kept.items()]


def export_files(args: Any, work: Path) -> tuple[dict[str, Path], list[Row]]:
    """The fp32 file and the int8 variants asked for, with a row per int8 file on how it was made."""
    from fisheye_infer.export.exporter import export, export_int8
    from fisheye_infer.export.options import Int8Options
    from fisheye_infer.precision import WEIGHT_BITS

    ckpt, config, rig = trained_model(args)
    fp32_path = export(ckpt, work / "model.onnx", config=config, rig=rig, progress=lambda _: None).path
    if fp32_path is None:
        raise SystemExit("the fp32 export wrote no file")
    paths: dict[str, Path] = {"fp32": fp32_path}
    variants: list[tuple[str, str, tuple[str, ...] | None, int]] = [
        ("auto", "auto", None, WEIGHT_BITS),
        ("network", "network", None, WEIGHT_BITS),
        ("trunk", "trunk", None, WEIGHT_BITS),
    ]
    variants += [
        (f"network, float: {m or 'none'}", "network", tuple(p for p in m.split(",") if p), WEIGHT_BITS)
        for m in args.keep_float
    ]
    if args.weight_bits:
        variants.append((f"network, {args.weight_bits}-bit weights", "network", None, args.weight_bits))
    rows = []
    for i, (name, scope, keep_float, bits) in enumerate(variants):
        options = Int8Options(
            calib_images=args.calib_images,
            calib_frames=args.calib_frames,
            scope=scope,
            keep_float=keep_float,
            weight_bits=bits,
        )
        t0 = time.perf_counter()
        result = export_int8(
            fp32_path, work / f"model.int8-{i}.onnx", options=options, force=True, progress=lambda _: None
        )
        if result.path is None:
            raise SystemExit(f"int8 {name}: no file written")
        paths[name] = result.path
        p, q = result.parity, result.meta.quantization
        search = q.search if q is not None else None
        rows.append(
            {
                "file": name,
                "scope": q.scope if q is not None else None,
                "search: trials": len(search.trials) if search is not None else None,
                "export s": time.perf_counter() - t0,
                "own check: frames": p.frames,
                "own check: top-50 kept": p.top_matched_fraction,
                "standard error": p.top_matched_standard_error,
                "passed": p.passed,
            }
        )
    return paths, rows


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="20 held-out frames, 2 threads, 3 rounds of 3 calls")
    p = bench.parser
    add_model_arguments(p)
    p.add_argument("--calib-frames", type=int, default=8, help="the exporter's seeded calibration renders (default 8)")
    p.add_argument("--calib-images", help="folder with frames of your own for calibration")
    p.add_argument(
        "--keep-float",
        action="append",
        default=[],
        metavar="MODULES",
        help="also measure the network scope with these modules float32 instead of the architecture's "
        "(comma-separated state-dict prefixes, '' for none; repeatable)",
    )
    p.add_argument(
        "--weight-bits", type=int, choices=(8,), help="also measure the network scope with 8-bit weights instead of 7"
    )
    p.add_argument("--threads", default="1,2", help="thread counts to time (default 1,2)")
    p.add_argument("--rounds", type=int, default=5, help="rounds of the files in turns (default 5)")
    p.add_argument("--repeat", type=int, default=10, help="timed calls per file per round (default 10)")
    p.add_argument(
        "--work-dir", default="artifacts/int8", help="folder for the frames and the files (default artifacts/int8)"
    )
    args = bench.parse(argv)
    if args.quick:
        args.frames, args.threads, args.rounds, args.repeat = 20, "2", 3, 3

    _, _, rig = trained_model(args)
    work = Path(args.work_dir)
    data = heldout(rig, work / "heldout", args.frames, args.seed)
    paths, made = export_files(args, work)
    reports = {name: run(Detector(path, threads=1), data, list(rig.names))[0] for name, path in paths.items()}
    fp32 = Detector(paths["fp32"], threads=1)
    kept = {name: top50_kept(fp32, Detector(path, threads=1), data) for name, path in paths.items() if name != "fp32"}
    accuracy = []
    for name, report in reports.items():
        near, far = (report.distance[label] for label in RANGES)
        accuracy.append(
            {
                "file": name,
                "MB": paths[name].stat().st_size / 1e6,
                "FDS 0-30 m": near.FDS,
                "mAP 0-30 m": near.mAP,
                "FDS 0-48 m": far.FDS,
                "mAP 0-48 m": far.mAP,
                "FDS vs fp32 (0-30 m)": near.FDS - reports["fp32"].distance[RANGES[0]].FDS,
                "top-50 kept": kept[name].share() if name in kept else 1.0,
            }
        )
    kept[PIXEL_NOISE] = top50_kept(fp32, fp32, data, pixel_noise=True)

    frame = next(iter(Fisheye3DOD(data, "val")))
    size = fp32.info.image_size
    images, valid = stack_frames([load_frame(dict(frame.image_paths), fp32.info.cameras, size)], size)
    latency = []
    for threads in (int(t) for t in str(args.threads).split(",")):
        detectors = {name: Detector(path, threads=threads) for name, path in paths.items()}
        calls = {name: (lambda d=d: d.run_arrays(images, valid)) for name, d in detectors.items()}
        timings = harness.alternate(calls, args.rounds, args.repeat)
        fp32_ms = timings["fp32"].median
        latency += [
            {"threads": threads, "file": name, **t.row(), "speed-up over fp32": fp32_ms / t.median}
            for name, t in timings.items()
        ]
    bench.save(
        args,
        {
            f"Accuracy on {args.frames} held-out frames": accuracy,
            "int8 files: how they were made": made,
            "top-50 kept per class (last row: the criterion's floor)": kept_rows(kept, kept[PIXEL_NOISE].classes),
            "top-50 kept by the fp32 box's score": kept_rows(kept, list(SCORE_BANDS)),
            "Latency, one frame, files in turns": latency,
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
