"""``create_app(settings)``: the FastAPI application, built by a factory with a lifespan.

    app = create_app(ServiceSettings(model_path="model.onnx"))
    uvicorn.run(app)                    # or: fisheye-infer serve model.onnx

Nothing heavy happens at import or in the factory: the lifespan loads and warms the Detector
once, off the event loop, and stops the inference workers at shutdown. A ``Detector`` may be
passed in (an application embedding the service, or tests sharing one session).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import Depends, FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse, JSONResponse

from fisheye_infer._version import __version__
from fisheye_infer.errors import FisheyeInferError
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.service.deps import require_api_key
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
`X-API-Key` (the health endpoints do not need it; this document and `/docs` need it too unless the
service was started with `docs_public`).
"""


async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
    """A bug, not a refusal: logged with its traceback, answered without internals."""
    log.exception("unexpected error on %s %s", request.method, request.url.path, exc_info=exc)
    return JSONResponse(
        {"error": "internal error; see the server log", "status": 500, "type": "InternalError", "field": None},
        status_code=500,
    )


def _add_protected_docs(app: FastAPI) -> None:
    """``/openapi.json`` and ``/docs`` behind the API key: the schema names the model's cameras,
    classes and limits, which a service with a key does not tell strangers."""
    key = [Depends(require_api_key)]

    @app.get("/openapi.json", include_in_schema=False, dependencies=key)
    async def openapi_document() -> JSONResponse:
        return JSONResponse(app.openapi())

    @app.get("/docs", include_in_schema=False, dependencies=key)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(openapi_url="/openapi.json", title=f"{app.title} - docs")


def create_app(settings: ServiceSettings, detector: Detector | None = None) -> FastAPI:
    """Build the service's FastAPI application for ``settings``.

    Nothing heavy happens here: the application's lifespan loads and warms the Detector once, off the event loop,
    and stops the inference workers at shutdown. The routes are ``POST /detect`` (one frame, multipart or JSON),
    ``POST /detect/batch``, ``WebSocket /stream``, ``GET /model``, the KServe v2 routes under ``/v2``, ``/healthz``,
    ``/readyz`` and ``/metrics``; with an ``api_key`` every route but the health endpoints needs ``X-API-Key``.

    Args:
        settings (ServiceSettings): The model, limits and options
            ([`ServiceSettings`][fisheye_infer.service.settings.ServiceSettings]).
        detector (Detector | None): A loaded [`Detector`][fisheye_infer.runtime.detector.Detector] to serve (an
            application embedding the service, or tests sharing one session); None loads ``settings.model_path``
            at startup.

    Returns:
        FastAPI: The application, for uvicorn or any ASGI server.

    Examples:
        ```python
        import uvicorn

        from fisheye_infer.service.app import create_app
        from fisheye_infer.service.settings import ServiceSettings

        app = create_app(ServiceSettings(model_path="model.onnx"))
        uvicorn.run(app, port=8000)  # or build_server(settings, app).run() for the graceful drain
        ```
    """
    service = Service(settings)
    protect_docs = settings.api_key is not None and not settings.docs_public

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        await service.start(detector)
        try:
            yield
        finally:
            await service.stop()

    if protect_docs:
        app = FastAPI(
            title="fisheye-infer",
            version=__version__,
            description=DESCRIPTION,
            lifespan=lifespan,
            docs_url=None,
            redoc_url=None,
            openapi_url=None,
        )
        _add_protected_docs(app)
    else:
        app = FastAPI(title="fisheye-infer", version=__version__, description=DESCRIPTION, lifespan=lifespan)
    app.state.service = service
    app.add_exception_handler(FisheyeInferError, handle_fisheye_error)
    app.add_exception_handler(Exception, _unexpected)
    app.add_middleware(ServiceMiddleware, metrics=service.metrics, max_body_bytes=settings.max_body_bytes)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["GET", "POST"],
            allow_headers=["Content-Type", "X-API-Key"],
        )
    for group in (health, detect, stream, kserve):
        app.include_router(group.router)
    install_openapi(app, service)
    return app
