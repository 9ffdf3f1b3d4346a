"""The bounded inference queue: worker threads call the Detector, the event loop never does.

    queue.refuse_if_full()              # before reading a body: 503 + Retry-After at once when full
    ...                                 # the body arrives and is decoded
    ticket = queue.admit()              # the place is taken only now (503 if full meanwhile)
    try:
        results = await ticket.run([frame])   # frame: one array (or None) per camera
    finally:
        ticket.release()

Why admission comes last: a place is taken only by a request whose body has arrived and whose
images are decoded, so clients that send headers and stall (or upload slowly, or send images
that are slow to decode) cannot fill the queue and lock out everyone else; the time they may
take is bounded by ``header_timeout_s`` and ``body_timeout_s`` instead. A full queue is still
refused cheaply: ``refuse_if_full`` answers 503 before the body is read. The memory held by
waiting requests is bounded by ``queue_size`` decoded frame sets. Every admitted request is answered: with its result,
with the Detector's error, with 504 after ``request_timeout_s``, or with 503 when the service
stops before its turn. A request whose client left is taken out of the queue (or, if already
running, its result is discarded), so nothing waits for nobody.

Micro-batching (``microbatch_max_size > 1``): a worker that picks up a single-frame request
waits up to ``microbatch_max_wait_ms`` for more single-frame requests and runs them as one
``detect_batch`` call. Multi-frame requests (``/detect/batch``) always run alone, as one call.
"""

from __future__ import annotations

import asyncio
import collections
import logging
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.service.errors import InferenceTimeout, Unavailable
from fisheye_infer.service.metrics import ServiceMetrics
from fisheye_infer.service.settings import ServiceSettings

__all__ = ["InferenceQueue", "Ticket", "RunResult", "LoadedFrame"]

log = logging.getLogger("fisheye_infer.service")

LoadedFrame = Sequence["np.ndarray | None"]  # one decoded image (or None) per camera, model order


@dataclass(frozen=True)
class RunResult:
    """One frame's raw detections and how it ran."""

    detections: Detections
    batch_size: int  # frames in the detect_batch call
    queue_wait_ms: float


@dataclass(eq=False)
class _Job:
    frames: Sequence[LoadedFrame]
    loop: asyncio.AbstractEventLoop
    future: asyncio.Future[list[RunResult]]
    submitted: float = field(default_factory=time.perf_counter)


def _resolve(future: asyncio.Future[Any], result: object, error: BaseException | None) -> None:
    if future.done():  # the waiter gave up (client left, timeout)
        return
    if error is not None:
        future.set_exception(error)
    else:
        future.set_result(result)


class Ticket:
    """A request's place in the queue; ``release`` must be called exactly once (use ``finally``)."""

    def __init__(self, owner: InferenceQueue) -> None:
        self._owner = owner
        self._job: _Job | None = None
        self._state = "reserved"  # -> queued -> taken; or released
        self._released = False

    async def run(self, frames: Sequence[LoadedFrame]) -> list[RunResult]:
        """Queue the frames and wait for their results (one ``detect_batch`` call)."""
        loop = asyncio.get_running_loop()
        job = _Job(frames, loop, loop.create_future())
        self._owner._enqueue(self, job)
        try:
            return await asyncio.wait_for(asyncio.shield(job.future), self._owner.settings.request_timeout_s)
        except asyncio.TimeoutError:
            raise InferenceTimeout(
                f"result: not ready within request_timeout_s={self._owner.settings.request_timeout_s:g} s",
                field="request_timeout_s",
            ) from None

    def release(self) -> None:
        self._owner._release(self)


