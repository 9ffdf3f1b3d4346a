"""uvicorn with a graceful drain: the first SIGTERM/SIGINT stops new work, not work in flight.

    server = build_server(settings)       # or build_server(settings, app)
    server.run()                          # blocks; returns after the drain and shutdown

On the first signal (or ``request_drain()``, for embedding and tests) the service starts
draining: new requests get 503 with Retry-After while the listening socket stays open, streams
answer their frame in flight and close with 1001. When nothing is in flight, or after
``drain_timeout_s``, uvicorn's own shutdown runs (lifespan: the workers stop). A second signal
skips the wait (uvicorn's behaviour: a second Ctrl-C forces the exit).

Limits set here, at the socket: ``max_connections`` (uvicorn's ``limit_concurrency``: beyond it
new requests get uvicorn's plain 503), the header deadline (``edge.py``) and uvicorn's keep-alive
timeout for idle connections. Only uvicorn's h11 protocol is used, whatever else is installed,
so these limits hold the same everywhere.
"""

from __future__ import annotations

import logging
import signal
import time
from types import FrameType

import uvicorn
from fastapi import FastAPI

from fisheye_infer.service.app import create_app
from fisheye_infer.service.edge import header_timeout_protocol
from fisheye_infer.service.settings import ServiceSettings
from fisheye_infer.service.state import Service

__all__ = ["DrainingServer", "build_server"]

log = logging.getLogger("fisheye_infer.service")


class DrainingServer(uvicorn.Server):
    """See the module docstring."""

    def __init__(self, config: uvicorn.Config, service: Service) -> None:
        super().__init__(config)
        self.service = service
        self._drain_requested = False
        self._drain_deadline: float | None = None

    def request_drain(self) -> None:
        """Start a graceful shutdown (thread-safe: only sets a flag the event loop reads)."""
        self._drain_requested = True

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        if self._drain_requested or self.service.settings.drain_timeout_s == 0:
            super().handle_exit(sig, frame)
            return
        log.info("received %s: draining", signal.Signals(sig).name)
        self.request_drain()

    async def on_tick(self, counter: int) -> bool:
        if self._drain_requested and not self.should_exit:
            now = time.monotonic()
            if self._drain_deadline is None:
                self.service.begin_drain()
                self._drain_deadline = now + self.service.settings.drain_timeout_s
            elif self.service.busy == 0 or now >= self._drain_deadline:
                if self.service.busy:
                    log.warning("drain_timeout_s passed with %d request(s) or stream(s) still open", self.service.busy)
                self.should_exit = True
        return await super().on_tick(counter)


def build_server(settings: ServiceSettings, app: FastAPI | None = None, log_level: str = "info") -> DrainingServer:
    """A uvicorn server for the service, with a graceful drain on the first SIGTERM or SIGINT.

    On the first signal (or ``request_drain()``, for embedding) new requests get 503 with Retry-After while work in
    flight finishes; after ``drain_timeout_s``, or when nothing is in flight, uvicorn shuts down. A second signal
    exits at once. ``max_connections``, ``header_timeout_s`` and ``max_body_bytes`` (WebSocket messages) are
    enforced at the socket; only uvicorn's h11 protocol is used.

    Args:
        settings (ServiceSettings): Where to listen and the limits
            ([`ServiceSettings`][fisheye_infer.service.settings.ServiceSettings]).
        app (FastAPI | None): The application; None builds it with
            [`create_app`][fisheye_infer.service.app.create_app]``(settings)``. A given app must come from
            ``create_app``.
        log_level (str): uvicorn's log level (``debug``, ``info``, ``warning``, ``error``, ``critical``).

    Returns:
        DrainingServer: A ``uvicorn.Server``; ``run()`` blocks until the drain and shutdown are done.
    """
    app = app if app is not None else create_app(settings)
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        log_level=log_level,
        lifespan="on",
        http=header_timeout_protocol(settings.header_timeout_s),
        limit_concurrency=settings.max_connections,
        timeout_keep_alive=5,
        ws_max_size=settings.max_body_bytes,  # a larger stream message closes the socket with 1009
        timeout_graceful_shutdown=max(1, int(settings.drain_timeout_s)),
        server_header=False,
    )
    return DrainingServer(config, app.state.service)
