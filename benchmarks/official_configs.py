"""The eight official configs, each exported from the checkpoint kit: the export's self-check figures and the time.

    python benchmarks/official_configs.py [--only nusc_bevdet nusc_petr]

For each config stem: the kit's ``make_checkpoint.py`` writes an official-format checkpoint with
BatchNorm calibrated by the official model, ``fisheye-infer export`` (the Python API) writes the
ONNX file from it with the released config file, the six-camera pinhole rig for ``nusc_*`` and the
shipped fisheye rig otherwise, and checks it against PyTorch float64 at 1 and 2 threads; then one
frame runs through the file (``Detector.run_arrays``, 2 threads, median of ``--repeat`` calls after
a warm-up). Where OpenVINO is installed (the ``bench`` extra), the same frame through ONNX Runtime and
OpenVINO (f32) on the same file at 1 and 2 threads, each session timed alone, the two in turns
(``harness.alternate``; ``--rounds`` rounds of one call after one untimed call).
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import harness
import numpy as np

from fisheye_infer.cameras.rig import resolve_rig
from fisheye_infer.export.exporter import export, verification_frames
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.session import create_session

ROOT = Path(__file__).resolve().parents[1]
#: Where the checkpoints and ONNX files go by default (``benchmarks/profile_ops.py STEM`` reads the files there).
WORK_DIR = ROOT / "benchmarks" / "artifacts" / "official_configs"
#: config stem -> the rig it was calibrated on (None: the shipped Fisheye3DOD rig)
STEMS = {
    "fisheye_bevdet": None,
    "fisheye_petr": None,
    "fisheye_to_cyl_bevdet": None,
    "fisheye_to_cyl_petr": None,
    "fisheye_to_pinhole_bevdet": None,
    "fisheye_to_pinhole_petr": None,
    "nusc_bevdet": "rig-pinhole6/cameras.json",
    "nusc_petr": "rig-pinhole6/cameras.json",
}


def against_openvino(stem: str, path: Path, feeds: dict[str, np.ndarray], rounds: int) -> list[dict[str, object]]:
    """ONNX Runtime's and OpenVINO's time for one frame of ``path`` at 1 and 2 threads, timed in turns."""
    from speed_table import openvino_call

    rows: list[dict[str, object]] = []
    for threads in (1, 2):
        calls = {
            "ONNX Runtime": harness.session_call(create_session(path, threads=threads), feeds),
            "OpenVINO": openvino_call(path, threads, feeds),
        }
        ms = {k: t.median for k, t in harness.alternate(calls, rounds=rounds).items()}
        rows.append(
            {
                "config": stem,
                "threads": threads,
                "ONNX Runtime ms": ms["ONNX Runtime"],
                "OpenVINO ms": ms["OpenVINO"],
                "ORT/OpenVINO speed": ms["OpenVINO"] / ms["ONNX Runtime"],
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__)
    p = bench.parser
    p.add_argument(
        "--kit",
        type=Path,
        default=ROOT.parent / "shared" / "checkpoints",
        help="the checkpoint kit (make_checkpoint.py, configs/)",
    )
    p.add_argument("--data", type=Path, default=ROOT.parent / "shared" / "data", help="folder holding rig-pinhole6/")
    p.add_argument("--only", nargs="+", choices=sorted(STEMS), help="these config stems only")
    p.add_argument("--repeat", type=int, default=3, help="timed inference calls per file")
    p.add_argument("--rounds", type=int, default=3, help="rounds of ONNX Runtime against OpenVINO per thread count")
    p.add_argument(
        "--work-dir",
        type=Path,
        default=WORK_DIR,
        help="folder for the checkpoints and the ONNX files",
    )
    args = bench.parse(argv)
    args.work_dir.mkdir(parents=True, exist_ok=True)
    with_openvino = not harness.missing(["openvino"])
    rows, runtimes = [], []
    for stem in args.only or STEMS:
        ckpt = args.work_dir / f"{stem}.pth"
        subprocess.run(
            [sys.executable, str(args.kit / "make_checkpoint.py"), stem, str(ckpt)], check=True, capture_output=True
        )
        rig = resolve_rig(args.data / STEMS[stem]) if STEMS[stem] else resolve_rig(None)
        start = time.perf_counter()
        result = export(
            ckpt,
            args.work_dir / f"{stem}.onnx",
            config=args.kit / "configs" / f"{stem}.py",
            rig=rig,
            progress=lambda _: None,
        )
        seconds = time.perf_counter() - start
        detector = Detector(result.path, threads=2)
        frame = verification_frames(rig, 1, seed=7)
        valid = np.ones(frame.shape[:2], bool)
        inference = harness.measure(lambda d=detector, f=frame, v=valid: d.run_arrays(f, v), args.repeat)
        p_ = result.parity
        width, height = result.meta.image_size
        rows.append(
            {
                "config": stem,
                "architecture": result.meta.architecture,
                "input": f"{len(result.meta.cameras)} x {width}x{height}",
                "export s": seconds,
                "self-check": "passed" if p_.passed else "FAILED",
                "dense diff": p_.max_rank_score_abs_diff,
                "box diff m": p_.max_box_abs_diff_m,
                "score diff": p_.max_score_abs_diff,
                "float32 box m": p_.pytorch_float32[1] if p_.pytorch_float32 else None,
                "tie substitutions": p_.tie_substitutions,
                "inference median ms": inference.median,
            }
        )
        print(harness.markdown_table(rows[-1:]), file=sys.stderr, flush=True)
        if with_openvino:
            feeds = {INPUT_IMAGES: frame, INPUT_CAMERA_VALID: valid}
            runtimes += against_openvino(stem, result.path, feeds, args.rounds)
            print(harness.markdown_table(runtimes[-2:]), file=sys.stderr, flush=True)
        ckpt.unlink()
    tables = {"Official configs: export self-check and inference, 2 threads": rows}
    if with_openvino:
        tables["Official configs: ONNX Runtime against OpenVINO (f32), 1 and 2 threads"] = runtimes
    bench.save(args, tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
