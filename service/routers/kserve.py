"""The KServe v2 inference protocol (the one Triton serves) for the loaded model's raw graph.

    GET  /v2                                   server metadata
    GET  /v2/health/live, /v2/health/ready     liveness, readiness (no API key, like /healthz)
    GET  /v2/models/{name}[/versions/1]        model metadata: inputs, outputs, shapes, data types
    GET  /v2/models/{name}[/versions/1]/ready
    GET  /v2/models/{name}[/versions/1]/config Triton's model configuration extension (JSON form)
    POST /v2/models/{name}[/versions/1]/infer  tensors in, the graph's outputs out

``name`` is the model file's stem (``fisheye-infer triton``'s default), so a ``TritonDetector``
pointed at this service and at a Triton server loaded with ``fisheye-infer triton``'s repository
behaves the same. Tensors come as JSON ``data`` or with the binary tensor extension
(``Inference-Header-Content-Length``), and answers use binary data where the request asks for
it. The inputs are the graph's own, ``images`` uint8 ``(B, N, H, W, 3)`` and ``camera_valid``
bool ``(B, N)``; the outputs are the fixed-size ``boxes``, ``scores``, ``labels`` and ``valid``.

The service's limits hold here too: the body size (413), at most ``max_batch_frames`` frames
and no more than fit in ``max_body_bytes`` (the ``max_batch_size`` the config reports; 422), a
queue place taken before the body is read (503 when full or draining), a result within
``request_timeout_s`` (504), the API key. At most ``workers`` graph runs at a time. Errors are
the service's ``ErrorOut``, whose ``error`` field is what KServe clients read. These routes
are left out of the OpenAPI document: the KServe v2 specification describes them.
"""

from __future__ import annotations

import asyncio
import json
from functools import partial
from typing import Any

import anyio
import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import JSONResponse, Response

from fisheye_infer._version import __version__
from fisheye_infer.deploy.triton.repository import KSERVE_DTYPES, TritonOptions, model_config, model_name
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS
from fisheye_infer.service.deps import DetectorDep, ServiceDep, require_api_key
from fisheye_infer.service.errors import (
    BadRequest,
    InferenceTimeout,
    RequestInvalid,
    RequestTimeout,
    ServiceError,
    Unavailable,
    listed,
    shown,
)
from fisheye_infer.service.state import Service

__all__ = ["router", "ModelNotFound", "HEADER_LENGTH"]

HEADER_LENGTH = "Inference-Header-Content-Length"
VERSION = "1"
_HEADER_ROOM = 16 * 1024  # room for the JSON header of a binary request
_NUMPY = {
    "UINT8": np.uint8,
    "BOOL": np.bool_,
    "FP32": np.float32,
    "INT64": np.int64,
    "INT32": np.int32,
    "FP16": np.float16,
    "FP64": np.float64,
}
_KSERVE = {np.dtype(v): k for k, v in _NUMPY.items()}

router = APIRouter(prefix="/v2", tags=["kserve"], include_in_schema=False)
_keyed = [Depends(require_api_key)]


class ModelNotFound(ServiceError):
    """The model name or version in the URL is not the one this service serves."""

    status = 404


async def _config(request: Request, service: Service) -> dict[str, Any]:
    """The model's Triton configuration, read from the model file once per app (in a thread)."""
    cached: dict[str, Any] | None = getattr(request.app.state, "kserve_config", None)
    if cached is None:
        s = service.settings
        options = TritonOptions(max_batch_size=_max_batch(service), instances=s.workers, kind="cpu")
        cached = await anyio.to_thread.run_sync(model_config, s.model_path, options)
        request.app.state.kserve_config = cached
    return cached


