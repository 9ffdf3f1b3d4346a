"""The eight official configs, each exported from the checkpoint kit: the self-check's figures and the time.

    .venv/bin/python benchmarks/official_configs.py                          # all eight, ~20 min on 2 cores
    .venv/bin/python benchmarks/official_configs.py --only nusc_bevdet nusc_petr

For each config stem: the kit's ``make_checkpoint.py`` writes an official-format checkpoint with
BatchNorm calibrated by the official model, ``fisheye-infer export`` (the Python API) writes the
ONNX file from it with the released config file, the six-camera pinhole rig for ``nusc_*`` and the
shipped fisheye rig otherwise, and checks it against PyTorch float64 at 1 and 2 threads; then one
frame runs through the file (``Detector.run_arrays``, 2 threads, median of ``--repeat`` calls after
a warm-up). Prints one row per config and writes ``official_configs.json`` to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from fisheye_infer.bench import machine
from fisheye_infer.detector import Detector
from fisheye_infer.export.exporter import export, verification_frames
from fisheye_infer.rig import resolve_rig

ROOT = Path(__file__).resolve().parents[1]
#: config stem -> the rig it was calibrated on (None: the shipped Fisheye3DOD rig)
STEMS = {
    "fisheye_bevdet": None, "fisheye_petr": None, "fisheye_to_cyl_bevdet": None, "fisheye_to_cyl_petr": None,
    "fisheye_to_pinhole_bevdet": None, "fisheye_to_pinhole_petr": None, "nusc_bevdet": "rig-pinhole6/cameras.json",
    "nusc_petr": "rig-pinhole6/cameras.json",
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--kit", type=Path, default=ROOT.parent / "shared" / "checkpoints", help="the checkpoint kit (make_checkpoint.py, configs/)")
    parser.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data", help="folder holding rig-pinhole6/")
    parser.add_argument("--only", nargs="+", choices=sorted(STEMS), help="these config stems only")
    parser.add_argument("--repeat", type=int, default=3, help="timed inference calls per file")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "artifacts" / "official_configs")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    host = machine()
    print(f"CPU: {host['cpu']}, {host['cpu_count']} cores")
    header = ("config", "architecture", "input", "export s", "self-check", "dense diff", "box diff m", "score diff",
              "float32 box m", "tie subst.", "inference ms")
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    rows = []
    for stem in args.only or STEMS:
        ckpt = args.out / f"{stem}.pth"
        subprocess.run([sys.executable, str(args.kit / "make_checkpoint.py"), stem, str(ckpt)], check=True, capture_output=True)
        rig = resolve_rig(args.data / STEMS[stem]) if STEMS[stem] else resolve_rig(None)
        start = time.perf_counter()
        result = export(ckpt, args.out / f"{stem}.onnx", config=args.kit / "configs" / f"{stem}.py", rig=rig, progress=lambda _: None)
        seconds = time.perf_counter() - start
        detector = Detector(result.path, threads=2)
        frame = verification_frames(rig, 1, seed=7)
        valid = np.ones(frame.shape[:2], bool)
        detector.run_arrays(frame, valid)
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            detector.run_arrays(frame, valid)
            times.append((time.perf_counter() - t0) * 1e3)
        p = result.parity
        row = {"config": stem, "architecture": result.meta.architecture,
               "input": f"{len(result.meta.cameras)} x {result.meta.image_size[0]}x{result.meta.image_size[1]}",
               "export_s": round(seconds, 1), "passed": p.passed, "threads": list(p.threads),
               "dense_diff": p.max_rank_score_abs_diff, "box_diff_m": p.max_box_abs_diff_m, "score_diff": p.max_score_abs_diff,
               "float32_box_m": p.pytorch_float32[1] if p.pytorch_float32 else None, "tie_substitutions": p.tie_substitutions,
               "inference_ms": round(float(np.median(times)), 1)}
        rows.append(row)
        print(f"| {stem} | {row['architecture']} | {row['input']} | {row['export_s']} | {'passed' if p.passed else 'FAILED'} | "
              f"{row['dense_diff']:.1e} | {row['box_diff_m']:.1e} | {row['score_diff']:.1e} | {row['float32_box_m']:.1e} | "
              f"{row['tie_substitutions']} | {row['inference_ms']} |", flush=True)
        ckpt.unlink()
    (args.out / "official_configs.json").write_text(json.dumps({"host": host, "configs": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