class InferenceQueue:
    """See the module docstring."""

    def __init__(self, detector: Detector, settings: ServiceSettings, metrics: ServiceMetrics) -> None:
        self.detector = detector
        self.settings = settings
        self.metrics = metrics
        self._cond = threading.Condition()
        self._jobs: collections.deque[tuple[Ticket, _Job]] = collections.deque()
        self._pending = 0  # admitted, not yet picked up by a worker
        self._busy = 0  # admitted, not yet released
        self._stopping = False
        self._threads: list[threading.Thread] = []

    # -- life cycle ----------------------------------------------------------------------------

    def start(self) -> None:
        for i in range(self.settings.workers):
            thread = threading.Thread(target=self._work, name=f"fisheye-infer-worker-{i}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def stop(self, timeout: float = 10.0) -> None:
        """Stop the workers; requests still queued are answered 503."""
        with self._cond:
            self._stopping = True
            left = list(self._jobs)
            self._jobs.clear()
            for ticket, _ in left:
                ticket._state = "taken"
            self._pending -= len(left)
            self._gauges()
            self._cond.notify_all()
        for _, job in left:
            self._complete(
                job,
                None,
                Unavailable(
                    "service: shutting down before this request's turn",
                    field="service",
                    retry_after=self.settings.retry_after_s,
                ),
            )
        deadline = time.monotonic() + timeout
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))
        self._threads.clear()

    @property
    def busy(self) -> int:
        """Requests admitted and not yet answered (what a graceful shutdown waits for)."""
        return self._busy

    @property
    def depth(self) -> int:
        return self._pending

    # -- admission (event loop thread) -----------------------------------------------------------

    def _refuse_if_full(self, draining: bool) -> None:
        retry = self.settings.retry_after_s
        if draining or self._stopping:
            raise Unavailable("service: shutting down, not accepting new work", field="service", retry_after=retry)
        if self._pending >= self.settings.queue_size:
            raise Unavailable(
                f"queue: full ({self._pending} requests waiting, queue_size={self.settings.queue_size}); retry after "
                f"{retry} s",
                field="queue",
                retry_after=retry,
            )

    def refuse_if_full(self, draining: bool = False) -> None:
        """503 now if ``admit`` would refuse: checked before a body is read, no place is taken."""
        with self._cond:
            self._refuse_if_full(draining)

    def admit(self, draining: bool = False) -> Ticket:
        with self._cond:
            self._refuse_if_full(draining)
            self._pending += 1
            self._busy += 1
            self._gauges()
        return Ticket(self)

    def _enqueue(self, ticket: Ticket, job: _Job) -> None:
        with self._cond:
            if ticket._state != "reserved":
                raise RuntimeError("a ticket runs once")
            if self._stopping:
                raise Unavailable(
                    "service: shutting down, not accepting new work",
                    field="service",
                    retry_after=self.settings.retry_after_s,
                )
            ticket._job, ticket._state = job, "queued"
            self._jobs.append((ticket, job))
            self._cond.notify()

    def _release(self, ticket: Ticket) -> None:
        with self._cond:
            if ticket._released:
                return
            ticket._released = True
            if ticket._state == "queued" and ticket._job is not None:  # the client left or timed out before its turn
                self._jobs.remove((ticket, ticket._job))
            if ticket._state in ("reserved", "queued"):
                self._pending -= 1
            self._busy -= 1
            self._gauges()

    def _gauges(self) -> None:
        self.metrics.queue_depth.set(self._pending)
        self.metrics.inflight.set(self._busy)

    # -- workers -----------------------------------------------------------------------------

    def _take(self) -> _Job:
        ticket, job = self._jobs.popleft()
        ticket._state = "taken"
        self._pending -= 1
        self._gauges()
        return job

    def _next_batch(self) -> list[_Job] | None:
        """The next job, plus (micro-batching) further single-frame jobs arriving within the wait."""
        limit, wait = self.settings.microbatch_max_size, self.settings.microbatch_max_wait_ms / 1e3
        with self._cond:
            while not self._jobs and not self._stopping:
                self._cond.wait()
            if self._stopping:
                return None
            batch = [self._take()]
            if limit <= 1 or len(batch[0].frames) != 1:
                return batch
            deadline = time.monotonic() + wait
            while len(batch) < limit:
                if self._jobs:
                    if len(self._jobs[0][1].frames) != 1:
                        break
                    batch.append(self._take())
                    continue
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._stopping:
                    break
                self._cond.wait(remaining)
            return batch

    def _work(self) -> None:
        while True:
            batch = self._next_batch()
            if batch is None:
                return
            self._run(batch)

    def _run(self, batch: list[_Job]) -> None:
        frames = [frame for job in batch for frame in job.frames]
        started = time.perf_counter()
        try:
            results = self.detector.detect_batch(frames)
        except Exception as exc:  # every waiter gets the error, the worker lives on
            for job in batch:
                self._complete(job, None, exc)
            return
        self.metrics.batch_frames.observe(len(frames))
        i = 0
        for job in batch:
            wait_ms = (started - job.submitted) * 1e3
            out = [RunResult(dets, len(frames), wait_ms) for dets in results[i : i + len(job.frames)]]
            i += len(job.frames)
            self._complete(job, out, None)

    @staticmethod
    def _complete(job: _Job, result: object, error: BaseException | None) -> None:
        try:
            job.loop.call_soon_threadsafe(_resolve, job.future, result, error)
        except RuntimeError:  # the loop is closed: the server is gone, nobody waits
            log.debug("result for a closed event loop discarded")
