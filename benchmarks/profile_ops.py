"""Where the time goes inside one exported file: ONNX Runtime's and OpenVINO's profilers side by side.

    python benchmarks/profile_ops.py compact [--int8] [--threads 2] [--runs 4] [--top 10]

Runs the file (``--int8``: the int8 file of a named model) on one seeded frame, ``--runs`` times in each
runtime; the last run's time per operator type (ONNX Runtime's kernel times with the project's session options;
OpenVINO's per-layer counters, f32), ONNX Runtime's time per operator and input shapes (the nodes of repeated
layers summed: a decoder's six layers' attention products are one row; weights ONNX Runtime packs at load time
are not among a kernel's inputs), the slowest ONNX Runtime nodes with their input shapes, and how far
OpenVINO's outputs are from ONNX Runtime's. The earlier runs are warm-up: the first one allocates. Profiling
adds overhead: compare shares, not totals, with ``fisheye-infer bench``. OpenVINO is optional (the ``bench``
extra).
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path
from typing import Any

import harness
import numpy as np
import onnxruntime as ort
from model_files import MODEL_HELP, model_path

from fisheye_infer.export.exporter import verification_frames
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, read_meta
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.session import open_session, session_options

Row = dict[str, Any]


def _by_type(runtime: str, times: dict[str, float]) -> list[Row]:
    total = sum(times.values())
    ranked = sorted(times.items(), key=lambda kv: -kv[1])
    return [{"runtime": runtime, "operator": op, "ms": ms, "share": ms / total} for op, ms in ranked]


def _shapes(event: dict[str, Any]) -> list[str]:
    """A kernel event's input shapes (the first three), each as ``type[dims]``."""
    return [f"{t}{list(d)}" for s in event["args"].get("input_type_shape", [])[:3] for t, d in s.items()]


def _by_shapes(kernels: list[dict[str, Any]], top: int) -> list[Row]:
    """The ``top`` (operator, input shapes) groups by their summed time."""
    groups: dict[tuple[str, str], list[float]] = {}
    for e in kernels:
        groups.setdefault((e["args"]["op_name"], " x ".join(_shapes(e))), []).append(e["dur"] / 1e3)
    total = sum(e["dur"] for e in kernels) / 1e3
    ranked = sorted(groups.items(), key=lambda kv: -sum(kv[1]))[:top]
    return [
        {"operator": op, "input shapes": shapes, "nodes": len(ms), "ms": sum(ms), "share": sum(ms) / total}
        for (op, shapes), ms in ranked
    ]


def profile_ort(
    path: Path, feeds: dict[str, np.ndarray], threads: int, runs: int, top: int
) -> tuple[list[np.ndarray], list[Row], list[Row], list[Row]]:
    """The outputs, ms per operator type, per operator and input shapes, and the ``top`` slowest nodes of the last
    of ``runs`` runs."""
    options = session_options(threads)
    options.enable_profiling = True
    with tempfile.TemporaryDirectory() as tmp:
        options.profile_file_prefix = str(Path(tmp) / "ort")
        session = open_session(str(path), options, ["CPUExecutionProvider"], f"model {path}")
        with flushed_denormals():
            for _ in range(runs):
                outputs = session.run(list(OUTPUTS), feeds)
        events = json.loads(Path(session.end_profiling()).read_text())
    kernels = [e for e in events if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]
    last = kernels[-(len(kernels) // runs) :]
    per_type: dict[str, float] = {}
    for e in last:
        per_type[e["args"]["op_name"]] = per_type.get(e["args"]["op_name"], 0.0) + e["dur"] / 1e3
    slowest = [
        {
            "node": e["name"].removesuffix("_kernel_time"),
            "operator": e["args"]["op_name"],
            "ms": e["dur"] / 1e3,
            "input shapes": " x ".join(_shapes(e)),
        }
        for e in sorted(last, key=lambda e: -e["dur"])[:top]
    ]
    return outputs, _by_type(f"ONNX Runtime {ort.__version__}", per_type), _by_shapes(last, top), slowest


def profile_openvino(
    path: Path, feeds: dict[str, np.ndarray], threads: int, runs: int, reference: list[np.ndarray]
) -> tuple[list[Row], list[Row]]:
    """ms per layer type of the last of ``runs`` runs, and the largest difference from ``reference`` per output."""
    import openvino as ov

    config = {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32", "PERF_COUNT": True}
    request = ov.Core().compile_model(str(path), "CPU", config).create_infer_request()
    for _ in range(runs):
        request.infer(feeds)
    per_type: dict[str, float] = {}
    for layer in request.get_profiling_info():
        per_type[layer.node_type] = per_type.get(layer.node_type, 0.0) + layer.real_time.total_seconds() * 1e3
    got = {name: request.get_tensor(name).data.astype(np.float64) for name in OUTPUTS}
    diffs = [
        {"output": name, "max abs difference": float(np.abs(got[name] - ref).max())}
        for name, ref in zip(OUTPUTS, reference)
    ]
    return _by_type(f"OpenVINO {ov.__version__}", per_type), diffs


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__)
    bench.parser.add_argument("model", help=MODEL_HELP)
    bench.parser.add_argument("--threads", type=int, default=2)
    bench.parser.add_argument("--runs", type=int, default=4, help="runs per runtime; the last is reported (default 4)")
    bench.parser.add_argument("--top", type=int, default=10, help="rows of the shape and node tables (default 10)")
    bench.parser.add_argument("--int8", action="store_true", help="the int8 file of a named model")
    args = bench.parse(argv)
    model = model_path(args.model, "int8" if args.int8 else "fp32")
    images = verification_frames(read_meta(model).rig, 1)
    feeds = {INPUT_IMAGES: images, INPUT_CAMERA_VALID: np.ones(images.shape[:2], bool)}
    runs = max(2, args.runs)
    reference, by_type, by_shapes, slowest = profile_ort(model, feeds, args.threads, runs, args.top)
    tables = {
        "Time by operator type, last run": by_type,
        "ONNX Runtime: time by operator and input shapes": by_shapes,
        "Slowest ONNX Runtime nodes": slowest,
    }
    if harness.missing(["openvino"]):
        reason = "openvino is not installed (pip install -e '.[bench]')"
        tables["Not measured"] = [{"runtime": "OpenVINO", "reason": reason}]
    else:
        float64 = [r.astype(np.float64) for r in reference]
        ov_by_type, diffs = profile_openvino(model, feeds, args.threads, runs, float64)
        tables["Time by operator type, last run"] = by_type + ov_by_type
        tables["OpenVINO against ONNX Runtime"] = diffs
    bench.save(args, tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
