"""The service's own refusals, and the one place where errors become HTTP answers.

The service extends the runtime's tree (``fisheye_infer.errors``) with the refusals only a
network front end makes, each carrying its status code:

    FisheyeInferError
     ├── FrameError            422  an image or camera is unusable (the runtime's message)
     ├── OptionError           422  an option out of range (the runtime's message)
     ├── ConfigError           422
     ├── ArtifactError         500  the model file is wrong: an operator's problem, not the client's
     ├── InferenceError        500
     └── ServiceError               (this module)
          ├── BadRequest           400  the body cannot be parsed (malformed multipart or JSON)
          ├── Unauthorized         401  X-API-Key missing or wrong
          ├── RequestTimeout       408  headers or body did not arrive in time (connection closed)
          ├── PayloadTooLarge      413  body or stream message over max_body_bytes (connection closed)
          ├── UnsupportedMediaType 415  request or image part is not multipart/JSON, JPEG/PNG
          ├── RequestInvalid       422  a field, camera name, count or image size is refused
          ├── Unavailable          503  queue full, draining or not ready (with Retry-After)
          └── InferenceTimeout     504  the result did not come within request_timeout_s

``error_response`` is the single mapping; ``app.py`` registers it once for the whole tree.
Every answer is an ``ErrorOut`` JSON body naming the field or camera that was refused. What a
message repeats from the request is capped (``shown``, ``listed``): a 10 kB part name or 100,000
unknown class names are not echoed back whole.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from fisheye_infer.errors import ArtifactError, ConfigError, FisheyeInferError, FrameError, InferenceError, OptionError

__all__ = [
    "ServiceError",
    "BadRequest",
    "Unauthorized",
    "RequestTimeout",
    "PayloadTooLarge",
    "UnsupportedMediaType",
    "RequestInvalid",
    "Unavailable",
    "InferenceTimeout",
    "shown",
    "listed",
    "status_of",
    "error_body",
    "error_response",
    "handle_fisheye_error",
]

if TYPE_CHECKING:  # the classes stay importable without the web stack (stream clients use them)
    from starlette.requests import Request
    from starlette.responses import JSONResponse

log = logging.getLogger("fisheye_infer.service")


MAX_SHOWN_CHARS = 64
MAX_LISTED = 20


def shown(text: str, limit: int = MAX_SHOWN_CHARS) -> str:
    """``text`` as a message repeats it: cut to ``limit`` characters, saying how long it was."""
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def listed(names: list[str] | tuple[str, ...], limit: int = MAX_LISTED) -> str:
    """At most ``limit`` names, each ``shown``, then "and N more"."""
    text = ", ".join(shown(str(n)) for n in names[:limit])
    return text + (f" and {len(names) - limit} more" if len(names) > limit else "")


class ServiceError(FisheyeInferError):
    """A refusal by the service; ``field`` names the form field, camera or header concerned."""

    status = 500
    closes_connection = False  # answered with Connection: close (the rest of the request is not read)

    def __init__(self, message: str, *, field: str | None = None, retry_after: int | None = None) -> None:
        super().__init__(message)
        self.field = None if field is None else shown(field)
        self.retry_after = retry_after


class BadRequest(ServiceError):
    """The body is not well-formed multipart or JSON."""

    status = 400


class Unauthorized(ServiceError):
    """The X-API-Key header is missing or does not match."""

    status = 401


class RequestTimeout(ServiceError):
    """The headers or the body did not arrive in time (a stalled or very slow upload)."""

    status = 408
    closes_connection = True


class PayloadTooLarge(ServiceError):
    """The body (or a stream message) is larger than max_body_bytes."""

    status = 413
    closes_connection = True


class UnsupportedMediaType(ServiceError):
    """The request is neither multipart nor JSON, or an image part is not JPEG or PNG."""

    status = 415


class RequestInvalid(ServiceError, ValueError):
    """A field, camera name, image count or image size is refused."""

    status = 422


class Unavailable(ServiceError):
    """The queue is full, the service is draining, or the model is not ready: try again later."""

    status = 503


class InferenceTimeout(ServiceError):
    """The result did not arrive within request_timeout_s."""

    status = 504


_STATUS: tuple[tuple[type[FisheyeInferError], int], ...] = (
    (FrameError, 422),
    (OptionError, 422),
    (ConfigError, 422),
    (ArtifactError, 500),
    (InferenceError, 500),
)


def status_of(exc: FisheyeInferError) -> int:
    if isinstance(exc, ServiceError):
        return exc.status
    for kind, status in _STATUS:
        if isinstance(exc, kind):
            return status
    return 500


def _field_of(exc: FisheyeInferError) -> str | None:
    """The camera or field a runtime message names (``camera 'front': ...`` -> ``front``)."""
    if isinstance(exc, ServiceError):
        return exc.field
    text = str(exc)
    if text.startswith("camera '"):
        return text[len("camera '") :].split("'", 1)[0]
    head = text.split(":", 1)[0]
    return head if head and " " not in head else None


def error_body(exc: FisheyeInferError) -> dict[str, object]:
    """The ``ErrorOut`` document for ``exc`` (also sent over the stream)."""
    return {"error": str(exc), "status": status_of(exc), "type": type(exc).__name__, "field": _field_of(exc)}


def error_response(exc: FisheyeInferError, close: bool = False) -> JSONResponse:
    """The answer to ``exc``; ``close`` (or the error's own ``closes_connection``) ends the connection after it."""
    from starlette.responses import JSONResponse

    status = status_of(exc)
    headers = {}
    if close or getattr(exc, "closes_connection", False):
        headers["Connection"] = "close"
    retry_after = getattr(exc, "retry_after", None)
    if retry_after is not None:
        headers["Retry-After"] = str(retry_after)
    if status == 503:  # overload, draining or warming up: an expected answer the client retries
        log.warning("%s: %s", type(exc).__name__, exc)
    elif status >= 500:
        log.error("%s: %s", type(exc).__name__, exc)
    return JSONResponse(error_body(exc), status_code=status, headers=headers)


async def handle_fisheye_error(request: Request, exc: Exception) -> JSONResponse:
    """The exception handler for the whole ``FisheyeInferError`` tree."""
    if not isinstance(exc, FisheyeInferError):  # registered for that class only
        raise exc
    return error_response(exc)
