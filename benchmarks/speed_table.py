"""The shipped models' speed in one table: int8 against fp32, ONNX Runtime against OpenVINO, 1 and 2 threads.

    python benchmarks/speed_table.py [--models compact compact-petr] [--quick]

For each shipped model:
1. its fp32 file (``export``, verified) and the int8 file ``--int8`` writes from it (``export_int8``, the int8
   search's choice), the files of ``model_files`` (kept under ``benchmarks/artifacts/``);
2. one frame (the export's verification frame) through ONNX Runtime fp32 and int8 (the runtime's session
   options) and OpenVINO f32 on the fp32 file, at 1 and at 2 threads: each session timed alone in blocks after
   warm-up, the sessions in turns (``harness.alternate``: two ONNX Runtime sessions timed call by call slow each
   other through their spinning worker threads);
3. per model and thread count: int8/fp32 and ONNX Runtime/OpenVINO speed (a ratio above 1: the first is faster);
   per model: how each file scales from 1 to 2 threads, and int8's scaling over fp32's.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path
from typing import Any

import harness
import numpy as np
from model_files import SHIPPED, model_files

from fisheye_infer.export.exporter import verification_frames
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, read_meta
from fisheye_infer.runtime.session import create_session


def openvino_call(path: Path, threads: int, feeds: dict[str, np.ndarray]) -> Any:
    """One OpenVINO f32 inference of ``path`` on ``feeds``, as a callable."""
    import openvino as ov

    config = {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32"}
    request = ov.Core().compile_model(str(path), "CPU", config).create_infer_request()
    return partial(request.infer, feeds)


def main() -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="2 rounds of 2")
    bench.parser.add_argument(
        "--models", nargs="+", choices=list(SHIPPED), default=list(SHIPPED), help="shipped models"
    )
    args = bench.parse()
    rounds, repeat = (2, 2) if args.quick else (5, 3)
    rows, scaling = [], []
    for short in args.models:
        name, files = SHIPPED[short], model_files(short)
        fp32, int8 = files.fp32, files.int8
        images = verification_frames(read_meta(fp32).rig, 1)
        feeds = {INPUT_IMAGES: images, INPUT_CAMERA_VALID: np.ones(images.shape[:2], bool)}
        ms: dict[int, dict[str, float]] = {}
        for threads in (1, 2):
            calls = {
                "ORT fp32": harness.session_call(create_session(fp32, threads=threads), feeds),
                "ORT int8": harness.session_call(create_session(int8, threads=threads), feeds),
                "OpenVINO fp32": openvino_call(fp32, threads, feeds),
            }
            ms[threads] = {k: t.median for k, t in harness.alternate(calls, rounds=rounds, repeat=repeat).items()}
            m = ms[threads]
            rows.append(
                {
                    "model": name,
                    "threads": threads,
                    **{f"{k} ms": v for k, v in m.items()},
                    "int8/fp32 speed": m["ORT fp32"] / m["ORT int8"],
                    "ORT/OpenVINO speed (fp32)": m["OpenVINO fp32"] / m["ORT fp32"],
                }
            )
            print(rows[-1], flush=True)
        fp32_scaling, int8_scaling = (ms[1][k] / ms[2][k] for k in ("ORT fp32", "ORT int8"))
        scaling.append(
            {
                "model": name,
                "fp32 1 -> 2 threads": fp32_scaling,
                "int8 1 -> 2 threads": int8_scaling,
                "int8 scaling / fp32 scaling": int8_scaling / fp32_scaling,
            }
        )
    bench.save(args, {"Speed of the shipped models": rows, "Scaling with threads": scaling})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
