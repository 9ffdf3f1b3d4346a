"""``WebSocket /stream``: frames in (binary, see ``protocol.py``), JSON answers out, latest frame wins.

    ws://127.0.0.1:8000/stream?score_threshold=0.3&classes=Car,Van&nms=rotated
    ws://127.0.0.1:8000/stream?track=true&track_score=0.15

Options are query parameters (the ``/detect`` form fields). ``track=true`` gives the connection a tracker of its
own ([`Tracker`][fisheye_infer.tracking.Tracker], ``track_score`` starts tracks, a third of it keeps them alive; default
the score threshold, else the tracker's): every answer then carries ``tracks`` (ids, boxes, velocities over ground,
ages), the tracker fed every box of the frame at the time the server received it. A new connection starts new
tracks; the tracker goes with its connection. Each connection runs two tasks:

- the receiver reads every message as it arrives and keeps only the newest one as *pending*;
  a pending frame replaced by a newer one is *dropped*, and its id is reported in the next
  answer's ``dropped`` list (and counted in ``fisheye_stream_dropped_frames_total``);
- the processor takes the pending frame, runs it through the shared inference queue and
  answers it, then takes the next.

So a client that sends faster than the model runs gets answers for the newest frames, and the
server holds at most one pending frame per connection (plus the one running).

A frame refused for its content (unknown camera, bad image: the ``/detect`` status codes) is
answered with a ``StreamError`` naming its ``frame_id``, and the connection stays open. A
connection that cannot go on gets a ``StreamError`` and then a close code: 1008 X-API-Key
missing or wrong, or bad options; 1013 not ready or draining (try again later); 1003 a text
message; 1002 an unreadable frame header; 1009 a message over max_body_bytes (closed by the
server without a message); 1001 shutting down, after answering the frame in flight (a pending
frame gets a 503 ``StreamError``). When the client leaves, both tasks end and its queued work is
withdrawn.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from typing import Any

from fastapi import APIRouter, WebSocket

from fisheye_infer.errors import FisheyeInferError
from fisheye_infer.service.deps import check_api_key
from fisheye_infer.service.errors import (
    PayloadTooLarge,
    RequestInvalid,
    ServiceError,
    Unauthorized,
    Unavailable,
    error_body,
    shown,
)
from fisheye_infer.service.intake import check_frame, parse_options
from fisheye_infer.service.pipeline import run_frames
from fisheye_infer.service.protocol import StreamProtocolError, decode_frame, peek_frame_id
from fisheye_infer.service.schemas import DetectOptions
from fisheye_infer.service.state import Service
from fisheye_infer.tracking import Tracker, TrackerConfig

__all__ = ["router", "StreamSession"]

log = logging.getLogger("fisheye_infer.service")
router = APIRouter(tags=["stream"])


class _Gone(Exception):
    """The socket is closed; the session ends."""


class StreamSession:
    """One connection's receiver and processor (see the module docstring)."""

    def __init__(
        self, websocket: WebSocket, service: Service, options: DetectOptions, tracker: Tracker | None = None
    ) -> None:
        self.ws = websocket
        self.service = service
        self.options = options
        self.tracker = tracker
        self.pending: tuple[int, bytes, float] | None = None
        self.dropped: list[int] = []
        self._wake = asyncio.Event()
        self._send_lock = asyncio.Lock()
        self._closed = False

    def wake(self) -> None:
        self._wake.set()

    async def run(self) -> None:
        metrics = self.service.metrics
        self.service.streams.add(self)
        metrics.stream_connections.inc()
        tasks = [asyncio.ensure_future(self._receive()), asyncio.ensure_future(self._process())]
        try:
            await asyncio.wait(tasks, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for task in tasks:
                task.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
            if self.pending is not None:
                self.pending = None
                metrics.stream_pending.dec()
            self.service.streams.discard(self)
            metrics.stream_connections.dec()
            await self._close(1000, "")

    # -- sending ---------------------------------------------------------------------------------

    async def _send(self, document: dict[str, Any]) -> None:
        async with self._send_lock:
            if self._closed:
                raise _Gone
            try:
                await self.ws.send_json(document)
            except Exception as exc:  # the client went away mid-send
                self._closed = True
                raise _Gone from exc

    async def _refuse(self, exc: FisheyeInferError, frame_id: int | None) -> None:
        self.service.metrics.stream_frames.labels("error").inc()
        await self._send({"kind": "error", "frame_id": frame_id, "dropped": self._take_dropped(), **error_body(exc)})

    async def _close(self, code: int, reason: str) -> None:
        async with self._send_lock:
            if self._closed:
                return
            self._closed = True
            with contextlib.suppress(Exception):  # already closed by the client
                await self.ws.close(code, reason)

    def _take_dropped(self) -> list[int]:
        dropped, self.dropped = self.dropped, []
        return dropped

    # -- the two tasks ---------------------------------------------------------------------------

    async def _receive(self) -> None:
        metrics, limit = self.service.metrics, self.service.settings.max_body_bytes
        while True:
            message = await self.ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            data = message.get("bytes")
            try:
                if data is None:
                    raise StreamProtocolError(
                        "message: got a text message, frames are binary messages (see the protocol)", field="message"
                    )
                frame_id = peek_frame_id(data)
            except StreamProtocolError as exc:
                await self._refuse(exc, None)
                await self._close(1003 if data is None else 1002, str(exc)[:120])
                return
            if len(data) > limit:
                await self._refuse(
                    PayloadTooLarge(f"message: {len(data)} bytes, at most max_body_bytes={limit}", field="message"),
                    frame_id,
                )
                continue
            if self.pending is not None:
                self.dropped.append(self.pending[0])
                metrics.stream_dropped.inc()
                metrics.stream_frames.labels("dropped").inc()
            else:
                metrics.stream_pending.inc()
            self.pending = (frame_id, data, time.monotonic())
            self._wake.set()

    async def _process(self) -> None:
        try:
            while True:
                await self._wake.wait()
                self._wake.clear()
                if self.service.draining:
                    await self._drain()
                    return
                if self.pending is None:
                    continue
                (frame_id, data, received), self.pending = self.pending, None
                self.service.metrics.stream_pending.dec()
                await self._answer(frame_id, data, received)
                if self.pending is not None:
                    self._wake.set()
        except _Gone:
            return

    async def _answer(self, frame_id: int, data: bytes, received: float) -> None:
        service = self.service
        track = None if self.tracker is None else (self.tracker, received)
        try:
            if service.spec is None:
                raise Unavailable("model: not loaded yet", field="model", retry_after=service.settings.retry_after_s)
            frame = decode_frame(data)
            check_frame(frame.images, service.spec, self.options)
            documents = await run_frames(service, [frame.images], self.options, track)
        except FisheyeInferError as exc:
            await self._refuse(exc, frame_id)
            return
        service.metrics.stream_frames.labels("answered").inc()
        await self._send(
            {
                "kind": "result",
                "frame_id": frame_id,
                "model_id": service.model_id,
                **documents[0],
                "dropped": self._take_dropped(),
            }
        )

    async def _drain(self) -> None:
        """Shutting down: the pending frame is refused by name, then the socket closes (1001)."""
        if self.pending is not None:
            frame_id, self.pending = self.pending[0], None
            self.service.metrics.stream_pending.dec()
            await self._refuse(
                Unavailable(
                    "service: shutting down; frame not run",
                    field="service",
                    retry_after=self.service.settings.retry_after_s,
                ),
                frame_id,
            )
        await self._close(1001, "server shutting down")


@router.websocket("/stream")
async def stream(websocket: WebSocket) -> None:
    """Binary frames in, JSON answers out; see the module docstring and ``protocol.py``."""
    service: Service = websocket.app.state.service
    try:
        check_api_key(service.settings, websocket.headers.get("x-api-key"))
    except Unauthorized as exc:
        await _deny(websocket, exc, 1008)
        return
    if not service.ready or service.spec is None:
        await _deny(
            websocket,
            Unavailable(
                "service: not ready or shutting down", field="service", retry_after=service.settings.retry_after_s
            ),
            1013,
        )
        return
    params = dict(websocket.query_params)
    try:
        tracker = _tracker(params.pop("track", ""), params.pop("track_score", ""), params.get("score_threshold", ""))
        options = parse_options(params, service.spec)
    except ServiceError as exc:
        await _deny(websocket, exc, 1008)
        return
    await websocket.accept()
    await StreamSession(websocket, service, options, tracker).run()


def _tracker(track: str, track_score: str, score_threshold: str) -> Tracker | None:
    """The connection's tracker, or None: ``track`` true/false (1/0), ``track_score`` in [0, 1]."""
    if track.lower() not in ("true", "1", "false", "0", ""):
        raise RequestInvalid(f"track: expected true or false, got {shown(track)}", field="track")
    if track.lower() not in ("true", "1"):
        if track_score:
            raise RequestInvalid("track_score: applies to track=true", field="track_score")
        return None
    given = track_score or score_threshold
    try:
        score = float(given) if given else TrackerConfig().score_threshold
        if not 0.0 <= score <= 1.0:
            raise ValueError
    except ValueError:
        raise RequestInvalid(
            f"track_score: expected a number in [0, 1], got {shown(given)}", field="track_score"
        ) from None
    return Tracker(TrackerConfig(score_threshold=score, low_score=score / 3))


async def _deny(websocket: WebSocket, exc: FisheyeInferError, code: int) -> None:
    """Refuse a connection: accept, send the ``StreamError``, close with ``code``.

    Accepting first lets every client read why (a refused handshake carries no message through
    most WebSocket clients), and works the same under any ASGI server.
    """
    await websocket.accept()
    try:
        await websocket.send_json({"kind": "error", "frame_id": None, "dropped": [], **error_body(exc)})
        await websocket.close(code, str(exc)[:120])
    except Exception:  # the client left already
        pass
