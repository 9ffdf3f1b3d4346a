"""The OpenAPI document, with request bodies that name this model's cameras.

The detect handlers read their bodies themselves (so that size, content-type and camera checks
come first and give the documented status codes), which leaves FastAPI unaware of them. This
module writes both bodies into the schema: multipart (one binary part per camera, or
``<frame>.<camera>`` for batches, plus the option fields) and JSON (``DetectJsonRequest``,
``BatchJsonRequest``), and adds the ``/stream`` answers (``StreamResult``, ``StreamError``) to
the components, since OpenAPI has no place for WebSocket messages. The camera names come from the
loaded model, so the schema is built after the lifespan loaded it, and cached from then on.
"""

from __future__ import annotations

import re
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi

from fisheye_infer.service.schemas import BatchJsonRequest, DetectJsonRequest, FrameIn, StreamError, StreamResult
from fisheye_infer.service.state import Service

__all__ = ["install_openapi"]

_REF = "#/components/schemas/{model}"
_BINARY = {"type": "string", "format": "binary", "contentMediaType": "application/octet-stream"}


def _options(classes: tuple[str, ...]) -> dict[str, Any]:
    return {
        "score_threshold": {
            "type": "number",
            "minimum": 0,
            "maximum": 1,
            "description": "drop boxes scoring below this",
        },
        "classes": {"type": "string", "description": f"comma-separated class names to keep, of: {', '.join(classes)}"},
        "nms": {"type": "string", "enum": ["rotated", "circle"], "description": "optional BEV NMS"},
        "allow_missing_cameras": {
            "type": "boolean",
            "description": "run with the cameras given instead of refusing the frame",
        },
    }


def _image(camera: str, size: tuple[int, int]) -> dict[str, Any]:
    return {**_BINARY, "description": f"camera '{camera}': JPEG or PNG, {size[0]}x{size[1]}"}


def _multipart_schemas(service: Service) -> dict[str, Any]:
    if service.detector is None:
        return {
            "DetectMultipart": {
                "type": "object",
                "description": "one binary part per camera (see GET /model) and the option fields",
            },
            "BatchMultipart": {
                "type": "object",
                "description": "parts named '<frame index>.<camera>' and the option fields",
            },
        }
    info = service.detector.info
    cameras, size = info.cameras, info.image_size
    single = {c: _image(c, size) for c in cameras}
    first = {f"0.{c}": _image(c, size) for c in cameras}
    pattern = r"^[0-9]+\.(" + "|".join(re.escape(c) for c in cameras) + r")$"
    return {
        "DetectMultipart": {
            "type": "object",
            "description": "one file part per camera, named by the camera, and the option fields",
            "properties": {**single, **_options(info.classes)},
            "required": list(cameras),
            "additionalProperties": False,
        },
        "BatchMultipart": {
            "type": "object",
            "description": (
                "file parts named '<frame index>.<camera>' for frames 0..n-1 "
                f"(n <= {service.settings.max_batch_frames}), and the option fields"
            ),
            "properties": {**first, **_options(info.classes)},
            "patternProperties": {pattern: _image("<camera>", size)},
            "required": list(first),
            "additionalProperties": False,
        },
    }


def _json_schemas() -> dict[str, Any]:
    """Request bodies, and the /stream messages (no route declares them; clients want them too)."""
    out: dict[str, Any] = {}
    for model in (FrameIn, DetectJsonRequest, BatchJsonRequest, StreamResult, StreamError):
        schema = model.model_json_schema(ref_template=_REF)
        out.update(schema.pop("$defs", {}))
        out[model.__name__] = schema
    return out


def _body(multipart: str, json_model: str) -> dict[str, Any]:
    return {
        "required": True,
        "content": {
            "multipart/form-data": {"schema": {"$ref": _REF.format(model=multipart)}},
            "application/json": {"schema": {"$ref": _REF.format(model=json_model)}},
        },
    }


def install_openapi(app: FastAPI, service: Service) -> None:
    """Replace ``app.openapi`` with the builder above."""

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        components.update(_json_schemas())
        components.update(_multipart_schemas(service))
        schema["paths"]["/detect"]["post"]["requestBody"] = _body("DetectMultipart", "DetectJsonRequest")
        schema["paths"]["/detect/batch"]["post"]["requestBody"] = _body("BatchMultipart", "BatchJsonRequest")
        if service.detector is not None:  # camera names known: keep it
            app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]