def _max_batch(service: Service) -> int:
    """Frames per request: at most ``max_batch_frames``, and no more than fit in ``max_body_bytes`` as
    binary tensors."""
    s, info = service.settings, service.detector.info if service.detector else None
    if info is None:
        raise Unavailable("model: not loaded yet", field="model", retry_after=s.retry_after_s)
    width, height = info.image_size
    frame_bytes = len(info.cameras) * (height * width * 3 + 1)
    return max(1, min(s.max_batch_frames, (s.max_body_bytes - _HEADER_ROOM) // frame_bytes))


def _check_model(service: Service, name: str, version: str | None) -> None:
    served = model_name(service.settings.model_path)
    if name != served:
        raise ModelNotFound(f"model '{name}': not served here (models: {served})", field="name")
    if version not in (None, "", VERSION):
        raise ModelNotFound(
            f"model '{name}': version '{version}' not served here (versions: {VERSION})", field="version"
        )


def _io(config: dict[str, Any], key: str) -> list[dict[str, Any]]:
    """Tensors as KServe metadata lists them: the batch axis, if batched, as -1 in front of the dims."""
    batch = [-1] if config["max_batch_size"] > 0 else []
    return [
        {"name": t["name"], "datatype": KSERVE_DTYPES[t["data_type"]], "shape": [*batch, *t["dims"]]}
        for t in config[key]
    ]


@router.get("")
async def server_metadata() -> dict[str, Any]:
    return {
        "name": "fisheye-infer",
        "version": __version__,
        "extensions": ["binary_tensor_data", "model_configuration"],
    }


@router.get("/health/live")
async def live() -> dict[str, bool]:
    return {"live": True}


@router.get("/health/ready")
async def ready(service: ServiceDep) -> JSONResponse:
    return JSONResponse({"ready": service.ready}, status_code=200 if service.ready else 503)


@router.get("/models/{name}", dependencies=_keyed)
@router.get("/models/{name}/versions/{version}", dependencies=_keyed)
async def model_metadata(
    name: str, request: Request, service: ServiceDep, _: DetectorDep, version: str | None = None
) -> dict[str, Any]:
    _check_model(service, name, version)
    config = await _config(request, service)
    return {
        "name": name,
        "versions": [VERSION],
        "platform": "onnxruntime_onnx",
        "inputs": _io(config, "input"),
        "outputs": _io(config, "output"),
    }


@router.get("/models/{name}/ready", dependencies=_keyed)
@router.get("/models/{name}/versions/{version}/ready", dependencies=_keyed)
async def model_ready(name: str, service: ServiceDep, version: str | None = None) -> JSONResponse:
    _check_model(service, name, version)
    return JSONResponse({"name": name, "ready": service.ready}, status_code=200 if service.ready else 503)


@router.get("/models/{name}/config", dependencies=_keyed)
@router.get("/models/{name}/versions/{version}/config", dependencies=_keyed)
async def model_configuration(
    name: str, request: Request, service: ServiceDep, _: DetectorDep, version: str | None = None
) -> dict[str, Any]:
    _check_model(service, name, version)
    config = await _config(request, service)
    return {**config, "name": name}


# -- inference ---------------------------------------------------------------------------------------


def _split_body(body: bytes, header_length: str | None) -> tuple[dict[str, Any], bytes]:
    if header_length is None:
        size = len(body)
    elif not (header_length.isascii() and header_length.isdigit() and len(header_length) <= 20) or int(
        header_length
    ) > len(body):
        raise BadRequest(
            f"{HEADER_LENGTH}: {shown(repr(header_length))} is not a length within the {len(body)}-byte body",
            field=HEADER_LENGTH,
        )
    else:
        size = int(header_length)
    try:
        doc = json.loads(body[:size])
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError, and an integer of more than 4300 digits
        raise BadRequest(
            f"inference request: the JSON header is not valid JSON ({shown(str(exc))})", field="body"
        ) from None
    except RecursionError:
        raise BadRequest(
            "inference request: the JSON header nests arrays or objects too deep to read", field="body"
        ) from None
    if not isinstance(doc, dict) or not isinstance(doc.get("inputs"), list):
        raise RequestInvalid("inference request: expected an object with an 'inputs' list", field="inputs")
    if "id" in doc and not isinstance(doc["id"], str):
        raise RequestInvalid(f"id: expected a string, got {type(doc['id']).__name__}", field="id")
    for i, item in enumerate(doc["inputs"]):
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            raise RequestInvalid(
                f"inputs[{i}]: expected an object whose 'name' is a string, got {_kind(item, 'name')}", field="inputs"
            )
    return doc, body[size:]


def _kind(item: object, key: str) -> str:
    """What a client sent where an object with a string ``key`` was expected, named by type only."""
    if not isinstance(item, dict):
        return type(item).__name__
    return f"'{key}' of type {type(item.get(key)).__name__}" if key in item else f"no '{key}'"


def _parameters(item: dict[str, Any], where: str) -> dict[str, Any]:
    """``item``'s ``parameters``: an object (KServe's map of names to values), empty when absent."""
    parameters = item.get("parameters")
    if parameters is None:
        return {}
    if not isinstance(parameters, dict):
        raise RequestInvalid(
            f"{where}.parameters: expected an object, got {type(parameters).__name__}", field=f"{where}.parameters"
        )
    return parameters


def _shape(item: dict[str, Any], expected: dict[str, Any]) -> list[int]:
    """An input's shape, after checking its datatype and shape against the graph's input ``expected``."""
    name, want, dims = expected["name"], KSERVE_DTYPES[expected["data_type"]], expected["dims"]
    if item.get("datatype") != want:
        raise RequestInvalid(
            f"input '{name}': datatype {shown(repr(item.get('datatype')))}, expected {want}", field=name
        )
    shape = item.get("shape")
    if not (
        isinstance(shape, list)
        and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape)
        and len(shape) == len(dims) + 1
        and all(d == -1 or d == s for d, s in zip(dims, shape[1:]))
    ):
        raise RequestInvalid(
            f"input '{name}': shape {shown(repr(shape))}, expected [B, {', '.join(map(str, dims))}]", field=name
        )
    return shape


def _data(
    item: dict[str, Any], shape: list[int], dtype: np.dtype, binary: memoryview, offset: int
) -> tuple[np.ndarray, int]:
    """An input's values: from the binary part (binary tensor extension) or from its JSON ``data``."""
    name, count = item["name"], int(np.prod(shape))
    size = _parameters(item, f"input '{name}'").get("binary_data_size")
    if size is not None:
        if not isinstance(size, int) or size != count * dtype.itemsize or offset + size > len(binary):
            raise RequestInvalid(
                f"input '{name}': binary_data_size {shown(repr(size))} does not fit shape {shape} "
                f"({count * dtype.itemsize} bytes) in the {len(binary) - offset} bytes left",
                field=name,
            )
        return np.frombuffer(binary[offset : offset + size], dtype).reshape(shape), offset + size
    try:
        data = np.asarray(item.get("data"), dtype).reshape(-1)
    except (TypeError, ValueError, OverflowError) as exc:  # OverflowError: 300 or -1 as UINT8
        raise RequestInvalid(
            f"input '{name}': data cannot be read as {item['datatype']} ({shown(str(exc))})", field=name
        ) from None
    if data.size != count:
        raise RequestInvalid(f"input '{name}': {data.size} values in data, shape {shape} needs {count}", field=name)
    return data.reshape(shape), offset


def _inputs(
    doc: dict[str, Any], binary: bytes, config: dict[str, Any], max_frames: int
) -> tuple[np.ndarray, np.ndarray]:
    """Names, datatypes, shapes and the frame count first (cheap), then the values."""
    expected = {t["name"]: t for t in config["input"]}
    given = {item["name"]: item for item in doc["inputs"]}  # each an object with a string name (_split_body)
    if len(given) != len(doc["inputs"]) or set(given) != set(expected):
        names = listed([repr(item["name"]) for item in doc["inputs"]])
        raise RequestInvalid(f"inputs: got [{names}], expected exactly {sorted(expected)} once each", field="inputs")
    shapes = {name: _shape(item, expected[name]) for name, item in given.items()}
    frames = {shape[0] for shape in shapes.values()}
    if len(frames) != 1 or 0 in frames:
        raise RequestInvalid(
            f"inputs: {INPUT_IMAGES} has {shapes[INPUT_IMAGES][0]} frames, {INPUT_CAMERA_VALID} "
            f"{shapes[INPUT_CAMERA_VALID][0]}; expected the same, at least 1",
            field="inputs",
        )
    if frames.pop() > max_frames:
        raise RequestInvalid(
            f"inputs: {shapes[INPUT_IMAGES][0]} frames, at most max_batch_size={max_frames} per request "
            "(max_batch_frames, and what fits in max_body_bytes)",
            field="inputs",
        )
    view, offset, arrays = memoryview(binary), 0, {}
    for item in doc["inputs"]:  # binary data follows the header in the order of the inputs
        dtype = np.dtype(_NUMPY[item["datatype"]])
        arrays[item["name"]], offset = _data(item, shapes[item["name"]], dtype, view, offset)
    return arrays[INPUT_IMAGES], arrays[INPUT_CAMERA_VALID]


def _wanted(doc: dict[str, Any]) -> list[tuple[str, bool]]:
    """(output name, as binary) in the order asked for; all outputs when none are named."""
    default_binary = bool(_parameters(doc, "request").get("binary_data_output", False))
    asked = doc.get("outputs")
    if asked is None:
        return [(name, default_binary) for name in OUTPUTS]
    if not isinstance(asked, list) or not all(isinstance(o, dict) and o.get("name") in OUTPUTS for o in asked):
        raise RequestInvalid(
            f"outputs: expected a list of {{'name': one of {', '.join(OUTPUTS)}}}, got {shown(repr(asked))}",
            field="outputs",
        )
    return [
        (o["name"], bool(_parameters(o, f"output '{o['name']}'").get("binary_data", default_binary))) for o in asked
    ]


def _answer(name: str, doc: dict[str, Any], outputs: dict[str, np.ndarray], wanted: list[tuple[str, bool]]) -> Response:
    described, blobs = [], []
    for output, binary in wanted:
        array = np.ascontiguousarray(outputs[output])
        entry: dict[str, Any] = {"name": output, "datatype": _KSERVE[array.dtype], "shape": list(array.shape)}
        if binary:
            blobs.append(array.tobytes())
            entry["parameters"] = {"binary_data_size": len(blobs[-1])}
        else:
            entry["data"] = array.reshape(-1).tolist()
        described.append(entry)
    body: dict[str, Any] = {"model_name": name, "model_version": VERSION, "outputs": described}
    if "id" in doc:
        body["id"] = doc["id"]
    header = json.dumps(body).encode()
    if not blobs:
        return Response(header, media_type="application/json")
    return Response(
        header + b"".join(blobs), media_type="application/octet-stream", headers={HEADER_LENGTH: str(len(header))}
    )


def _limiter(request: Request, workers: int) -> anyio.CapacityLimiter:
    limiter = getattr(request.app.state, "kserve_limiter", None)
    if limiter is None:
        limiter = request.app.state.kserve_limiter = anyio.CapacityLimiter(workers)
    return limiter


@router.post("/models/{name}/infer", dependencies=_keyed)
@router.post("/models/{name}/versions/{version}/infer", dependencies=_keyed)
async def infer(name: str, request: Request, service: ServiceDep, version: str | None = None) -> Response:
    _check_model(service, name, version)
    ticket = service.admit()  # a queue place before the body is read: a full queue refuses at once
    try:
        detector, settings = service.detector, service.settings
        if detector is None:
            raise Unavailable("model: not loaded yet", field="model", retry_after=settings.retry_after_s)
        try:
            body = await asyncio.wait_for(request.body(), settings.request_timeout_s)
        except asyncio.TimeoutError:
            raise RequestTimeout(
                f"body: not received within request_timeout_s={settings.request_timeout_s:g} s", field="body"
            ) from None
        doc, binary = _split_body(body, request.headers.get(HEADER_LENGTH))
        config = await _config(request, service)
        wanted = _wanted(doc)
        images, valid = _inputs(doc, binary, config, config["max_batch_size"])
        try:
            with anyio.fail_after(settings.request_timeout_s):
                arrays = await anyio.to_thread.run_sync(
                    partial(detector.run_arrays, images, valid),
                    limiter=_limiter(request, settings.workers),
                    abandon_on_cancel=True,
                )
        except TimeoutError:
            raise InferenceTimeout(
                f"result: not ready within request_timeout_s={settings.request_timeout_s:g} s",
                field="request_timeout_s",
            ) from None
        return _answer(name, doc, dict(zip(OUTPUTS, arrays)), wanted)
    finally:
        ticket.release()
