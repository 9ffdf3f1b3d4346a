"""ONNX Runtime against other ways to run the same model here: PyTorch eager, torch.compile, OpenVINO, int8.

    python benchmarks/compare.py                            # full-size FisheyeBEVDet and FisheyePETR, seeded weights
    python benchmarks/compare.py --models compact --quick   # the shipped compact FisheyeBEVDet

Per model (``model_files``: the checkpoint, its fp32 and int8 exports):

- one frame through each runtime, timed in turns at ``--ratio-threads``: the ONNX Runtime graph
  (``Detector.run_arrays``), ONNX Runtime fp32 and int8 end to end (``Detector.detect`` on arrays),
  PyTorch eager and OpenVINO (f32, the same ONNX file); torch.compile in a child process, since
  compiling takes minutes;
- ``fisheye-infer bench`` on both files (``fisheye_infer.tools.bench.bench_model``): time per stage,
  batch sizes, thread counts, the graph cut into its stages, peak RSS;
- the graph's multiply-add FLOPs, and the time they take at the best fp32 GEMM throughput measured
  here (numpy, PyTorch and ONNX Runtime on 2048 x 2048 matrices);
- ``POST /detect`` with JPEG parts against ``Detector.detect`` on arrays, timed in turns.

A reference that cannot run here is listed with the reason.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import harness
import numpy as np
from model_files import NAMES, ModelFiles, model_files, torch_model

Row = dict[str, Any]
RUNTIMES, COMPILED, MODELS = "Runtimes, one frame, in turns", "torch.compile, one frame, own process", "Models"
BENCH = (
    "fisheye-infer bench: end to end by stage",
    "fisheye-infer bench: graph stages, batch 1",
    "fisheye-infer bench: peak RSS",
)
SERVICE, SKIPPED = "Service overhead, one frame, in turns", "Not measured"


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def openvino(onnx_path: Path, images: np.ndarray, threads: int) -> Callable[[], object] | str:
    """One OpenVINO CPU inference on the ONNX file (f32: a CPU with bf16 would pick that otherwise), or why it
    cannot run here."""
    if harness.missing(["openvino"]):
        return "openvino is not installed (pip install -e '.[bench]')"
    import openvino as ov

    try:
        config = {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32", "PERFORMANCE_HINT": "LATENCY"}
        compiled = ov.Core().compile_model(str(onnx_path), "CPU", config)
        request = compiled.create_infer_request()
        feeds = {"images": images, "camera_valid": np.ones(images.shape[:2], bool)}
        request.infer(feeds)
        return lambda: request.infer(feeds)
    except Exception as exc:  # OpenVINO raises its own untyped errors
        lines = [ln.strip() for ln in str(exc).strip().splitlines() if ln.strip()]
        return f"OpenVINO failed: {' / '.join(lines[1:3] or lines)[:300]}"


def runtimes(
    files: ModelFiles, images: np.ndarray, threads: int, rounds: int, repeat: int
) -> tuple[dict[str, harness.Stats], list[Row]]:
    """One frame through each runtime, in turns; and the runtimes that cannot run here, with the reason."""
    import torch

    from fisheye_infer.runtime.detector import Detector

    valid = np.ones(images.shape[:2], bool)
    frame = list(images[0])
    ort32, ort8 = Detector(files.fp32, threads=threads), Detector(files.int8, threads=threads)
    torch.set_num_threads(threads)
    model = torch_model(files)
    x, v = torch.from_numpy(images), torch.from_numpy(valid)

    def eager() -> None:
        with torch.inference_mode():
            model(x, v)

    fns: dict[str, Callable[[], object]] = {
        "ONNX Runtime fp32, graph": lambda: ort32.run_arrays(images, valid),
        "ONNX Runtime fp32, end to end": lambda: ort32.detect(frame),
        "ONNX Runtime int8, end to end": lambda: ort8.detect(frame),
        "PyTorch eager": eager,
    }
    skipped = []
    ov = openvino(files.fp32, images, threads)
    if callable(ov):
        fns["OpenVINO fp32, graph"] = ov
    else:
        skipped.append({"model": files.name, "reference": "OpenVINO", "reason": ov})
    _progress(f"{files.name}: {', '.join(fns)} in turns at {threads} thread(s)")
    return harness.alternate(fns, rounds, repeat), skipped


def torch_compile(name: str, threads: int, repeat: int, timeout_s: float = 1800) -> dict[str, Any]:
    """torch.compile (inductor) in a child process with a time limit: {"compile_s", "ms"} or {"error"}."""
    job = json.dumps({"model": name, "threads": threads, "repeat": repeat})
    try:
        done = subprocess.run(
            [sys.executable, __file__, "--compile-worker", job], capture_output=True, text=True, timeout=timeout_s
        )
    except subprocess.TimeoutExpired:
        return {"error": f"torch.compile did not finish within {timeout_s:.0f} s"}
    if done.returncode != 0:
        lines = done.stderr.strip().splitlines()
        return {"error": "torch.compile failed: " + (lines[-1][:300] if lines else f"exit {done.returncode}")}
    return json.loads(done.stdout.strip().splitlines()[-1])


def _compile_worker(job: dict[str, Any]) -> None:
    import torch

    from fisheye_infer.export.exporter import verification_frames
    from fisheye_infer.runtime.artifact import read_meta

    torch.set_num_threads(job["threads"])
    files = model_files(job["model"])
    images = verification_frames(read_meta(files.fp32).rig, 1)
    x, v = torch.from_numpy(images), torch.ones(images.shape[:2], dtype=torch.bool)
    compiled = torch.compile(torch_model(files))
    with torch.inference_mode():
        t0 = time.perf_counter()
        compiled(x, v)
        compile_s = time.perf_counter() - t0
        timing = harness.measure(lambda: compiled(x, v), job["repeat"])
    print(json.dumps({"compile_s": compile_s, "ms": list(timing.values)}))


def _matmul_model(kind: str, n: int) -> bytes:
    from onnx import TensorProto, helper

    if kind == "fp32":
        types = (TensorProto.FLOAT, TensorProto.FLOAT, TensorProto.FLOAT)
        node = helper.make_node("MatMul", ["a", "b"], ["y"])
    else:  # u8 x s8 -> s32, what QDQ convolutions become
        types = (TensorProto.UINT8, TensorProto.INT8, TensorProto.INT32)
        node = helper.make_node("MatMulInteger", ["a", "b"], ["y"])
    a, b, y = (helper.make_tensor_value_info(name, t, [n, n]) for name, t in zip("aby", types))
    graph = helper.make_graph([node], "gemm", [a, b], [y])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)], ir_version=10).SerializeToString()


def gemm_peak(threads: int, n: int, repeat: int) -> dict[str, float]:
    """GFLOP/s of square matrix products: numpy, PyTorch, ONNX Runtime MatMul (fp32) and MatMulInteger (int8)."""
    import torch

    from fisheye_infer.runtime.session import open_session, session_options

    rng = np.random.default_rng(0)
    a, b = rng.standard_normal((n, n), np.float32), rng.standard_normal((n, n), np.float32)
    torch.set_num_threads(threads)
    ta, tb = torch.from_numpy(a), torch.from_numpy(b)
    fns: dict[str, Callable[[], object]] = {"numpy fp32": lambda: a @ b, "PyTorch fp32": lambda: ta @ tb}
    ints = {"a": rng.integers(0, 255, (n, n), dtype=np.uint8), "b": rng.integers(-127, 127, (n, n), dtype=np.int8)}
    for kind, feeds in (("fp32", {"a": a, "b": b}), ("int8", ints)):
        sess = open_session(_matmul_model(kind, n), session_options(threads), ["CPUExecutionProvider"], "GEMM")
        fns[f"ONNX Runtime {kind}"] = harness.session_call(sess, feeds)
    for fn in fns.values():  # first calls allocate
        fn()
    return {name: 2.0 * n**3 / t.median / 1e6 for name, t in harness.alternate(fns, repeat, warmup=0).items()}


def count_flops(onnx_path: Path) -> dict[str, float]:
    """Multiply-add GFLOP (2 per MAC) of Conv, ConvTranspose, MatMul and Gemm at batch 1, from the graph.

    Shapes come from one ONNX Runtime run with those nodes' outputs exposed (exact, where the graph's
    shapes are symbolic too); weights from the initializers.
    """
    import onnx
    import onnxruntime as ort

    from fisheye_infer.export.graph_stages import name_nodes

    model = onnx.load(str(onnx_path))
    name_nodes(model)
    inits = {i.name: list(i.dims) for i in model.graph.initializer}
    ops = [n for n in model.graph.node if n.op_type in ("Conv", "ConvTranspose", "MatMul", "Gemm")]
    wanted = list(dict.fromkeys([n.output[0] for n in ops] + [n.input[0] for n in ops if n.input[0] not in inits]))
    known = {o.name for o in model.graph.output} | {i.name for i in model.graph.input}
    model.graph.output.extend(
        onnx.helper.make_tensor_value_info(w, onnx.TensorProto.FLOAT, None) for w in wanted if w not in known
    )
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
            total["Conv"] += 2.0 * np.prod(out) * int(np.prod(inits[n.input[1]][1:]))
        elif n.op_type == "ConvTranspose":
            total["ConvTranspose"] += 2.0 * np.prod(shapes[n.input[0]]) * int(np.prod(inits[n.input[1]][1:]))
        else:
            a = shapes.get(n.input[0]) or inits[n.input[0]]
            total[n.op_type] += 2.0 * np.prod(out) * int(a[-1])
    total["total"] = sum(total.values())
    return {k: float(v) / 1e9 for k, v in total.items()}


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def service_overhead(
    onnx_path: Path, jpegs: dict[str, bytes], frame: list[np.ndarray], threads: int, rounds: int
) -> dict[str, Any]:
    """``POST /detect`` with JPEG parts against ``Detector.detect`` on arrays: same process, same Detector, in turns."""
    if harness.missing(["httpx", "uvicorn", "fastapi"]):
        return {"error": "the service is not installed (pip install -e '.[serve]')"}
    import httpx
    import uvicorn

    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.service.app import create_app
    from fisheye_infer.service.settings import ServiceSettings

    detector = Detector(onnx_path, threads=threads)
    port = _free_port()
    settings = ServiceSettings(model_path=onnx_path, port=port, threads=threads)
    app = create_app(settings, detector)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="error"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    try:
        for _ in range(200):
            if server.started:
                break
            time.sleep(0.05)
        files = {name: (f"{name}.jpg", data, "image/jpeg") for name, data in jpegs.items()}
        decode: list[float] = []
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=120) as client:

            def post() -> None:
                response = client.post("/detect", files=files)
                response.raise_for_status()
                decode.append(float(response.json()["timings_ms"]["decode"]))

            times = harness.alternate({"POST /detect": post, "Detector.detect": lambda: detector.detect(frame)}, rounds)
        return {"times": times, "decode": harness.Stats(tuple(decode))}
    except Exception as exc:
        return {"error": f"service measurement failed: {exc}"}
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def bench_rows(name: str, kind: str, result: dict[str, Any]) -> tuple[list[Row], list[Row], list[Row]]:
    """``bench_model``'s figures as rows: end to end by stage, graph stages, peak RSS."""
    parts = ("decode", "preprocess", "inference", "postprocess")
    runs = [
        {
            "model": name,
            "file": kind,
            "threads": r["threads"],
            "batch": r["batch"],
            "total median ms": r["total"]["median"],
            "total p90 ms": r["total"]["p90"],
            **{f"{k} ms": r[k]["median"] for k in parts},
            "frames/s": r["fps"],
        }
        for r in result["runs"]
    ]
    stages = [
        {"model": name, "file": kind, "threads": int(t), "stage": stage, "median ms": s["median"], "p90 ms": s["p90"]}
        for t, st in result["stages"].items()
        for stage, s in st.items()
    ]
    rss = [
        {"model": name, "file": kind, "threads": int(t), "peak RSS MB": mb} for t, mb in result["peak_rss_mb"].items()
    ]
    return runs, stages, rss


