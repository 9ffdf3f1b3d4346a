"""What a local ``fisheye-infer serve`` sustains under load for a fixed time.

    python benchmarks/load_service.py compact [--duration 10 --concurrency 4 --stream-fps 30] [--quick]

The server runs as a subprocess on a free 127.0.0.1 port (loopback only); one synthetic frame of
the model's own rig is sent in two phases of ``--duration`` seconds each:

1. ``/detect``: ``--concurrency`` clients post the frame (multipart JPEG) back to back;
2. ``/stream``: one WebSocket client sends the frame at ``--stream-fps`` while reading answers
   (latest frame wins, so at rates above the model's some frames are dropped by design).

Per phase: throughput, p50/p99 latency, status counts and dropped frames, and the server's peak
resident memory (VmHWM) after it. Each phase lasts at most 120 s; the server is stopped with
SIGTERM at the end.
"""

from __future__ import annotations

import collections
import json
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import cv2
import harness
import httpx
import numpy as np
from model_files import MODEL_HELP, model_path
from websockets.sync.client import connect

from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.scenes.render import Renderer, random_scene
from fisheye_infer.service.protocol import encode_frame

HOST = "127.0.0.1"
MAX_SECONDS = 120.0


def _free_port() -> int:
    with socket.socket() as s:
        s.bind((HOST, 0))
        return s.getsockname()[1]


def _peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _frame(model: Path) -> dict[str, bytes]:
    rig = read_meta(model).rig
    images = Renderer(texture_seed=1).render(rig, random_scene(np.random.default_rng(0)))
    return {
        name: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 90])[1].tobytes() for name, image in images.items()
    }


def _percentiles(latencies: list[float]) -> dict[str, float | None]:
    if not latencies:
        return {"p50 ms": None, "p99 ms": None}
    p50, p99 = np.percentile(np.asarray(latencies) * 1e3, [50, 99])
    return {"p50 ms": float(p50), "p99 ms": float(p99)}


def detect_phase(url: str, frame: dict[str, bytes], duration: float, concurrency: int) -> dict[str, Any]:
    files = [(name, (f"{name}.jpg", data, "image/jpeg")) for name, data in frame.items()]
    latencies: list[float] = []
    statuses: collections.Counter[str] = collections.Counter()
    lock = threading.Lock()
    stop_at = time.monotonic() + duration

    def client() -> None:
        with httpx.Client(base_url=url, timeout=30) as http:
            while time.monotonic() < stop_at:
                t0 = time.perf_counter()
                try:
                    status = str(http.post("/detect", files=files).status_code)
                except httpx.HTTPError as exc:
                    status = type(exc).__name__
                with lock:
                    statuses[status] += 1
                    if status == "200":
                        latencies.append(time.perf_counter() - t0)

    threads = [threading.Thread(target=client) for _ in range(concurrency)]
    started = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - started
    ok = statuses.get("200", 0)
    return {
        "phase": f"/detect, {concurrency} clients",
        "seconds": elapsed,
        "frames/s": ok / elapsed,
        **_percentiles(latencies),
        "sent": sum(statuses.values()),
        "answered": ok,
        "refused or failed": sum(statuses.values()) - ok,
        "dropped": None,
        "statuses": [f"{k} x{v}" for k, v in sorted(statuses.items())],
    }


def stream_phase(ws_url: str, frame: dict[str, bytes], duration: float, fps: float) -> dict[str, Any]:
    sent_at: dict[int, float] = {}
    latencies: list[float] = []
    counts: collections.Counter[str] = collections.Counter()
    with connect(ws_url, max_size=None) as ws:
        done = threading.Event()

        def receiver() -> None:
            while not done.is_set() or len(sent_at) > 0:
                try:
                    answer = json.loads(ws.recv(timeout=5))
                except TimeoutError:
                    return
                counts["dropped"] += len(answer["dropped"])
                for frame_id in answer["dropped"]:
                    sent_at.pop(frame_id, None)
                t0 = sent_at.pop(answer["frame_id"], None)
                counts[answer["kind"]] += 1
                if answer["kind"] == "result" and t0 is not None:
                    latencies.append(time.perf_counter() - t0)

        reader = threading.Thread(target=receiver)
        reader.start()
        started = time.perf_counter()
        frame_id = 0
        while time.perf_counter() - started < duration:
            sent_at[frame_id] = time.perf_counter()
            ws.send(encode_frame(frame_id, frame))
            frame_id += 1
            time.sleep(max(0.0, started + frame_id / fps - time.perf_counter()))
        done.set()
        reader.join(30)
        elapsed = time.perf_counter() - started
    return {
        "phase": f"/stream, {fps:g} frames/s sent",
        "seconds": elapsed,
        "frames/s": counts["result"] / elapsed,
        **_percentiles(latencies),
        "sent": frame_id,
        "answered": counts["result"],
        "refused or failed": counts["error"],
        "dropped": counts["dropped"],
    }


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="5 s per phase")
    p = bench.parser
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--duration", type=float, default=10.0, help=f"seconds per phase (at most {MAX_SECONDS:g})")
    p.add_argument("--concurrency", type=int, default=4, help="/detect clients")
    p.add_argument("--stream-fps", type=float, default=30.0)
    p.add_argument("--threads", type=int, help="server: ONNX Runtime intra-op threads")
    p.add_argument("--workers", type=int, default=1, help="server: inference threads")
    p.add_argument("--queue-size", type=int, default=8)
    p.add_argument("--microbatch", type=int, default=1, help="server: microbatch_max_size (1: off)")
    args = bench.parse(argv)
    if args.quick:
        args.duration = 5.0
    duration = min(args.duration, MAX_SECONDS)
    model_file = model_path(args.model)

    port = _free_port()
    command = [
        sys.executable,
        "-m",
        "fisheye_infer",
        "serve",
        str(model_file),
        "--host",
        HOST,
        "--port",
        str(port),
        "--workers",
        str(args.workers),
        "--queue-size",
        str(args.queue_size),
        "--microbatch-max-size",
        str(args.microbatch),
        "--log-level",
        "warning",
    ]
    if args.threads:
        command += ["--threads", str(args.threads)]
    server = subprocess.Popen(command)
    url = f"http://{HOST}:{port}"
    try:
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if server.poll() is not None or time.monotonic() > deadline:
                print("the server did not come up", file=sys.stderr)
                return 1
            time.sleep(0.2)
        info = httpx.get(f"{url}/model").json()
        frame = _frame(model_file)
        size = info["image_size"]
        model = {
            "model": info["model_id"],
            "cameras": len(info["cameras"]),
            "image": f"{size['width']}x{size['height']}",
            "frame kB (JPEG)": sum(map(len, frame.values())) / 1024,
            "idle peak RSS MB": _peak_rss_mb(server.pid),
        }
        phases = [detect_phase(url, frame, duration, args.concurrency)]
        phases[-1]["server peak RSS MB"] = _peak_rss_mb(server.pid)
        phases.append(stream_phase(f"ws://{HOST}:{port}/stream", frame, duration, args.stream_fps))
        phases[-1]["server peak RSS MB"] = _peak_rss_mb(server.pid)
    finally:
        server.send_signal(signal.SIGTERM)
        try:
            server.wait(30)
        except subprocess.TimeoutExpired:
            server.kill()
    bench.save(args, {"Model and frame": [model], "Load phases": phases})
    return 0


if __name__ == "__main__":
    sys.exit(main())
