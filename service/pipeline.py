"""One request's frames through decode -> queue -> per-request options -> result documents.

The images are decoded in a thread (at most one decode per core at a time), before the request
takes its queue place: a slow decode holds a thread, never the queue or the event loop. Shared
by ``/detect``, ``/detect/batch`` and ``/stream``. The worker always runs the official
output set (no threshold, no NMS), so requests with different options can share one
micro-batch; each request's threshold, class filter and NMS are applied afterwards, off the
event loop, and counted as postprocess time.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any

import anyio

from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.service.errors import Unavailable
from fisheye_infer.service.intake import EncodedFrame, decode_frames
from fisheye_infer.service.queue import RunResult
from fisheye_infer.service.schemas import DetectOptions
from fisheye_infer.service.state import Service
from fisheye_infer.tracking import Tracker

__all__ = ["run_frames", "finish"]


def finish(
    result: RunResult, options: DetectOptions, decode_ms: float, track: tuple[Tracker, float] | None = None
) -> dict[str, Any]:
    """A ``FrameResult`` document for one frame, after the request's options; with ``track`` (a stream's tracker
    and the frame's time, seconds) also its ``tracks``, the tracker fed every box (before the options)."""
    dets = result.detections
    t0 = time.perf_counter()
    if options.score_threshold is not None or options.classes is not None:
        dets = dets.filter(min_score=options.score_threshold, classes=options.classes)
    if options.nms is not None:
        dets = dets.with_nms(NmsConfig(kind=options.nms))
    extra_ms = (time.perf_counter() - t0) * 1e3
    t = result.detections.timings_ms
    timings = {
        "queue_wait": result.queue_wait_ms,
        "decode": decode_ms,
        "preprocess": t.get("decode", 0.0) + t.get("preprocess", 0.0),  # the Detector's array checks + stacking
        "inference": t.get("inference", 0.0),
        "postprocess": t.get("postprocess", 0.0) + extra_ms,
    }
    document = {
        "detections": dets.to_dicts(),
        "records": dets.to_nuscenes(),
        "cameras_used": list(dets.cameras_used),
        "timings_ms": timings,
        "batch_size": result.batch_size,
    }
    if track is not None:
        tracker, stamp = track
        document["tracks"] = tracker.update(result.detections, stamp).to_dicts()
    return document


def _finish_all(
    results: list[RunResult], options: DetectOptions, decode_ms: list[float], track: tuple[Tracker, float] | None
) -> list[dict[str, Any]]:
    return [finish(r, options, ms, track) for r, ms in zip(results, decode_ms, strict=True)]


async def run_frames(
    service: Service,
    frames: list[EncodedFrame],
    options: DetectOptions,
    track: tuple[Tracker, float] | None = None,
) -> list[dict[str, Any]]:
    """Decode (thread) -> queue place -> run (worker) -> options (thread); one document per frame, in order.
    ``track``: one frame's tracker and time (a stream's), whose tracks join its document."""
    if service.spec is None:
        raise Unavailable("model: not loaded yet", field="model", retry_after=service.settings.retry_after_s)
    service.refuse_if_full()  # no decoding for a request the queue would refuse
    decode = partial(
        decode_frames, frames, service.spec, map_images=service.detector.map_images if service.detector else map
    )
    loaded, decode_ms = await anyio.to_thread.run_sync(decode, limiter=service.decode_limiter)
    ticket = service.admit()
    try:
        results = await ticket.run(loaded)
    finally:
        ticket.release()
    documents = await anyio.to_thread.run_sync(_finish_all, results, options, decode_ms, track)
    for doc in documents:
        service.metrics.observe_stages(doc["timings_ms"])
    return documents
