"""Where the time goes inside one exported file: ONNX Runtime's and OpenVINO's profilers side by side.

    .venv/bin/python benchmarks/profile_ops.py model.onnx [--threads 2] [--runs 4] [--top 10]

Runs the file on one seeded frame, ``--runs`` times in each runtime, and prints the last run's
time per operator type (ONNX Runtime's kernel times with the project's session options;
OpenVINO's per-layer counters, f32), the slowest ONNX Runtime nodes with their input shapes,
and how far OpenVINO's outputs are from ONNX Runtime's. The earlier runs are warm-up: the first
one allocates and is far slower. Profiling adds overhead, so compare shares, not totals, with
``fisheye-infer bench``. OpenVINO is optional (``make bench`` installs it).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
import onnxruntime as ort

from fisheye_infer.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, read_meta
from fisheye_infer.export.exporter import verification_frames
from fisheye_infer.session import session_options


def _by_type(times: dict[str, float]) -> str:
    top = sorted(times.items(), key=lambda kv: -kv[1])
    return ", ".join(f"{k} {v:.0f}" for k, v in top[:8]) + f"; total {sum(times.values()):.0f} ms"


def profile_ort(path: Path, feeds: dict[str, np.ndarray], threads: int, runs: int, top: int) -> list[np.ndarray]:
    options = session_options(threads)
    options.enable_profiling = True
    with tempfile.TemporaryDirectory() as tmp:
        options.profile_file_prefix = str(Path(tmp) / "ort")
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        for _ in range(runs):
            outputs = session.run(list(OUTPUTS), feeds)
        events = json.loads(Path(session.end_profiling()).read_text())
    kernels = [e for e in events if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]
    last = kernels[-(len(kernels) // runs):]
    per_type: dict[str, float] = {}
    for e in last:
        per_type[e["args"]["op_name"]] = per_type.get(e["args"]["op_name"], 0.0) + e["dur"] / 1e3
    print(f"ONNX Runtime {ort.__version__}, ms by operator: {_by_type(per_type)}")
    for e in sorted(last, key=lambda e: -e["dur"])[:top]:
        shapes = [next(iter(s.values())) for s in e["args"].get("input_type_shape", [])][:3]
        print(f"  {e['dur'] / 1e3:8.1f} ms  {e['args']['op_name']:<12} {e['name'].removesuffix('_kernel_time'):<40} {shapes}")
    return outputs


def profile_openvino(path: Path, feeds: dict[str, np.ndarray], threads: int, runs: int, reference: list[np.ndarray]) -> None:
    try:
        import openvino as ov
    except ImportError:
        print("OpenVINO: not installed (make bench installs it)")
        return
    compiled = ov.Core().compile_model(str(path), "CPU", {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32", "PERF_COUNT": True})
    request = compiled.create_infer_request()
    for _ in range(runs):
        request.infer(feeds)
    per_type: dict[str, float] = {}
    for layer in request.get_profiling_info():
        per_type[layer.node_type] = per_type.get(layer.node_type, 0.0) + layer.real_time.total_seconds() * 1e3
    print(f"OpenVINO {ov.__version__}, ms by layer type: {_by_type(per_type)}")
    diffs = []
    for name, ref in zip(OUTPUTS, reference):
        got = request.get_tensor(name).data
        diffs.append(f"{name} {np.abs(got.astype(np.float64) - ref.astype(np.float64)).max():.2e}")
    print(f"OpenVINO vs ONNX Runtime, max |difference|: {', '.join(diffs)}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--runs", type=int, default=4, help="runs per runtime; only the last is reported (default 4)")
    parser.add_argument("--top", type=int, default=10, help="slowest ONNX Runtime nodes to list (default 10)")
    args = parser.parse_args()
    images = verification_frames(read_meta(args.model).rig, 1)
    feeds = {INPUT_IMAGES: images, INPUT_CAMERA_VALID: np.ones(images.shape[:2], bool)}
    runs = max(2, args.runs)
    reference = profile_ort(args.model, feeds, args.threads, runs, args.top)
    profile_openvino(args.model, feeds, args.threads, runs, reference)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
