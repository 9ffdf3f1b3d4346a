"""``Service``: what one app instance owns (Detector, queue, metrics, drain state) and its life cycle.

The lifespan in ``app.py`` calls ``start`` once (load and warm the Detector off the event loop,
start the workers) and ``stop`` once. Between the two, ``begin_drain`` (called by the server on
SIGTERM/SIGINT) makes new work answer 503 while admitted work finishes; ``busy`` tells the
server when nothing is left.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from typing import Protocol

import anyio

from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.session import usable_cpus
from fisheye_infer.service.errors import Unavailable
from fisheye_infer.service.intake import FrameSpec
from fisheye_infer.service.metrics import ServiceMetrics
from fisheye_infer.service.queue import InferenceQueue, Ticket
from fisheye_infer.service.settings import ServiceSettings

__all__ = ["Service"]

log = logging.getLogger("fisheye_infer.service")


class _Stream(Protocol):
    def wake(self) -> None: ...


class Service:
    """See the module docstring."""

    def __init__(self, settings: ServiceSettings, metrics: ServiceMetrics | None = None) -> None:
        self.settings = settings
        self.metrics = metrics or ServiceMetrics()
        self.detector: Detector | None = None
        self.queue: InferenceQueue | None = None
        self.spec: FrameSpec | None = None
        self.draining = False
        self.streams: set[_Stream] = set()
        self.decode_limiter: anyio.CapacityLimiter | None = (
            None  # requests decoding at once, one per core (images: the Detector's threads)
        )
        self.reading = 0  # requests whose body is arriving or whose images are decoding (no queue place yet)

    async def start(self, detector: Detector | None = None) -> None:
        """Load (unless given) and warm the Detector in a thread, then start the workers."""
        s = self.settings
        if detector is None:
            detector = await anyio.to_thread.run_sync(
                partial(
                    Detector,
                    s.model_path,
                    threads=s.threads,
                    providers=s.session_providers,
                    warmup=s.warmup,
                    spin=s.spin,
                )
            )
        elif s.warmup and not detector.ready:
            await anyio.to_thread.run_sync(detector.warmup)
        if detector.score_threshold is not None or detector.nms is not None:
            log.warning("the Detector's own score_threshold/nms apply to every request before the request's options")
        self.decode_limiter = anyio.CapacityLimiter(usable_cpus())
        self.detector = detector
        self.spec = FrameSpec.of(detector.info, s.max_batch_frames)
        self.queue = InferenceQueue(detector, s, self.metrics)
        self.queue.start()
        log.info(
            "model %s ready: %d cameras at %dx%d, %d worker(s), queue_size %d, micro-batching %s",
            detector.info.model_id,
            len(detector.info.cameras),
            *detector.info.image_size,
            s.workers,
            s.queue_size,
            f"up to {s.microbatch_max_size} frames / {s.microbatch_max_wait_ms:g} ms" if s.microbatching else "off",
        )

    async def stop(self) -> None:
        self.begin_drain()
        if self.queue is not None:
            await anyio.to_thread.run_sync(partial(self.queue.stop, timeout=max(self.settings.drain_timeout_s, 1.0)))

    def begin_drain(self) -> None:
        """Refuse new work from now on; streams finish their current frame and close."""
        if not self.draining:
            log.info("draining: new requests get 503, %d in flight finish", self.busy)
        self.draining = True
        for stream in list(self.streams):
            stream.wake()

    @property
    def ready(self) -> bool:
        return self.detector is not None and self.detector.ready and self.queue is not None and not self.draining

    @property
    def model_id(self) -> str:
        return self.detector.info.model_id if self.detector else ""

    @property
    def busy(self) -> int:
        """Requests being read, decoded or run, and open streams: what a graceful shutdown waits for."""
        return (self.queue.busy if self.queue else 0) + len(self.streams) + self.reading

    @contextmanager
    def reading_request(self) -> Iterator[None]:
        """Counts a request from its headers to its answer, so that a drain waits for it to be answered."""
        self.reading += 1
        try:
            yield
        finally:
            self.reading -= 1

    def refuse_if_full(self) -> None:
        """503 now if the queue is full, loading or draining; called before reading a body."""
        if self.queue is None:
            raise Unavailable("model: not loaded yet", field="model", retry_after=self.settings.retry_after_s)
        self.queue.refuse_if_full(self.draining)

    def admit(self) -> Ticket:
        """A queue place, taken once the request's images are decoded (see ``queue.py``)."""
        if self.queue is None:
            raise Unavailable("model: not loaded yet", field="model", retry_after=self.settings.retry_after_s)
        return self.queue.admit(self.draining)
