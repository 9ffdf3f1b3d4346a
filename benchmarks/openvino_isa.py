"""int8 against fp32 with the instruction set capped: what the same files gain on a CPU without VNNI.

    .venv/bin/python benchmarks/openvino_isa.py model.onnx model.int8.onnx [--isa native,AVX2,AVX512_CORE] [--threads 1,2]

ONNX Runtime picks its kernels from the CPU's flags and has no switch to pretend to be another CPU.
OpenVINO's CPU plugin does: its own kernels read ``OV_CPU_MAX_ISA`` and oneDNN's read
``ONEDNN_MAX_CPU_ISA``, each once, so each ISA runs in a fresh process with both set (``make bench``
installs OpenVINO). ``AVX2`` is an AVX2-only CPU's instruction set (int8 by ``vpmaddubsw`` pairs, no
VNNI); ``AVX512_CORE`` is AVX-512 before VNNI (Skylake-SP). Same cores, caches and clocks as the
machine's own: the ratio isolates the instruction set, not a different CPU. These are OpenVINO's
speed-ups, not ONNX Runtime's. Prints, per ISA and thread count, the median latency of each file,
the int8 speed-up, the kernels the int8 convolutions ran (``jit_avx2_I8``, ``brgconv_avx512_I8``,
...), and how many kernels of either file still name AVX-512 or AMX, so a cap that did not take is
visible.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from collections import Counter

import numpy as np

#: OpenVINO's own kernels and oneDNN's each read one of these (``OV_CPU_MAX_ISA``, ``ONEDNN_MAX_CPU_ISA``).
ISA_VARIABLES = ("OV_CPU_MAX_ISA", "ONEDNN_MAX_CPU_ISA")
WORKER_TIMEOUT_S = 1800


def time_files(paths: list[str], threads: int, rounds: int, repeat: int) -> dict[str, object]:
    """In this process (ISA already capped): median ms per file, files alternated, and the int8 convolutions' kernels."""
    import openvino as ov

    core = ov.Core()
    rng = np.random.default_rng(0)
    compiled, feeds = {}, {}
    for path in paths:
        model = core.compile_model(path, "CPU", {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32"})
        compiled[path] = model.create_infer_request()
        feeds[path] = {}
        for port in model.inputs:
            shape = [d.get_length() if d.is_static else 1 for d in port.get_partial_shape()]
            if port.get_element_type() == ov.Type.boolean:
                feeds[path][port.get_any_name()] = np.ones(shape, dtype=bool)
            else:
                feeds[path][port.get_any_name()] = rng.integers(0, 256, shape).astype(np.uint8)
    kernels: Counter[str] = Counter()
    wide = 0
    for path in paths:
        for op in compiled[path].get_compiled_model().get_runtime_model().get_ops():
            info = op.get_rt_info()
            kind = str(info["primitiveType"].astype(str))
            wide += "512" in kind or "amx" in kind
            if path == paths[-1] and str(info["layerType"].astype(str)) == "Convolution" and "I8" in kind:
                kernels[kind] += 1
    times: dict[str, list[float]] = {path: [] for path in paths}
    for path in paths:
        for _ in range(2):
            compiled[path].infer(feeds[path])
    for _ in range(rounds):
        for path in paths:
            for _ in range(repeat):
                t0 = time.perf_counter()
                compiled[path].infer(feeds[path])
                times[path].append((time.perf_counter() - t0) * 1e3)
    return {"ms": {path: float(np.median(t)) for path, t in times.items()}, "int8_kernels": dict(kernels), "avx512_or_amx_kernels": wide}


def measure(fp32: str, int8: str, isas: list[str], threads: list[int], rounds: int, repeat: int) -> dict[str, dict[int, dict[str, object]]]:
    """Each ISA in its own process; {isa: {threads: time_files(...)}}."""
    results: dict[str, dict[int, dict[str, object]]] = {}
    for isa in isas:
        env = {k: v for k, v in os.environ.items() if k not in ISA_VARIABLES}
        if isa != "native":
            env.update(dict.fromkeys(ISA_VARIABLES, isa))
        results[isa] = {}
        for n in threads:
            job = json.dumps({"paths": [fp32, int8], "threads": n, "rounds": rounds, "repeat": repeat})
            try:
                done = subprocess.run([sys.executable, __file__, "--worker", job], env=env, capture_output=True, text=True, check=False,
                                      timeout=WORKER_TIMEOUT_S)
            except subprocess.TimeoutExpired:
                raise SystemExit(f"OpenVINO at {isa}, {n} thread(s): no result within {WORKER_TIMEOUT_S} s") from None
            lines = done.stdout.strip().splitlines()
            if done.returncode != 0 or not lines:
                raise SystemExit(f"OpenVINO at {isa}, {n} thread(s) failed (exit {done.returncode}):\n{done.stderr[-2000:]}")
            results[isa][n] = json.loads(lines[-1])
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("fp32", nargs="?")
    parser.add_argument("int8", nargs="?")
    parser.add_argument("--isa", default="native,AVX2", help="comma-separated ONEDNN_MAX_CPU_ISA values; 'native' = no cap")
    parser.add_argument("--threads", default="1,2")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--worker", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        job = json.loads(args.worker)
        print(json.dumps(time_files(job["paths"], job["threads"], job["rounds"], job["repeat"])))
        return
    if not (args.fp32 and args.int8):
        parser.error("give the fp32 file and its int8 file")
    from fisheye_infer.cpu import cpu_info

    cpu = cpu_info()
    print(f"CPU: {cpu.label}; AVX2: {cpu.avx2}, AVX-512: {cpu.avx512}, VNNI: {cpu.vnni}")
    results = measure(args.fp32, args.int8, args.isa.split(","), [int(t) for t in args.threads.split(",")], args.rounds, args.repeat)
    print(f"\nOpenVINO, medians of {args.rounds} x {args.repeat} calls, files alternated; one process per ISA\n")
    print("| ISA cap | threads | fp32 ms | int8 ms | int8 speed-up | int8 convolution kernels | AVX-512/AMX kernels left |\n|---|---|---|---|---|---|---|")
    for isa, by_threads in results.items():
        for n, r in by_threads.items():
            ms = r["ms"]
            assert isinstance(ms, dict)
            kernels = ", ".join(f"{k} x{v}" for k, v in sorted(r["int8_kernels"].items()))  # type: ignore[union-attr]
            print(f"| {isa} | {n} | {ms[args.fp32]:.1f} | {ms[args.int8]:.1f} | {ms[args.fp32] / ms[args.int8]:.2f}x | {kernels} "
                  f"| {r['avx512_or_amx_kernels']} |")


if __name__ == "__main__":
    main()
