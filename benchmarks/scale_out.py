"""Throughput of the scale-out paths on this machine: Ray Serve with one replica vs two, a plain loop vs Ray Data.

    .venv/bin/python benchmarks/scale_out.py artifacts/demo/fisheye_bevdet_random.onnx [--repeats 3] [--frames 12] [--duration 20]

Not a test: it measures, prints a table of medians and writes ``benchmarks/artifacts/scale_out.json``.
Everything stays on this machine: a local Ray with as many CPUs as the machine has, Ray Serve on
127.0.0.1, synthetic frames rendered for the model's own rig.

- Ray Serve: ``--clients`` threads POST the same four JPEGs to ``/detect`` for ``--duration``
  seconds; frames answered per second. One replica gets every CPU as ONNX Runtime threads; two
  replicas get an equal share each.
- Batch: ``--frames`` synthetic frames (Fisheye3DOD layout). The plain loop is one ``Detector``
  with every CPU as threads calling ``detect`` frame by frame; Ray Data is ``detect_frames`` with
  one actor per CPU (one thread each). Both timings include loading the model(s).

Runs alternate between the configurations, so load from elsewhere hits them alike.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np

from fisheye_infer.artifact import read_meta
from fisheye_infer.batch import BatchOptions, dataset_frames, detect_frames
from fisheye_infer.cpu import cpu_info
from fisheye_infer.detector import Detector
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.service.settings import ServiceSettings
from fisheye_infer.synth import Renderer, random_scene, synthesize


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
    runs: dict[str, list[float]] = {"serve_1_replica": [], "serve_2_replicas": []}
    settings = ServiceSettings(model_path=model, queue_size=16, max_body_bytes=64 * 1024 * 1024, request_timeout_s=300)
    for repeat in range(args.repeats):
        for key, replicas in (("serve_1_replica", 1), ("serve_2_replicas", 2)):
            options = RayServeOptions(replicas=replicas, cpus_per_replica=cpus / replicas, max_batch_size=args.clients, batch_wait_ms=10)
            serve.run(build_app(settings, options), name="bench", route_prefix="/")
            load(url, files, args.clients, min(args.duration, 10))  # warm: first batches, allocator growth
            runs[key].append(load(url, files, args.clients, args.duration))
            print(f"  [{repeat + 1}/{args.repeats}] {key}: {runs[key][-1]:.3f} frames/s", file=sys.stderr)
            serve.delete("bench")
    serve.shutdown()
    return runs


def batch_runs(model: Path, cpus: int, root: Path, args: argparse.Namespace) -> dict[str, list[float]]:
    frames = dataset_frames(Fisheye3DOD(root, "val"))
    runs: dict[str, list[float]] = {"plain_loop": [], "ray_data": []}

    def plain() -> float:
        t0 = time.perf_counter()
        detector = Detector(model, threads=cpus)
        for _, files in frames:
            detector.detect(files)
        return len(frames) / (time.perf_counter() - t0)

    def ray_data() -> float:
        result = detect_frames(model, frames, BatchOptions(batch_size=2, concurrency=cpus, cpus_per_actor=1))
        assert not result.failed, result.failed
        return result.frames_per_second

    steps: tuple[tuple[str, Callable[[], float]], ...] = (("plain_loop", plain), ("ray_data", ray_data))
    for repeat in range(args.repeats):
        for key, run in steps:
            runs[key].append(run())
            print(f"  [{repeat + 1}/{args.repeats}] {key}: {runs[key][-1]:.3f} frames/s", file=sys.stderr)
    return runs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", type=Path, help="ONNX file written by fisheye-infer export")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--frames", type=int, default=12, help="synthetic frames for the batch comparison")
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of load per Ray Serve run")
    parser.add_argument("--clients", type=int, default=4, help="concurrent HTTP clients (also the batch size)")
    parser.add_argument("--only", choices=("serve", "batch"), help="run one of the two comparisons")
    parser.add_argument("--out", type=Path, default=Path("benchmarks/artifacts/scale_out.json"))
    args = parser.parse_args()

    import ray

    cpus = os.cpu_count() or 1
    meta = read_meta(args.model)
    ray.init(num_cpus=cpus, include_dashboard=False, _node_ip_address="127.0.0.1", configure_logging=False, log_to_driver=False)
    ray.data.DataContext.get_current().enable_progress_bars = False
    runs: dict[str, Any] = {}
    try:
        if args.only in (None, "serve"):
            frame = Renderer(texture_seed=1).render(meta.rig, random_scene(np.random.default_rng(1)))
            files = [(c, (f"{c}.jpg", cv2.imencode(".jpg", frame[c], [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes(), "image/jpeg")) for c in meta.cameras]
            print("Ray Serve, one replica vs two:", file=sys.stderr)
            runs |= serve_runs(args.model, cpus, files, args)
        if args.only in (None, "batch"):
            with tempfile.TemporaryDirectory() as tmp:
                print(f"rendering {args.frames} synthetic frames ...", file=sys.stderr)
                synthesize(meta.rig, tmp, frames=args.frames, seed=7)
                print("plain loop vs Ray Data:", file=sys.stderr)
                runs |= batch_runs(args.model, cpus, Path(tmp), args)
    finally:
        ray.shutdown()
    medians = {k: statistics.median(v) for k, v in runs.items()}
    doc = {"model": str(args.model), "architecture": meta.architecture, "image_size": meta.image_size, "cpu": cpu_info().label, "cpus": cpus,
           "ray": ray.__version__, "repeats": args.repeats, "frames": args.frames, "duration_s": args.duration, "clients": args.clients,
           "runs_frames_per_s": runs, "median_frames_per_s": medians}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1))
    print(f"\n{meta.architecture}, {len(meta.cameras)} x {meta.image_size[0]}x{meta.image_size[1]}, {cpus} x {doc['cpu']}, medians of {args.repeats}:")
    for key, value in medians.items():
        print(f"  {key:18s} {value:.3f} frames/s")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
