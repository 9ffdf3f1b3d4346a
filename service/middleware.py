"""One pure ASGI middleware: the body size limit and the per-request metrics.

Pure ASGI (not ``BaseHTTPMiddleware``) so that the body is counted as it streams in and the
request is never buffered twice. A declared Content-Length over ``max_body_bytes`` is answered
413 at once, before any byte of the body is read; a chunked body is cut off with 413 as soon
as it crosses the limit. Requests whose client left before the answer are counted with
status 499.
"""

from __future__ import annotations

import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from fisheye_infer.service.errors import PayloadTooLarge, error_response
from fisheye_infer.service.metrics import ServiceMetrics, endpoint_label

__all__ = ["ServiceMiddleware"]


class ServiceMiddleware:
    """See the module docstring."""

    def __init__(self, app: ASGIApp, metrics: ServiceMetrics, max_body_bytes: int) -> None:
        self.app = app
        self.metrics = metrics
        self.max_body_bytes = max_body_bytes

    def _too_large(self, size: str) -> PayloadTooLarge:
        return PayloadTooLarge(f"body: {size} bytes, at most max_body_bytes={self.max_body_bytes}", field="body")

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        endpoint = endpoint_label(scope["path"])
        started = time.perf_counter()
        status: list[int] = []

        async def send_counted(message: Message) -> None:
            if message["type"] == "http.response.start":
                status.append(message["status"])
            await send(message)

        declared = dict(scope["headers"]).get(b"content-length")
        received = 0

        async def receive_limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_body_bytes:
                    raise self._too_large(f"more than {received}")
            return message

        try:
            if declared is not None and (not declared.isdigit() or int(declared) > self.max_body_bytes):
                await error_response(self._too_large(declared.decode("latin-1")))(scope, receive, send_counted)
            else:
                await self.app(scope, receive_limited, send_counted)
        except Exception:
            if not status:
                status.append(500)
            raise
        finally:
            code = str(status[0]) if status else "499"
            self.metrics.requests.labels(endpoint, code).inc()
            self.metrics.latency.labels(endpoint).observe(time.perf_counter() - started)
