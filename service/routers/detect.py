"""``POST /detect`` (one frame) and ``POST /detect/batch`` (several frames, one ``detect_batch`` call).

Bodies (documented in the OpenAPI schema by ``openapi.py``, which knows the model's cameras):

- multipart/form-data: one file part per camera, named by the camera (``/detect``) or
  ``<frame index>.<camera>`` (``/detect/batch``, frames numbered from 0), plus optional form
  fields ``score_threshold``, ``classes`` (comma-separated), ``nms`` (rotated|circle),
  ``allow_missing_cameras``;
- application/json: ``DetectJsonRequest`` ``{"images": {camera: base64}, ...options}`` or
  ``BatchJsonRequest`` ``{"frames": [{"images": {...}}, ...], ...options}``.

A full queue is refused before the body is read (503 at once). The body must arrive within
``body_timeout_s`` (408, connection closed); its images are decoded in a thread, and only then
does the request take a queue place, so stalled or slow uploads never hold one. If the client
leaves while it waits, its place is given back and the work is dropped (counted as status 499).
"""

from __future__ import annotations

import asyncio
from collections.abc import Awaitable
from typing import Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response
from starlette.requests import ClientDisconnect

from fisheye_infer.service.bodies import read_request
from fisheye_infer.service.deps import ServiceDep, require_api_key
from fisheye_infer.service.errors import RequestTimeout, Unavailable
from fisheye_infer.service.pipeline import run_frames
from fisheye_infer.service.schemas import BatchResponse, DetectResponse, ErrorOut
from fisheye_infer.service.state import Service

__all__ = ["router", "ERROR_RESPONSES", "CLIENT_CLOSED"]

router = APIRouter(tags=["detect"], dependencies=[Depends(require_api_key)])

CLIENT_CLOSED = 499  # nginx's convention: the client left before the answer
ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    400: {
        "model": ErrorOut,
        "description": "malformed multipart or JSON body, or both Content-Length and Transfer-Encoding",
    },
    401: {"model": ErrorOut, "description": "X-API-Key missing or wrong"},
    408: {
        "model": ErrorOut,
        "description": "the headers or body did not arrive within header_timeout_s / body_timeout_s",
    },
    413: {"model": ErrorOut, "description": "body larger than max_body_bytes"},
    415: {"model": ErrorOut, "description": "not multipart/JSON, a Content-Encoding, or an image that is not JPEG/PNG"},
    422: {
        "model": ErrorOut,
        "description": "unknown, missing or repeated camera, bad option, wrong image size (read from the header), "
        "too many JPEG scans, corrupt image",
    },
    503: {"model": ErrorOut, "description": "queue full, draining or loading; see Retry-After"},
    504: {"model": ErrorOut, "description": "no result within request_timeout_s"},
}


async def _disconnected(request: Request) -> None:
    """Returns when the client closes the connection (the body has been read by then)."""
    while True:
        message = await request.receive()
        if message["type"] == "http.disconnect":
            return


async def _unless_client_leaves(request: Request, work: Awaitable[list[dict[str, Any]]]) -> list[dict[str, Any]] | None:
    """The work's result, or ``None`` (work cancelled) if the client leaves first."""
    job = asyncio.ensure_future(work)
    watch = asyncio.ensure_future(_disconnected(request))
    try:
        done, _ = await asyncio.wait({job, watch}, return_when=asyncio.FIRST_COMPLETED)
        return job.result() if job in done else None
    finally:
        for task in (job, watch):
            task.cancel()
        await asyncio.gather(job, watch, return_exceptions=True)


async def _serve(request: Request, service: Service, batch: bool) -> list[dict[str, Any]] | None:
    if service.spec is None:
        raise Unavailable("model: not loaded yet", field="model", retry_after=service.settings.retry_after_s)
    service.refuse_if_full()  # before reading the body: a full queue refuses at once
    timeout = service.settings.body_timeout_s
    with service.reading_request():
        try:
            frames, options = await asyncio.wait_for(read_request(request, service.spec, batch), timeout)
        except asyncio.TimeoutError:
            raise RequestTimeout(
                f"body: not received within body_timeout_s={timeout:g} s; the connection is closed", field="body"
            ) from None
        except ClientDisconnect:
            return None
        return await _unless_client_leaves(request, run_frames(service, frames, options))


@router.post("/detect", response_model=DetectResponse, responses=ERROR_RESPONSES, summary="detect objects in one frame")
async def detect(request: Request, service: ServiceDep) -> Any:
    documents = await _serve(request, service, batch=False)
    if documents is None:
        return Response(status_code=CLIENT_CLOSED)
    return {"model_id": service.model_id, **documents[0]}


@router.post(
    "/detect/batch",
    response_model=BatchResponse,
    responses=ERROR_RESPONSES,
    summary="detect objects in several frames, run as one batch",
)
async def detect_batch(request: Request, service: ServiceDep) -> Any:
    documents = await _serve(request, service, batch=True)
    if documents is None:
        return Response(status_code=CLIENT_CLOSED)
    return {"model_id": service.model_id, "frames": documents}
