"""int8 against fp32 with the instruction set capped: what the same files gain on a CPU without VNNI.

    python benchmarks/openvino_isa.py compact [--isa native,AVX2,AVX512_CORE] [--threads 1,2]
    python benchmarks/openvino_isa.py model.onnx model.int8.onnx

ONNX Runtime picks its kernels from the CPU's flags and has no switch to pretend to be another CPU.
OpenVINO's CPU plugin does: its own kernels read ``OV_CPU_MAX_ISA`` and oneDNN's read
``ONEDNN_MAX_CPU_ISA``, each once, so each ISA runs in a fresh process with both set. ``AVX2`` is
an AVX2-only CPU's instruction set (int8 by ``vpmaddubsw`` pairs, no VNNI); ``AVX512_CORE`` is
AVX-512 before VNNI (Skylake-SP). Same cores, caches and clocks as the machine's own: the ratio
isolates the instruction set, not a different CPU. These are OpenVINO's speed-ups, not ONNX
Runtime's. Per ISA and thread count: the median latency of each file (files in turns), the int8
speed-up, the kernels the int8 convolutions ran (``jit_avx2_I8``, ``brgconv_avx512_I8``, ...), and
how many kernels of either file still name AVX-512 or AMX, so a cap that did not take shows.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import Counter
from typing import Any

import harness
import numpy as np
from model_files import NAMES, model_path

#: OpenVINO's own kernels and oneDNN's each read one of these (``OV_CPU_MAX_ISA``, ``ONEDNN_MAX_CPU_ISA``).
ISA_VARIABLES = ("OV_CPU_MAX_ISA", "ONEDNN_MAX_CPU_ISA")
WORKER_TIMEOUT_S = 1800


def time_files(paths: list[str], threads: int, rounds: int, repeat: int) -> dict[str, Any]:
    """In this process (ISA already capped): median ms per file, files in turns, and the int8 convolutions' kernels."""
    import openvino as ov

    core = ov.Core()
    rng = np.random.default_rng(0)
    requests: dict[str, Any] = {}
    feeds: dict[str, dict[str, np.ndarray]] = {}
    for path in paths:
        model = core.compile_model(path, "CPU", {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32"})
        requests[path] = model.create_infer_request()
        feeds[path] = {}
        for port in model.inputs:
            shape = [d.get_length() if d.is_static else 1 for d in port.get_partial_shape()]
            boolean = port.get_element_type() == ov.Type.boolean
            value = np.ones(shape, bool) if boolean else rng.integers(0, 256, shape).astype(np.uint8)
            feeds[path][port.get_any_name()] = value
    kernels: Counter[str] = Counter()
    wide = 0
    for path in paths:
        for op in requests[path].get_compiled_model().get_runtime_model().get_ops():
            info = op.get_rt_info()
            kind = str(info["primitiveType"].astype(str))
            wide += "512" in kind or "amx" in kind
            if path == paths[-1] and str(info["layerType"].astype(str)) == "Convolution" and "I8" in kind:
                kernels[kind] += 1
    calls = {path: (lambda r=requests[path], f=feeds[path]: r.infer(f)) for path in paths}
    timings = harness.alternate(calls, rounds, repeat)
    return {
        "ms": {path: t.median for path, t in timings.items()},
        "int8_kernels": dict(kernels),
        "avx512_or_amx_kernels": wide,
    }


def measure(fp32: str, int8: str, isa: str, threads: int, rounds: int, repeat: int) -> dict[str, Any]:
    """``time_files`` in a fresh process with the ISA capped (``native``: not capped)."""
    env = {k: v for k, v in os.environ.items() if k not in ISA_VARIABLES}
    if isa != "native":
        env.update(dict.fromkeys(ISA_VARIABLES, isa))
    job = json.dumps({"paths": [fp32, int8], "threads": threads, "rounds": rounds, "repeat": repeat})
    try:
        done = subprocess.run(
            [sys.executable, __file__, "--worker", job],
            env=env,
            capture_output=True,
            text=True,
            check=False,
            timeout=WORKER_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired:
        raise SystemExit(f"OpenVINO at {isa}, {threads} thread(s): no result within {WORKER_TIMEOUT_S} s") from None
    lines = done.stdout.strip().splitlines()
    if done.returncode != 0 or not lines:
        raise SystemExit(
            f"OpenVINO at {isa}, {threads} thread(s) failed (exit {done.returncode}):\n{done.stderr[-2000:]}"
        )
    return json.loads(lines[-1])


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__)
    p = bench.parser
    p.add_argument("fp32", nargs="?", help="the fp32 file, or one of compact, fisheye-bevdet, fisheye-petr (its files)")
    p.add_argument("int8", nargs="?", help="its int8 file")
    p.add_argument("--isa", default="native,AVX2", help="comma-separated ONEDNN_MAX_CPU_ISA values; 'native': no cap")
    p.add_argument("--threads", default="1,2")
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--worker", help=argparse.SUPPRESS)
    args = bench.parse(argv)
    if args.worker:
        job = json.loads(args.worker)
        print(json.dumps(time_files(job["paths"], job["threads"], job["rounds"], job["repeat"])))
        return 0
    if not args.fp32 or not (args.int8 or args.fp32 in NAMES):
        p.error("give the fp32 file and its int8 file, or a model's name")
    fp32, int8 = str(model_path(args.fp32)), str(model_path(args.int8 or args.fp32, "int8"))
    if harness.missing(["openvino"]):
        raise SystemExit("openvino is not installed (pip install -e '.[bench]')")
    rows = []
    for isa in args.isa.split(","):
        for threads in (int(t) for t in args.threads.split(",")):
            r = measure(fp32, int8, isa, threads, args.rounds, args.repeat)
            fp32_ms, int8_ms = r["ms"][fp32], r["ms"][int8]
            rows.append(
                {
                    "ISA cap": isa,
                    "threads": threads,
                    "fp32 median ms": fp32_ms,
                    "int8 median ms": int8_ms,
                    "int8 speed-up": fp32_ms / int8_ms,
                    "int8 convolution kernels": [f"{k} x{v}" for k, v in sorted(r["int8_kernels"].items())],
                    "AVX-512/AMX kernels left": r["avx512_or_amx_kernels"],
                }
            )
    bench.save(args, {"OpenVINO, files in turns, one process per ISA": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
