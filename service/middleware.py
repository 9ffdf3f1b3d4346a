"""One pure ASGI middleware at the service's edge: request framing, the body size limit, metrics.

Pure ASGI (not ``BaseHTTPMiddleware``) so that the body is counted as it streams in and the
request is never buffered twice.

- A request with both Content-Length and Transfer-Encoding is refused with 400 and its
  connection closed (RFC 9112 section 6.3): the two framings disagree about where the body
  ends, which is how a second, smuggled request hides in the first one's body.
- A declared Content-Length over ``max_body_bytes`` is answered 413; a chunked body is cut
  off with 413 as soon as it crosses the limit. Before answering, the rest of the body is read
  and discarded for a short, bounded while (``LINGER_BYTES``, ``LINGER_S``), as proxies do
  with a "lingering close": a client that writes its whole body before reading (urllib,
  requests) then reads the 413 instead of a connection reset. A client that asked
  ``Expect: 100-continue`` has sent nothing yet and gets the 413 at once. The connection is
  closed after the answer.
- Requests whose client left before the answer are counted with status 499.
"""

from __future__ import annotations

import asyncio
import time

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from fisheye_infer.service.errors import BadRequest, PayloadTooLarge, error_response
from fisheye_infer.service.metrics import ServiceMetrics, endpoint_label

__all__ = ["ServiceMiddleware", "LINGER_BYTES", "LINGER_S", "discard_body"]

LINGER_BYTES = 64 * 1024 * 1024  # at most this much of a refused body is read and thrown away ...
LINGER_S = 5.0  # ... for at most this long


async def discard_body(receive: Receive, limit_bytes: int = LINGER_BYTES, limit_s: float = LINGER_S) -> None:
    """Read and drop the rest of a request body, within the bounds (a refused upload's lingering close)."""
    deadline = time.monotonic() + limit_s
    read = 0
    while read <= limit_bytes:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return
        try:
            message = await asyncio.wait_for(receive(), remaining)
        except asyncio.TimeoutError:
            return
        if message["type"] != "http.request":
            return
        read += len(message.get("body", b""))
        if not message.get("more_body", False):
            return


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

        headers = dict(scope["headers"])
        declared = headers.get(b"content-length")
        waits_for_continue = headers.get(b"expect", b"").lower() == b"100-continue"
        received = 0

        async def receive_limited() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_body_bytes:
                    if message.get("more_body", False):
                        await discard_body(receive)
                    raise self._too_large(f"more than {received}")
            return message

        try:
            if declared is not None and b"transfer-encoding" in headers:
                refusal = BadRequest(
                    "Content-Length and Transfer-Encoding: both given, so the body's end is ambiguous; send one of "
                    "them (RFC 9112 section 6.3); the connection is closed",
                    field="Transfer-Encoding",
                )
                await error_response(refusal, close=True)(scope, receive, send_counted)
            elif declared is not None and (not declared.isdigit() or int(declared) > self.max_body_bytes):
                if not waits_for_continue:
                    await discard_body(receive)
                shown = declared.decode("latin-1")
                await error_response(self._too_large(shown if len(shown) <= 20 else shown[:20] + "..."))(
                    scope, receive, send_counted
                )
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
