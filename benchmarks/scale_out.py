"""Throughput of the scale-out paths here: Ray Serve with one replica against two, a plain loop against Ray Data.

    python benchmarks/scale_out.py compact [--repeats 3] [--frames 12] [--duration 20] [--quick]

Everything stays on this machine: a local Ray with as many CPUs as the machine has, Ray Serve on
127.0.0.1, synthetic frames rendered for the model's own rig. The configurations run in turns.

- Ray Serve: ``--clients`` threads POST the same JPEGs to ``/detect`` for ``--duration`` seconds;
  frames answered per second. One replica gets every CPU as ONNX Runtime threads; two replicas
  get an equal share each.
- Batch: ``--frames`` synthetic frames (Fisheye3DOD layout). The plain loop is one ``Detector``
  with every CPU as threads calling ``detect`` frame by frame; Ray Data is ``detect_frames`` with
  one actor per CPU (one thread each). Both timings include loading the model(s).
"""

from __future__ import annotations

import argparse
import os
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import harness
import httpx
import numpy as np
from model_files import MODEL_HELP, model_path

from fisheye_infer.deploy.ray_batch import BatchOptions, dataset_frames, detect_frames
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene, synthesize
from fisheye_infer.service.settings import ServiceSettings


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def load(url: str, files: list[tuple[str, tuple[str, bytes, str]]], clients: int, duration: float) -> float:
    """Frames answered per second by ``clients`` threads posting for ``duration`` seconds."""
    done, errors = [0], []
    deadline = time.monotonic() + duration

    def client() -> None:
        with httpx.Client(timeout=120) as http:
            while time.monotonic() < deadline:
                response = http.post(f"{url}/detect", files=files)
                if response.status_code == 200:
                    done[0] += 1
                else:
                    errors.append(response.status_code)

    t0 = time.monotonic()
    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        print(f"  non-200 answers: {sorted(set(errors))} x{len(errors)}", file=sys.stderr)
    return done[0] / (time.monotonic() - t0)


def serve_runs(model: Path, cpus: int, files: list, args: argparse.Namespace) -> dict[str, list[float]]:
    from ray import serve

    from fisheye_infer.service.ray_serve import RayServeOptions, build_app

    port = free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    url = f"http://127.0.0.1:{port}"
    settings = ServiceSettings(model_path=model, queue_size=16, max_body_bytes=64 * 1024 * 1024, request_timeout_s=300)

    def replicas(count: int) -> Callable[[], float]:
        def run() -> float:
            options = RayServeOptions(
                replicas=count, cpus_per_replica=cpus / count, max_batch_size=args.clients, batch_wait_ms=10
            )
            serve.run(build_app(settings, options), name="bench", route_prefix="/")
            load(url, files, args.clients, min(args.duration, 10))  # warm: first batches, allocator growth
            try:
                return load(url, files, args.clients, args.duration)
            finally:
                serve.delete("bench")

        return run

    try:
        return harness.in_turns(
            {"Ray Serve, 1 replica": replicas(1), "Ray Serve, 2 replicas": replicas(2)}, args.repeats
        )
    finally:
        serve.shutdown()


def batch_runs(model: Path, cpus: int, root: Path, args: argparse.Namespace) -> dict[str, list[float]]:
    frames = dataset_frames(Fisheye3DOD(root, "val"))

    def plain() -> float:
        t0 = time.perf_counter()
        detector = Detector(model, threads=cpus)
        for _, files in frames:
            detector.detect(files)
        return len(frames) / (time.perf_counter() - t0)

    def ray_data() -> float:
        result = detect_frames(model, frames, BatchOptions(batch_size=2, concurrency=cpus, cpus_per_actor=1))
        if result.failed:
            raise RuntimeError(f"Ray Data: frames failed: {result.failed}")
        return result.frames_per_second

    return harness.in_turns({"plain loop, one Detector": plain, "Ray Data, one actor per CPU": ray_data}, args.repeats)


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="2 repeats, 6 frames, 5 s of load")
    p = bench.parser
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--frames", type=int, default=12, help="synthetic frames for the batch comparison")
    p.add_argument("--duration", type=float, default=20.0, help="seconds of load per Ray Serve run")
    p.add_argument("--clients", type=int, default=4, help="concurrent HTTP clients (also the batch size)")
    p.add_argument("--only", choices=("serve", "batch"), help="run one of the two comparisons")
    args = bench.parse(argv)
    if args.quick:
        args.repeats, args.frames, args.duration = 2, 6, 5.0

    import ray

    cpus = os.cpu_count() or 1
    model = model_path(args.model)
    meta = read_meta(model)
    ray.init(
        num_cpus=cpus,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        configure_logging=False,
        log_to_driver=False,
    )
    ray.data.DataContext.get_current().enable_progress_bars = False
    runs: dict[str, list[float]] = {}
    try:
        if args.only in (None, "serve"):
            frame = Renderer(texture_seed=1).render(meta.rig, random_scene(np.random.default_rng(1)))
            quality = [cv2.IMWRITE_JPEG_QUALITY, 95]
            jpegs = {c: cv2.imencode(".jpg", frame[c], quality)[1].tobytes() for c in meta.cameras}
            files = [(c, (f"{c}.jpg", data, "image/jpeg")) for c, data in jpegs.items()]
            runs |= serve_runs(model, cpus, files, args)
        if args.only in (None, "batch"):
            with tempfile.TemporaryDirectory() as tmp:
                synthesize(meta.rig, tmp, frames=args.frames, seed=7)
                runs |= batch_runs(model, cpus, Path(tmp), args)
    finally:
        ray.shutdown()
    width, height = meta.image_size
    described = f"{meta.architecture}, {len(meta.cameras)} x {width}x{height}"
    rows = [
        {"configuration": name, "model": described, "CPUs": cpus, **harness.Stats(tuple(values)).row("frames/s")}
        for name, values in runs.items()
    ]
    bench.save(args, {f"Throughput, Ray {ray.__version__}": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
