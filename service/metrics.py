"""Prometheus metrics of one service instance, in its own registry.

Each ``create_app`` gets its own ``CollectorRegistry``, so several apps in one process (tests,
an embedding application) never collide on metric names.

| metric | type | labels |
|---|---|---|
| ``fisheye_requests_total`` | counter | endpoint, status (499: the client left first) |
| ``fisheye_request_duration_seconds`` | histogram | endpoint |
| ``fisheye_stage_duration_seconds`` | histogram | stage: queue_wait, decode, preprocess, inference, postprocess |
| ``fisheye_queue_depth`` | gauge | requests admitted and not yet running |
| ``fisheye_inflight`` | gauge | requests and stream frames admitted and not yet answered |
| ``fisheye_batch_frames`` | histogram | frames per ``detect_batch`` call (micro-batching shows here) |
| ``fisheye_stream_connections`` | gauge | open ``/stream`` connections |
| ``fisheye_stream_pending_frames`` | gauge | stream frames waiting (at most one per connection) |
| ``fisheye_stream_frames_total`` | counter | outcome: answered, error, dropped |
| ``fisheye_stream_dropped_frames_total`` | counter | frames replaced by newer ones (latest frame wins) |
"""

from __future__ import annotations

from prometheus_client import CONTENT_TYPE_LATEST, CollectorRegistry, Counter, Gauge, Histogram, generate_latest

__all__ = ["ServiceMetrics", "CONTENT_TYPE", "ENDPOINTS", "endpoint_label"]

CONTENT_TYPE = CONTENT_TYPE_LATEST
#: Paths counted under their own name; anything else is "other", so labels stay few.
ENDPOINTS = (
    "/detect",
    "/detect/batch",
    "/stream",
    "/healthz",
    "/readyz",
    "/metrics",
    "/model",
    "/docs",
    "/openapi.json",
)
_SECONDS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0)


def endpoint_label(path: str) -> str:
    return path if path in ENDPOINTS else "other"


class ServiceMetrics:
    """The service's counters, gauges and histograms (see the module docstring)."""

    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter(
            "fisheye_requests", "HTTP requests answered, by endpoint and status", ["endpoint", "status"], registry=r
        )
        self.latency = Histogram(
            "fisheye_request_duration_seconds", "HTTP request duration", ["endpoint"], buckets=_SECONDS, registry=r
        )
        self.stage = Histogram(
            "fisheye_stage_duration_seconds", "time per frame in each stage", ["stage"], buckets=_SECONDS, registry=r
        )
        self.queue_depth = Gauge("fisheye_queue_depth", "requests admitted and not yet running", registry=r)
        self.inflight = Gauge(
            "fisheye_inflight", "requests and stream frames admitted and not yet answered", registry=r
        )
        self.batch_frames = Histogram(
            "fisheye_batch_frames", "frames per detect_batch call", buckets=(1, 2, 3, 4, 6, 8, 12, 16, 32), registry=r
        )
        self.stream_connections = Gauge("fisheye_stream_connections", "open /stream connections", registry=r)
        self.stream_pending = Gauge("fisheye_stream_pending_frames", "stream frames waiting for the model", registry=r)
        self.stream_frames = Counter("fisheye_stream_frames", "stream frames by outcome", ["outcome"], registry=r)
        self.stream_dropped = Counter(
            "fisheye_stream_dropped_frames", "stream frames replaced by a newer frame", registry=r
        )

    def observe_stages(self, timings_ms: dict[str, float]) -> None:
        for stage, ms in timings_ms.items():
            self.stage.labels(stage).observe(ms / 1e3)

    def render(self) -> bytes:
        return generate_latest(self.registry)
