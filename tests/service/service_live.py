"""A real uvicorn server in a thread for the service tests, and small request helpers."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import httpx

from fisheye_infer.runtime.detector import Detector
from fisheye_infer.service.app import create_app
from fisheye_infer.service.server import DrainingServer, build_server
from fisheye_infer.service.settings import ServiceSettings

API_KEY = "k" * 24
ORIGIN = "https://viewer.example"


@dataclass
class LiveServer:
    """A uvicorn server in a thread; ``url``/``ws_url`` point at it."""

    settings: ServiceSettings
    detector: Detector
    server: DrainingServer = field(init=False)
    port: int = field(init=False)
    thread: threading.Thread = field(init=False)

    def __post_init__(self) -> None:
        self.server = build_server(self.settings, create_app(self.settings, self.detector), log_level="warning")
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.bind(("127.0.0.1", 0))
        self.port = sock.getsockname()[1]
        self.thread = threading.Thread(
            target=self.server.run, kwargs={"sockets": [sock]}, name=f"uvicorn-{self.port}", daemon=True
        )

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def ws_url(self) -> str:
        return f"ws://127.0.0.1:{self.port}/stream"

    @property
    def service(self) -> Any:
        return self.server.service

    def start(self) -> LiveServer:
        self.thread.start()
        deadline = time.monotonic() + 30
        while not self.server.started:
            if not self.thread.is_alive() or time.monotonic() > deadline:
                raise RuntimeError(f"server on port {self.port} did not start")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(15)

    def metric(self, name: str, **labels: str) -> float:
        """One sample of /metrics (0 when absent)."""
        text = httpx.get(f"{self.url}/metrics", headers={"X-API-Key": API_KEY}).text
        want = name + ("{" + ",".join(f'{k}="{v}"' for k, v in labels.items()) + "}" if labels else "")
        for line in text.splitlines():
            if line.startswith(want + " "):
                return float(line.split()[-1])
        return 0.0

    def wait_metric(self, name: str, predicate: Any, timeout: float = 10.0, **labels: str) -> float:
        deadline = time.monotonic() + timeout
        while True:
            value = self.metric(name, **labels)
            if predicate(value) or time.monotonic() > deadline:
                return value
            time.sleep(0.05)


def serve(settings: ServiceSettings, detector: Detector) -> Iterator[LiveServer]:
    live = LiveServer(settings, detector).start()
    try:
        yield live
    finally:
        live.stop()


def multipart(
    images: dict[str, bytes], prefix: str = "", content_type: str = "image/png"
) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [(f"{prefix}{name}", (f"{name}.png", data, content_type)) for name, data in images.items()]


def settings_for(model: Any, **overrides: Any) -> ServiceSettings:
    base: dict[str, Any] = {
        "model_path": model,
        "threads": 1,
        "workers": 1,
        "queue_size": 2,
        "max_body_bytes": 1024 * 1024,
        "max_batch_frames": 8,
        "request_timeout_s": 20.0,
        "drain_timeout_s": 10.0,
    }
    return ServiceSettings(**{**base, **overrides})
