"""Graceful shutdown: in-flight requests finish, new ones get 503 while draining, then the server
exits; and ``fisheye-infer serve`` does the same on SIGTERM."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import pytest
from service_live import LiveServer, multipart, settings_for
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from fisheye_infer.runtime.detector import Detector


def _batch(images: dict[str, bytes], frames: int) -> list:
    return [part for i in range(frames) for part in multipart(images, f"{i}.")]


def test_drain_finishes_in_flight_and_refuses_new(
    small_model: Path, detector: Detector, images: dict[str, bytes]
) -> None:
    live = LiveServer(settings_for(small_model, queue_size=4), detector).start()
    with ThreadPoolExecutor(2) as pool, connect(live.ws_url) as ws:
        in_flight = [
            pool.submit(httpx.post, f"{live.url}/detect/batch", files=_batch(images, 8), timeout=30) for _ in range(2)
        ]
        assert live.wait_metric("fisheye_inflight", lambda v: v >= 2) == 2  # two batches of 8 frames (~0.7 s each)
        live.server.request_drain()
        deadline = time.monotonic() + 5
        while httpx.get(f"{live.url}/readyz").status_code != 503 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert httpx.get(f"{live.url}/readyz").json()["status"] == "draining"
        assert httpx.get(f"{live.url}/healthz").status_code == 200  # the process is still up
        refused = httpx.post(f"{live.url}/detect", files=multipart(images), timeout=10)
        assert refused.status_code == 503 and refused.headers["Retry-After"] == "1"
        assert "shutting down" in refused.json()["error"]
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=10)
        assert closed.value.rcvd is not None and closed.value.rcvd.code == 1001
        finished = [f.result() for f in in_flight]
    assert [r.status_code for r in finished] == [200, 200]
    assert all(len(r.json()["frames"]) == 8 for r in finished)
    live.thread.join(15)
    assert not live.thread.is_alive()
    with socket.socket() as probe:
        assert probe.connect_ex(("127.0.0.1", live.port)) != 0  # the port is closed


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_cli_serve_drains_on_sigterm(small_model: Path, images: dict[str, bytes]) -> None:
    port = _free_port()
    env = {
        **os.environ,
        "FISHEYE_QUEUE_SIZE": "3",
        "FISHEYE_DRAIN_TIMEOUT_S": "10",
        "FISHEYE_PROVIDERS": "CPUExecutionProvider",
    }
    command = [
        sys.executable,
        "-m",
        "fisheye_infer",
        "serve",
        str(small_model),
        "--port",
        str(port),
        "--threads",
        "1",
        "--log-level",
        "info",
    ]
    process = subprocess.Popen(command, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        url = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while True:
            try:
                if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            assert process.poll() is None and time.monotonic() < deadline, "server did not come up"
            time.sleep(0.1)
        model = httpx.get(f"{url}/model").json()
        assert model["limits"]["queue_size"] == 3 and model["providers"] == [
            "CPUExecutionProvider"
        ]  # from FISHEYE_QUEUE_SIZE, FISHEYE_PROVIDERS
        result: list[httpx.Response] = []
        sender = threading.Thread(
            target=lambda: result.append(httpx.post(f"{url}/detect/batch", files=_batch(images, 8), timeout=30))
        )
        sender.start()
        time.sleep(0.3)
        process.send_signal(signal.SIGTERM)
        sender.join(30)
        output, _ = process.communicate(timeout=30)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert result and result[0].status_code == 200, output
    assert process.returncode == 0, output
    assert "draining" in output and "Finished server process" in output


def test_serve_reports_a_missing_model_and_exits_1(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "fisheye_infer", "serve", str(tmp_path / "none.onnx"), "--port", "0"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1 and "none.onnx: no such file" in result.stderr


@pytest.mark.parametrize(
    "flags, env, words",
    [
        (["--queue-size", "0"], {}, "queue_size: Input should be greater than or equal to 1"),
        ([], {"FISHEYE_API_KEY": "short"}, "api_key: expected at least 16 characters, got 5"),
        (["--microbatch-max-size", "9"], {}, "microbatch_max_size: 9 exceeds max_batch_frames 8"),
        (
            ["--providers", "NoSuchExecutionProvider"],
            {},
            "providers: NoSuchExecutionProvider not offered by the installed onnxruntime",
        ),
    ],
)
def test_serve_refuses_bad_settings_by_name(flags: list[str], env: dict[str, str], words: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "fisheye_infer", "serve", "x.onnx", *flags],
        env={**os.environ, **env},
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 1 and words in result.stderr, result.stderr
