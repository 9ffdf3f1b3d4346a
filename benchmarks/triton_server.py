"""Requests per second and latency through a real Triton server, against ``POST /detect`` and an in-process Detector.

    python benchmarks/triton_server.py compact [--clients 4 --duration 10 --rounds 2] [--quick]

One synthetic frame of the model's rig (four JPEGs) is sent by ``--clients`` closed-loop client threads (each
sends, waits for the boxes, sends again) for ``--duration`` seconds after a warm-up, per configuration, the
configurations in turns (``--rounds`` times each; each runs alone on the machine):

- ``Detector``: one in-process ``Detector`` (every CPU as ONNX Runtime threads) shared by the client threads;
- ``POST /detect``: ``fisheye-infer serve`` (defaults; every CPU) as a subprocess on 127.0.0.1, multipart JPEGs;
- ``Triton HTTP`` and ``Triton gRPC``: the ``tritonserver`` of the nvidia-pytriton wheel serving the Python-backend
  repository (``fisheye-infer triton --backend python``: one instance, every CPU as ONNX Runtime threads, dynamic
  batching up to ``--clients`` frames), ``TritonDetector`` over each protocol (JPEGs decoded by the client).

Per configuration: frames per second and p50/p99 latency of the boxes, over all rounds.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import cv2
import harness
import httpx
import numpy as np
from model_files import MODEL_HELP, model_path

from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository
from fisheye_infer.deploy.triton.server import TritonServer, free_port
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene

HOST = "127.0.0.1"
WARMUP_S = 3.0


def closed_loop(make_call: Callable[[], Callable[[], None]], clients: int, duration: float) -> list[float]:
    """Latencies (s) of ``clients`` threads calling back to back for ``duration`` seconds."""
    latencies: list[float] = []
    lock = threading.Lock()
    stop_at = time.monotonic() + duration

    def client() -> None:
        call = make_call()
        while time.monotonic() < stop_at:
            t0 = time.perf_counter()
            call()
            with lock:
                latencies.append(time.perf_counter() - t0)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return latencies


@contextmanager
def detector_calls(model: Path, frame: dict[str, bytes]) -> Iterator[Callable[[], Callable[[], None]]]:
    detector = Detector(model, threads=os.cpu_count())
    yield lambda: lambda: _discard(detector.detect(frame))


@contextmanager
def service_calls(model: Path, frame: dict[str, bytes]) -> Iterator[Callable[[], Callable[[], None]]]:
    port = free_port()
    command = [sys.executable, "-m", "fisheye_infer", "serve", str(model), "--host", HOST, "--port", str(port)]
    server = subprocess.Popen([*command, "--log-level", "warning"])
    url = f"http://{HOST}:{port}"
    files = [(name, (f"{name}.jpg", data, "image/jpeg")) for name, data in frame.items()]
    try:
        deadline = time.monotonic() + 120
        while not _ready(f"{url}/readyz"):
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError("fisheye-infer serve did not come up")
            time.sleep(0.2)

        def make() -> Callable[[], None]:
            http = httpx.Client(base_url=url, timeout=60)
            return lambda: _discard(http.post("/detect", files=files).raise_for_status())

        yield make
    finally:
        server.send_signal(signal.SIGTERM)
        server.wait(30)


def _discard(_: object) -> None:
    """A call's answer, dropped once received."""


def _ready(url: str) -> bool:
    try:
        return httpx.get(url, timeout=1).status_code == 200
    except httpx.TransportError:
        return False


def triton_calls(protocol: str, clients: int) -> Callable[[Path, dict[str, bytes]], Any]:
    @contextmanager
    def calls(model: Path, frame: dict[str, bytes]) -> Iterator[Callable[[], Callable[[], None]]]:
        from fisheye_infer.deploy.triton import TritonDetector

        with tempfile.TemporaryDirectory() as repository:
            options = TritonOptions(name="model", backend="python", max_batch_size=clients, threads=os.cpu_count())
            write_repository(model, repository, options)
            with TritonServer(repository) as server:
                url = server.http_url if protocol == "http" else server.grpc_url
                detector = TritonDetector(url, "model", protocol=protocol)
                yield lambda: lambda: _discard(detector.detect(frame))

    return calls


def run(setup: Callable[[Path, dict[str, bytes]], Any], model: Path, frame: dict[str, bytes], args: Any) -> list:
    """One round of one configuration (started, warmed up, ``--duration`` seconds of load, stopped): latencies."""
    with setup(model, frame) as make_call:
        closed_loop(make_call, args.clients, WARMUP_S)
        return closed_loop(make_call, args.clients, args.duration)


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="1 round of 5 s")
    bench.parser.add_argument("model", help=MODEL_HELP)
    bench.parser.add_argument("--clients", type=int, default=4, help="closed-loop client threads")
    bench.parser.add_argument("--duration", type=float, default=10.0, help="seconds of load per round")
    bench.parser.add_argument("--rounds", type=int, default=2)
    args = bench.parse(argv)
    if args.quick:
        args.rounds, args.duration = 1, 5.0
    model = model_path(args.model)
    images = Renderer(texture_seed=1).render(read_meta(model).rig, random_scene(np.random.default_rng(0)))
    quality = [cv2.IMWRITE_JPEG_QUALITY, 90]
    frame = {name: cv2.imencode(".jpg", image, quality)[1].tobytes() for name, image in images.items()}
    setups = {
        "Detector (in process)": detector_calls,
        "POST /detect (fisheye-infer serve)": service_calls,
        "Triton HTTP (Python backend)": triton_calls("http", args.clients),
        "Triton gRPC (Python backend)": triton_calls("grpc", args.clients),
    }
    turns = {name: (lambda s=s: run(s, model, frame, args)) for name, s in setups.items()}
    rounds = harness.in_turns(turns, args.rounds)
    rows = []
    for name, latencies in rounds.items():
        every = np.concatenate([np.asarray(r) for r in latencies])
        p50, p99 = np.percentile(every * 1e3, [50, 99])
        seconds = args.duration * len(latencies)
        rows.append(
            {"path": name, "clients": args.clients, "frames/s": len(every) / seconds, "p50 ms": p50, "p99 ms": p99}
        )
    bench.save(args, {f"{args.model}: one frame, {args.clients} clients": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
