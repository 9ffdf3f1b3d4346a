"""Reference points for ``run_all.py``: PyTorch eager and torch.compile, OpenVINO, GEMM peak, FLOPs, service.

Each comparison runs on the same checkpoint / ONNX file and the same frames as the ORT figures;
OpenVINO comes as a callable so that ``run_all.py`` times it in turns with ONNX Runtime. A
reference that cannot run here says why (an ``error`` entry or message), never raises.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def timed(fn: Callable[[], object], repeat: int, warmup: int = 1) -> list[float]:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def load_torch_model(arch: str, ckpt: Path) -> Any:
    from fisheye_infer.models import load_checkpoint, load_model
    from fisheye_infer.rig import default_rig

    state_dict, _ = load_checkpoint(ckpt)
    model, _ = load_model(arch, {"state_dict": state_dict}, None, default_rig())
    return model.eval()


def torch_eager(arch: str, ckpt: Path, images: np.ndarray, threads: int, repeat: int) -> list[float]:
    """Full model forward (uint8 frames in, boxes out) in PyTorch eager, no_grad."""
    import torch

    torch.set_num_threads(threads)
    model = load_torch_model(arch, ckpt)
    x, valid = torch.from_numpy(images), torch.ones(images.shape[:2], dtype=torch.bool)
    with torch.inference_mode():
        return timed(lambda: model(x, valid), repeat)


def torch_compile(arch: str, ckpt: Path, threads: int, repeat: int, timeout_s: float = 600) -> dict[str, Any]:
    """torch.compile (inductor) in a child process with a time limit: compiling can take minutes."""
    code = (
        f"import sys, time, json, numpy as np, torch; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from compare import load_torch_model, timed\n"
        f"torch.set_num_threads({threads:d})\n"
        f"m = load_torch_model({arch!r}, __import__('pathlib').Path({str(ckpt)!r}))\n"
        "from fisheye_infer.artifact import read_meta\n"
        "c = torch.compile(m)\n"
        "x = torch.from_numpy(np.random.default_rng(0).integers(0, 255, (1, 4, 800, 800, 3), dtype=np.uint8)); v = torch.ones((1, 4), dtype=torch.bool)\n"
        "t0 = time.perf_counter()\n"
        "with torch.inference_mode():\n"
        "    c(x, v); compile_s = time.perf_counter() - t0\n"
        f"    ts = timed(lambda: c(x, v), {repeat:d})\n"
        "print(json.dumps({'compile_s': compile_s, 'ms': ts}))\n"
    )
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return {"error": f"torch.compile did not finish within {timeout_s:.0f} s"}
    if done.returncode != 0:
        return {"error": "torch.compile failed: " + done.stderr.strip().splitlines()[-1][:300] if done.stderr.strip() else "unknown"}
    import json

    return json.loads(done.stdout.strip().splitlines()[-1])


def openvino(onnx_path: Path, images: np.ndarray, threads: int) -> Callable[[], object] | str:
    """One OpenVINO CPU inference on the same ONNX file (f32 precision hint: this CPU would pick
    bf16 otherwise), as a callable to time alongside ONNX Runtime; or why it cannot run here."""
    try:
        import openvino as ov
    except ImportError:
        return "openvino is not installed (pip install openvino)"
    try:
        core = ov.Core()
        compiled = core.compile_model(str(onnx_path), "CPU", {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32",
                                                               "PERFORMANCE_HINT": "LATENCY"})
        request = compiled.create_infer_request()
        feeds = {"images": images, "camera_valid": np.ones(images.shape[:2], bool)}
        request.infer(feeds)
        return lambda: request.infer(feeds)
    except Exception as exc:  # OpenVINO raises its own untyped errors
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        return f"OpenVINO failed: {' / '.join(lines[1:3] or lines)[:300]}"


def _matmul_model(kind: str, n: int) -> bytes:
    from onnx import TensorProto, helper

    if kind == "fp32":
        a = helper.make_tensor_value_info("a", TensorProto.FLOAT, [n, n])
        b = helper.make_tensor_value_info("b", TensorProto.FLOAT, [n, n])
        y = helper.make_tensor_value_info("y", TensorProto.FLOAT, [n, n])
        node = helper.make_node("MatMul", ["a", "b"], ["y"])
    else:  # u8 x s8 -> s32, what QDQ convolutions become on VNNI
        a = helper.make_tensor_value_info("a", TensorProto.UINT8, [n, n])
        b = helper.make_tensor_value_info("b", TensorProto.INT8, [n, n])
        y = helper.make_tensor_value_info("y", TensorProto.INT32, [n, n])
        node = helper.make_node("MatMulInteger", ["a", "b"], ["y"])
    graph = helper.make_graph([node], "gemm", [a, b], [y])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10).SerializeToString()


def gemm_peak(threads: int, n: int = 2048, repeat: int = 5) -> dict[str, float]:
    """GFLOP/s of large square matrix products: numpy, torch, ORT MatMul (fp32) and ORT MatMulInteger (int8)."""
    import onnxruntime as ort
    import torch

    from fisheye_infer.session import session_options

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, n), np.float32), rng.standard_normal((n, n), np.float32)
    flop = 2.0 * n**3
    out: dict[str, float] = {}
    out["numpy_fp32"] = flop / np.median(timed(lambda: a @ b, repeat)) / 1e6
    torch.set_num_threads(threads)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    out["torch_fp32"] = flop / np.median(timed(lambda: ta @ tb, repeat)) / 1e6
    for kind, feeds in (("fp32", {"a": a, "b": b}),
                        ("int8", {"a": rng.integers(0, 255, (n, n), dtype=np.uint8), "b": rng.integers(-127, 127, (n, n), dtype=np.int8)})):
        sess = ort.InferenceSession(_matmul_model(kind, n), session_options(threads), providers=["CPUExecutionProvider"])
        out[f"ort_{kind}"] = flop / np.median(timed(lambda sess=sess, feeds=feeds: sess.run(None, feeds), repeat)) / 1e6
    return out


def count_flops(onnx_path: Path) -> dict[str, float]:
    """Multiply-add FLOPs (2 per MAC) of Conv, ConvTranspose, MatMul and Gemm at batch 1, from the graph.

    Shapes come from one ORT run with those nodes' outputs exposed (exact, even where the
    graph's shapes are symbolic, as in the pooling buckets); weights from the initializers.
    """
    import onnx
    import onnxruntime as ort

    from fisheye_infer.graph_stages import name_nodes

    model = onnx.load(str(onnx_path))
    name_nodes(model)
    inits = {i.name: list(i.dims) for i in model.graph.initializer}
    ops = [n for n in model.graph.node if n.op_type in ("Conv", "ConvTranspose", "MatMul", "Gemm")]
    wanted = list(dict.fromkeys([n.output[0] for n in ops] + [n.input[0] for n in ops if n.input[0] not in inits]))
    known = {o.name for o in model.graph.output} | {i.name for i in model.graph.input}
    model.graph.output.extend(onnx.helper.make_tensor_value_info(w, onnx.TensorProto.FLOAT, None) for w in wanted if w not in known)
    shape = [d.dim_value for d in model.graph.input[0].type.tensor_type.shape.dim][1:]
    feeds = {"images": np.zeros((1, *shape), np.uint8), "camera_valid": np.ones((1, shape[0]), bool)}
    options = ort.SessionOptions()
    options.log_severity_level = 3
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    sess = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    names = [o.name for o in sess.get_outputs()]
    shapes = {k: v.shape for k, v in zip(names, sess.run(names, feeds))}
    del model
    total = {"Conv": 0.0, "ConvTranspose": 0.0, "MatMul": 0.0, "Gemm": 0.0}
    for n in ops:
        out = shapes[n.output[0]]
        if n.op_type == "Conv":
            w = inits[n.input[1]]
            total["Conv"] += 2.0 * np.prod(out) * int(np.prod(w[1:]))
        elif n.op_type == "ConvTranspose":
            w, x = inits[n.input[1]], shapes.get(n.input[0])
            total["ConvTranspose"] += 2.0 * np.prod(x) * int(np.prod(w[1:]))
        else:
            a = shapes.get(n.input[0]) or inits[n.input[0]]
            total[n.op_type] += 2.0 * np.prod(out) * int(a[-1])
    total["total"] = sum(total.values())
    return {k: v / 1e9 for k, v in total.items()}  # GFLOP


def service_overhead(onnx_path: Path, frame_jpeg: dict[str, bytes], frame_arrays: list[np.ndarray], threads: int, repeat: int) -> dict[str, Any]:
    """POST /detect with JPEG parts against ``Detector.detect`` on arrays, same process, same Detector."""
    try:
        import httpx
        import uvicorn

        from fisheye_infer.detector import Detector
        from fisheye_infer.service.app import create_app
        from fisheye_infer.service.settings import ServiceSettings
    except ImportError as exc:
        return {"error": f"the service is not importable ({exc}); hook: benchmarks/compare.py service_overhead"}
    detector = Detector(onnx_path, threads=threads)
    settings = ServiceSettings(model_path=onnx_path, port=8765, threads=threads)
    server = uvicorn.Server(uvicorn.Config(create_app(settings, detector), host="127.0.0.1", port=8765, log_level="error"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        for _ in range(200):
            if server.started:
                break
            time.sleep(0.05)
        files = {name: (f"{name}.jpg", data, "image/jpeg") for name, data in frame_jpeg.items()}
        with httpx.Client(base_url="http://127.0.0.1:8765", timeout=120) as client:
            decode: list[float] = []

            def post() -> None:
                response = client.post("/detect", files=files)
                response.raise_for_status()
                decode.append(float(response.json()["timings_ms"]["decode"]))

            def direct() -> None:
                detector.detect(frame_arrays)

            post()  # warm-up
            direct()
            decode.clear()
            service, plain = [], []
            for _ in range(repeat):  # alternating, so load spikes hit both alike
                service += timed(post, 1, warmup=0)
                plain += timed(direct, 1, warmup=0)
        return {"service_ms": service, "direct_ms": plain, "decode_ms": decode}
    except Exception as exc:
        return {"error": f"service measurement failed: {exc}"}
    finally:
        server.should_exit = True
        thread.join(timeout=30)
