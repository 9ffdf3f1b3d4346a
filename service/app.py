"""``create_app(settings)``: the FastAPI application, built by a factory with a lifespan.

    app = create_app(ServiceSettings(model_path="model.onnx"))
    uvicorn.run(app)                    # or: fisheye-infer serve model.onnx

Nothing heavy happens at import or in the factory: the lifespan loads and warms the Detector
once, off the event loop, and stops the inference workers at shutdown. A ``Detector`` may be
passed in (an application embedding the service, or tests sharing one session).
"""

from __future__ import annotations

import logging
from contextlib import asynccontextmanager
from typing import AsyncIterator

from fastapi import FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import JSONResponse

from fisheye_infer._version import __version__
from fisheye_infer.detector import Detector
from fisheye_infer.errors import FisheyeInferError
from fisheye_infer.service.errors import handle_fisheye_error
from fisheye_infer.service.middleware import ServiceMiddleware
from fisheye_infer.service.openapi import install_openapi
from fisheye_infer.service.routers import detect, health, kserve, stream
from fisheye_infer.service.settings import ServiceSettings
from fisheye_infer.service.state import Service

__all__ = ["create_app"]

log = logging.getLogger("fisheye_infer.service")

DESCRIPTION = """\
Surround-view fisheye 3D object detection: send one image per camera, get boxes in the lidar frame.

- `POST /detect`: one frame (multipart, one part per camera, or JSON with base64 images);
- `POST /detect/batch`: several frames run as one batch;
- `WebSocket /stream`: binary frames in, JSON answers out, latest frame wins (format: see the
  `fisheye_infer.service.protocol` module);
- `GET /model`: the camera names, image size and classes to use; `/healthz`, `/readyz`, `/metrics`.

Every refusal is an `ErrorOut` naming the camera or field. With an API key configured, send it as
`X-API-Key` (the health endpoints do not need it).
"""


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    """A bug, not a refusal: logged with its traceback, answered without internals."""
    log.exception("unexpected error on %s %s", request.method, request.url.path, exc_info=exc)
    return JSONResponse({"error": "internal error; see the server log", "status": 500, "type": "InternalError", "field": None}, status_code=500)


def create_app(settings: ServiceSettings, detector: Detector | None = None) -> FastAPI:
    """The service for ``settings``; see the module docstring."""
    service = Service(settings)

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await service.start(detector)
        try:
            yield
        finally:
            await service.stop()

    app = FastAPI(title="fisheye-infer", version=__version__, description=DESCRIPTION, lifespan=lifespan)
    app.state.service = service
    app.add_exception_handler(FisheyeInferError, handle_fisheye_error)
    app.add_exception_handler(Exception, _unexpected)
    app.add_middleware(ServiceMiddleware, metrics=service.metrics, max_body_bytes=settings.max_body_bytes)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins, allow_methods=["GET", "POST"], allow_headers=["Content-Type", "X-API-Key"])
    for group in (health, detect, stream, kserve):
        app.include_router(group.router)
    install_openapi(app, service)
    return app
