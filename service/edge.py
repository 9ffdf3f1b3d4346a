"""The connection edge: a request's headers must arrive within ``header_timeout_s``.

An ASGI application only sees a request once its headers are complete, so a client that sends
them one byte a second (slowloris) holds a connection for as long as it likes, unseen by the
app; uvicorn's keep-alive timer is reset by every byte. ``header_timeout_protocol`` returns
uvicorn's h11 protocol with one addition: from the moment a connection opens, and again after
each response, the client has ``header_timeout_s`` to complete the next request's headers.
When the time is up the client gets a 408 ``ErrorOut``; the connection is then half-closed and
whatever the client still sends is read and dropped for ``LINGER_S`` before the socket closes, so
that a slow but honest client reads the 408 instead of a connection reset.

Two answers that uvicorn gives without the app get the service's ``ErrorOut`` form here too:

- bytes that h11 cannot parse as a request (a malformed request line or header; on a kept-alive
  connection, the bytes after a body shorter than its Content-Length, which are read as the next
  request): 400 ``BadRequest``, field ``request``, and the connection is closed (uvicorn's own answer
  is the text "Invalid HTTP request received.");
- a client that half-closes its side of the connection before the body its Content-Length declares
  has arrived: 400 ``BadRequest``, field ``body``, instead of a close without an answer. A client that
  keeps the connection open and sends no more gets the 408 of ``body_timeout_s``.

Everything that needs the headers (the body limit, the Content-Length + Transfer-Encoding
refusal, the body's own deadline) is done in ASGI, in ``middleware.py``.
"""

from __future__ import annotations

import asyncio
import json
from typing import Any

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

__all__ = ["HeaderTimeoutProtocol", "header_timeout_protocol", "LINGER_S"]

LINGER_S = 2.0


def _answer(status: int, kind: str, field: str, error: str) -> bytes:
    """A complete ``ErrorOut`` response that closes the connection, written straight to the socket."""
    body = json.dumps({"error": error, "status": status, "type": kind, "field": field}).encode()
    phrase = {400: "Bad Request", 408: "Request Timeout"}[status]
    head = (
        f"HTTP/1.1 {status} {phrase}\r\ncontent-type: application/json\r\ncontent-length: {len(body)}\r\n"
        "connection: close\r\n\r\n"
    ).encode()
    return head + body


def _timeout_answer(seconds: float) -> bytes:
    return _answer(408, "RequestTimeout", "headers", f"headers: not received within header_timeout_s={seconds:g} s")


#: What a request h11 cannot parse is told (h11 does not say which byte; the reasons it can have are listed).
NOT_HTTP = (
    "request: not a valid HTTP/1.1 request (a malformed request line or header, or on a kept-alive "
    "connection the bytes after a body shorter than its Content-Length, read as the next request); "
    "the connection is closed"
)


class HeaderTimeoutProtocol(H11Protocol):
    """uvicorn's h11 protocol with a deadline for each request's headers (see the module docstring)."""

    header_timeout_s: float = 10.0

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._header_timer: asyncio.TimerHandle | None = None
        self._lingering = False

    def data_received(self, data: bytes) -> None:
        if self._lingering:  # answered 408: what still arrives is dropped until the socket closes
            return
        super().data_received(data)

    def send_400_response(self, msg: str) -> None:
        """h11 could not parse the request: the service's ``ErrorOut`` in place of uvicorn's plain text."""
        self.logger.info("refusing bytes that are not an HTTP/1.1 request (%s)", msg)
        self.transport.write(_answer(400, "BadRequest", "request", NOT_HTTP))
        self.transport.close()

    def eof_received(self) -> None:
        """The client half-closed: mid-body, before any answer, it is told its body is short of the
        Content-Length; then (as uvicorn does) the connection closes."""
        cycle = self.cycle
        if cycle is not None and not cycle.response_started and self.conn.their_state is h11.SEND_BODY:
            declared = dict(self.headers).get(b"content-length")
            end = (
                f"the {declared.decode('latin-1')[:20]} bytes its Content-Length declares had arrived"
                if declared is not None
                else "its chunked body's last chunk"
            )
            self.transport.write(
                _answer(400, "BadRequest", "body", f"body: the client ended the connection before {end}")
            )
            cycle.disconnected = True  # the app's receive() gets http.disconnect; its answer is not sent
            cycle.message_event.set()

    def connection_made(self, transport: asyncio.Transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm_header_timer()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_header_timer()
        super().connection_lost(exc)

    def on_response_complete(self) -> None:
        super().on_response_complete()
        self._arm_header_timer()  # the next request on this connection gets its own deadline

    def _arm_header_timer(self) -> None:
        self._cancel_header_timer()
        if not self.transport.is_closing():
            self._header_timer = self.loop.call_later(self.header_timeout_s, self._header_deadline)

    def _cancel_header_timer(self) -> None:
        if self._header_timer is not None:
            self._header_timer.cancel()
            self._header_timer = None

    def _header_deadline(self) -> None:
        self._header_timer = None
        if self.transport.is_closing() or self.transport.get_protocol() is not self:  # closed, or now a WebSocket
            return
        if self.conn.their_state is not h11.IDLE:  # headers complete: a body or an answer is under way
            self._arm_header_timer()  # check again later, for the next request on this connection
            return
        self.logger.info("closing a connection whose request headers did not arrive within %g s", self.header_timeout_s)
        self.transport.write(_timeout_answer(self.header_timeout_s))
        self._lingering = True
        if self.transport.can_write_eof():
            self.transport.write_eof()
        self.loop.call_later(LINGER_S, self.transport.close)


def header_timeout_protocol(header_timeout_s: float) -> type[HeaderTimeoutProtocol]:
    """The protocol class for uvicorn's ``Config(http=...)``, with this header deadline."""
    return type("HeaderTimeoutProtocol", (HeaderTimeoutProtocol,), {"header_timeout_s": header_timeout_s})
