"""``/healthz``, ``/readyz``, ``/metrics``, ``/model``: what operators and clients ask first.

``/healthz`` and ``/readyz`` never need the API key: orchestrators probe them without one.
``/healthz`` says the process answers; ``/readyz`` says the model is loaded and warmed and the
service is not draining (a load balancer stops sending work when it turns 503).
"""

from __future__ import annotations

from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, Response

from fisheye_infer.runtime.codec import MAX_JPEG_SCANS
from fisheye_infer.service.deps import ApiKeyDep, DetectorDep, ServiceDep, check_api_key
from fisheye_infer.service.metrics import CONTENT_TYPE
from fisheye_infer.service.protocol import VERSION
from fisheye_infer.service.schemas import ErrorOut, Health, ImageSize, Limits, ModelInfo, Ready

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="the process is up")
async def healthz() -> Health:
    return Health()


@router.get(
    "/readyz",
    response_model=Ready,
    summary="the model is loaded and warmed, and the service is not draining",
    responses={503: {"model": Ready, "description": "loading or draining"}},
)
async def readyz(service: ServiceDep) -> JSONResponse | Ready:
    model_id = service.detector.info.model_id if service.detector else None
    if service.ready:
        return Ready(status="ready", model_id=model_id)
    status = "draining" if service.draining else "loading"
    return JSONResponse(Ready(status=status, model_id=model_id).model_dump(), status_code=503)


def _metrics_access(request: Request, service: ServiceDep) -> None:
    if not service.settings.metrics_public:
        check_api_key(service.settings, request.headers.get("x-api-key"))


@router.get(
    "/metrics",
    summary="Prometheus text format",
    response_class=Response,
    dependencies=[Depends(_metrics_access)],
    responses={
        200: {"content": {"text/plain": {"schema": {"type": "string"}}}, "description": "metrics"},
        401: {"model": ErrorOut},
    },
)
async def metrics(service: ServiceDep) -> Response:
    return Response(service.metrics.render(), media_type=CONTENT_TYPE)


@router.get(
    "/model",
    response_model=ModelInfo,
    summary="what to send: cameras, image size, classes, limits",
    responses={401: {"model": ErrorOut}, 503: {"model": ErrorOut}},
)
async def model(detector: DetectorDep, service: ServiceDep, _: ApiKeyDep) -> ModelInfo:
    info, s = detector.info, service.settings
    return ModelInfo(
        architecture=info.architecture,
        model_id=info.model_id,
        classes=list(info.classes),
        cameras=list(info.cameras),
        image_size=ImageSize(width=info.image_size[0], height=info.image_size[1]),
        colour_order=info.colour_order,
        num_boxes=info.num_boxes,
        rig_name=info.rig.name,
        rig_hash=info.meta.rig_hash,
        providers=list(info.providers),
        limits=Limits(
            max_body_bytes=s.max_body_bytes,
            max_batch_frames=s.max_batch_frames,
            queue_size=s.queue_size,
            microbatch_max_size=s.microbatch_max_size,
            microbatch_max_wait_ms=s.microbatch_max_wait_ms,
            body_timeout_s=s.body_timeout_s,
            max_jpeg_scans=MAX_JPEG_SCANS,
            stream_protocol_version=VERSION,
        ),
    )