def measure_model(name: str, args: argparse.Namespace, gemm_best: float, tables: dict[str, list[Row]]) -> None:
    """Every figure of one model, appended to ``tables``."""
    from fisheye_infer.export.exporter import verification_frames
    from fisheye_infer.export.graph_stages import time_stages
    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.tools.bench import bench_model

    files = model_files(name, _progress)
    t = args.ratio_threads
    meta, int8_meta = read_meta(files.fp32), read_meta(files.int8)
    images = verification_frames(meta.rig, 1)
    times, skipped = runtimes(files, images, t, args.rounds, args.repeat)
    graph = times["ONNX Runtime fp32, graph"].median
    for runtime, stats in times.items():
        tables[RUNTIMES].append(
            {
                "model": name,
                "runtime": runtime,
                "threads": t,
                **stats.row(),
                "relative to the ONNX Runtime graph": stats.median / graph,
            }
        )
    if args.compile:
        _progress(f"{name}: torch.compile (child process)")
        compiled = torch_compile(name, t, args.rounds * args.repeat)
        if "error" in compiled:
            skipped.append({"model": name, "reference": "torch.compile", "reason": compiled["error"]})
        else:
            stats = harness.Stats(tuple(compiled["ms"]))
            tables[COMPILED].append(
                {
                    "model": name,
                    "threads": t,
                    "compile s": compiled["compile_s"],
                    **stats.row(),
                    "relative to the ONNX Runtime graph": stats.median / graph,
                }
            )
    flops = count_flops(files.fp32)
    width, height = meta.image_size
    bound = flops["total"] / gemm_best * 1e3
    tables[MODELS].append(
        {
            "model": name,
            "architecture": meta.architecture,
            "input": f"{len(meta.cameras)} x {width}x{height}",
            **{f"{k} GFLOP": v for k, v in flops.items()},
            "FLOP-bound ms": bound,
            "graph ms / FLOP-bound ms": graph / bound,
            "int8 top-50 kept (its own check)": int8_meta.parity.top_matched_fraction,
        }
    )
    for kind, path, batches, stages in (("fp32", files.fp32, args.batch, time_stages), ("int8", files.int8, [1], None)):
        result = bench_model(path, args.threads, batches, args.repeat, 1, stages=stages, progress=_progress)
        for title, rows in zip(BENCH, bench_rows(name, kind, result)):
            tables[title] += rows
    if args.service:
        jpegs = {
            cam: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes()
            for cam, image in zip(meta.cameras, images[0])
        }
        svc = service_overhead(files.fp32, jpegs, list(images[0]), t, args.rounds * args.repeat)
        if "error" in svc:
            skipped.append({"model": name, "reference": "service", "reason": svc["error"]})
        else:
            post, direct = svc["times"]["POST /detect"].median, svc["times"]["Detector.detect"].median
            tables[SERVICE].append(
                {
                    "model": name,
                    "threads": t,
                    "POST /detect median ms": post,
                    "Detector.detect median ms": direct,
                    "overhead": post / direct - 1,
                    "JPEG decode median ms": svc["decode"].median,
                }
            )
    tables[SKIPPED] += skipped


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(
        __file__, __doc__, quick="the compact model, 2 threads, batch 1, fewer rounds, smaller GEMM, no torch.compile"
    )
    p = bench.parser
    p.add_argument(
        "--models",
        help=f"comma-separated, of {', '.join(NAMES)} (default fisheye-bevdet,fisheye-petr; with --quick: compact)",
    )
    p.add_argument("--threads", default="1,2", help="thread counts for fisheye-infer bench (default 1,2)")
    p.add_argument("--batch", default="1,2,4", help="batch sizes for fisheye-infer bench (default 1,2,4)")
    p.add_argument("--ratio-threads", type=int, default=2, help="threads for the runtimes timed in turns (default 2)")
    p.add_argument("--rounds", type=int, default=5, help="rounds of the runtimes in turns (default 5)")
    p.add_argument("--repeat", type=int, default=3, help="timed calls per runtime per round (default 3)")
    p.add_argument("--gemm-size", type=int, default=2048, help="side of the GEMM matrices (default 2048)")
    p.add_argument("--no-compile", dest="compile", action="store_false", help="leave torch.compile out")
    p.add_argument("--no-service", dest="service", action="store_false", help="leave the service overhead out")
    p.add_argument("--compile-worker", help=argparse.SUPPRESS)
    args = bench.parse(argv)
    if args.compile_worker:
        _compile_worker(json.loads(args.compile_worker))
        return 0
    if args.quick:
        args.threads, args.batch, args.rounds = "2", "1", 3
        args.compile, args.gemm_size = False, 1024
    args.models = args.models or ("compact" if args.quick else "fisheye-bevdet,fisheye-petr")
    args.threads = [int(x) for x in str(args.threads).split(",")]
    args.batch = [int(x) for x in str(args.batch).split(",")]
    gemm = gemm_peak(args.ratio_threads, args.gemm_size, args.rounds)
    tables: dict[str, list[Row]] = {title: [] for title in (RUNTIMES, COMPILED, MODELS, *BENCH, SERVICE, SKIPPED)}
    for name in args.models.split(","):
        measure_model(name, args, max(v for k, v in gemm.items() if k.endswith("fp32")), tables)
    tables["GEMM throughput"] = [
        {"kernel": k, "threads": args.ratio_threads, "size": args.gemm_size, "GFLOP/s": v} for k, v in gemm.items()
    ]
    bench.save(args, {title: rows for title, rows in tables.items() if rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
