"""Request bodies of /detect and /detect/batch -> checked encoded frames and options, refusing early and by name.

The multipart and JSON formats are read here; what a frame and its options must be (the same for
every format, and for /stream's frames) is checked in ``intake``. Order of the checks, cheapest
first, so a bad request costs little:

1. the request's Content-Type: multipart/form-data or application/json, and no
   Content-Encoding (images are compressed already), else 415;
2. the body's structure: a multipart body must end with its closing boundary (a body cut short
   is named as such, not reported as a missing camera), part headers must be of sane length,
   JSON must parse (a number with thousands of digits is named by its field), else 400/422;
3. part and field names: every camera known, none twice (in a batch ``0.front`` and ``00.front``
   are the same camera of the same frame), frame indices in ASCII digits, none missing (unless
   ``allow_missing_cameras``), options known and valid, else 422;
4. each image's declared content type (415) and its first bytes: PNG or JPEG signature (415);
5. each image's width and height read from its PNG/JPEG header, before any decoding: they must
   be the model's (422). A tiny file claiming 60000x60000 pixels (a decompression bomb) is
   refused here and never reaches the decoder;
6. decoding, in a thread, before the request takes a queue place (too many JPEG scans, corrupt
   data: 422; ``intake.decode_frames``, see ``fisheye_infer.runtime.codec``).

Steps 1-3 are this module's; 3 (options), 4 and 5 are ``intake``'s, called from here.
The body size limit (413) is enforced earlier, while the body is read (``middleware.py``).
Messages repeat at most a bounded part of what the client sent (``errors.shown``/``listed``).
"""

from __future__ import annotations

import base64
import binascii
import re

from pydantic import ValidationError
from python_multipart.multipart import parse_options_header
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import Request

from fisheye_infer.service.errors import BadRequest, RequestInvalid, ServiceError, UnsupportedMediaType, shown
from fisheye_infer.service.intake import (
    OPTION_FIELDS,
    EncodedFrame,
    FrameSpec,
    check_classes,
    check_frames,
    parse_options,
    refusal,
)
from fisheye_infer.service.schemas import BatchJsonRequest, DetectJsonRequest, DetectOptions

__all__ = ["read_request", "MAX_INDEX_DIGITS"]

MAX_INDEX_DIGITS = 6  # frame indices in batch part names
_KEY_BEFORE_NUMBER = re.compile(rb'"((?:[^"\\]|\\.){1,200})"\s*:\s*\[?\s*[-+0-9.eE]*$')
_JSON_POSITION = re.compile(r"line (\d+) column (\d+)")


def _media_type(request: Request) -> str:
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


def _boundary(request: Request) -> bytes | None:
    _, params = parse_options_header(request.headers.get("content-type", ""))
    return params.get(b"boundary") or None


def _check_closed(body: bytes, boundary: bytes) -> None:
    """A multipart body ends with ``--boundary--``; without it the upload was cut short."""
    last = body.rfind(b"--" + boundary)
    end = last + 2 + len(boundary)
    if last < 0 or body[end : end + 2] != b"--":
        raise BadRequest(
            f"multipart body: ended before its closing boundary '--{shown(boundary.decode('latin-1'))}--' "
            f"({len(body)} bytes received); the upload was cut short or the body is not the multipart it claims",
            field="body",
        )


def _parse_failure(exc: StarletteHTTPException, body: bytes, boundary: bytes | None) -> ServiceError:
    """Name what the multipart parser refused: a part whose headers are too long is named by its part name."""
    cause = exc.__context__.__cause__ if exc.__context__ is not None else None
    reason = str(cause) if cause is not None else str(exc.detail)
    offset = getattr(cause, "offset", -1)
    if "header size" in reason and boundary and offset >= 0:
        start = max(body.rfind(b"--" + boundary, 0, offset + 1), 0)
        found = re.search(rb'name="([^"]*)', body[start : start + (1 << 20)])
        if found:
            name = found.group(1).decode("utf-8", "replace")
            return RequestInvalid(
                f"part '{shown(name)}': its name or headers are too long ({reason.lower()}); "
                "expected a camera name or an option",
                field=name,
            )
    if "Field exceeded" in reason:
        return BadRequest(
            f"multipart body: {reason} (option fields are short text; images go in file parts)", field="body"
        )
    return BadRequest(
        f"multipart body: {exc.detail} ({reason})" if cause is not None else f"multipart body: {exc.detail}",
        field="body",
    )


async def _read_form(
    request: Request, spec: FrameSpec, batch: bool
) -> tuple[list[tuple[str, UploadFile]], dict[str, str]]:
    # the whole body first (bounded by max_body_bytes): its end is checked, and parse errors can be located
    body = await request.body()
    boundary = _boundary(request)
    if boundary:
        _check_closed(body, boundary)
    # room for a few parts too many, so that an unknown or repeated camera is refused by name
    max_files = len(spec.cameras) * ((spec.max_batch_frames if batch else 1) + 1)
    try:
        form = await request.form(max_files=max_files, max_fields=2 * len(OPTION_FIELDS), max_part_size=64 * 1024)
    except StarletteHTTPException as exc:
        if "Too many files" in str(exc.detail):
            expected = len(spec.cameras) * (spec.max_batch_frames if batch else 1)
            raise RequestInvalid(
                f"images: more than {max_files} image parts, expected at most {expected} ({len(spec.cameras)} cameras"
                f"{f' x max_batch_frames={spec.max_batch_frames}' if batch else ''})",
                field="images",
            ) from None
        raise _parse_failure(exc, body, boundary) from None
    try:
        return _split_form(form.multi_items(), spec, batch)
    except ServiceError:
        await form.close()
        raise


def _split_form(
    items: list[tuple[str, UploadFile | str]], spec: FrameSpec, batch: bool
) -> tuple[list[tuple[str, UploadFile]], dict[str, str]]:
    files: list[tuple[str, UploadFile]] = []
    fields: dict[str, str] = {}
    for name, value in items:
        if isinstance(value, UploadFile):
            if any(name == seen for seen, _ in files):
                raise RequestInvalid(f"camera '{shown(name)}': given twice", field=name)
            files.append((name, value))
            continue
        if name not in OPTION_FIELDS:
            is_camera = name in spec.cameras or (batch and name.partition(".")[2] in spec.cameras)
            if is_camera:
                raise RequestInvalid(
                    f"camera '{shown(name)}': send the image as a file part (with a filename), got a text field",
                    field=name,
                )
            raise RequestInvalid(
                f"field '{shown(name)}': not an image part or option (options: {', '.join(OPTION_FIELDS)})", field=name
            )
        if name in fields:
            raise RequestInvalid(f"field '{shown(name)}': given twice", field=name)
        fields[name] = value
    return files, fields


def _batch_index(name: str, spec: FrameSpec) -> tuple[int, str]:
    """``'<frame index>.<camera>'`` -> (index, camera); the index in ASCII digits ("²" is a digit to Python,
    not here)."""
    index, dot, camera = name.partition(".")
    if dot and index.isascii() and index.isdigit() and len(index) > MAX_INDEX_DIGITS:
        raise RequestInvalid(
            f"part '{shown(name)}': frame index of {len(index)} digits; at most {MAX_INDEX_DIGITS} digits are read, "
            f"and a batch holds frames 0..{spec.max_batch_frames - 1} (max_batch_frames={spec.max_batch_frames})",
            field=shown(name),
        )
    if not dot or not (index.isascii() and index.isdigit()):
        raise RequestInvalid(
            f"part '{shown(name)}': expected '<frame index>.<camera>' with the index in digits 0-9, "
            f"e.g. '0.{spec.cameras[0]}'",
            field=name,
        )
    return int(index), camera


async def _multipart(
    request: Request, spec: FrameSpec, batch: bool
) -> tuple[list[EncodedFrame], DetectOptions, list[dict[str, str | None]]]:
    files, fields = await _read_form(request, spec, batch)
    try:
        options = parse_options(fields, spec)
        frames: dict[int, EncodedFrame] = {}
        types: dict[int, dict[str, str | None]] = {}
        for name, upload in files:
            index, camera = _batch_index(name, spec) if batch else (0, name)
            if camera in frames.get(index, {}):
                raise RequestInvalid(
                    f"frame {index}: camera '{shown(camera)}' given twice (part '{shown(name)}' repeats an earlier "
                    "part)",
                    field=f"{index}.{camera}",
                )
            frames.setdefault(index, {})[camera] = await upload.read()
            types.setdefault(index, {})[camera] = upload.content_type
    finally:
        for _, upload in files:
            await upload.close()
    count = max(frames, default=-1) + 1
    spec.check_frame_count(count)
    gaps = [i for i in range(count) if i not in frames]
    if gaps:
        raise RequestInvalid(
            f"frame {gaps[0]}: no image parts, expected frames numbered 0..{count - 1} without gaps", field=str(gaps[0])
        )
    return [frames[i] for i in range(count)], options, [types[i] for i in range(count)]


def _number_field(body: bytes, message: str) -> str | None:
    """The key whose value a JSON parse error at "line L column C" points into, if it is a number."""
    where = _JSON_POSITION.search(message)
    if where is None:
        return None
    line, column = int(where.group(1)), int(where.group(2))
    lines = body.split(b"\n", line - 1)
    pos = sum(len(text) + 1 for text in lines[: line - 1]) + column
    found = _KEY_BEFORE_NUMBER.search(body[max(0, pos - 8192) : pos])
    return found.group(1).decode("utf-8", "replace") if found else None


def _json_refusal(exc: ValidationError, body: bytes) -> ServiceError:
    """A JSON body that does not parse (400; a number too long to read: 422 naming its key), else ``refusal``."""
    first = exc.errors()[0]
    if first["type"] != "json_invalid":
        return refusal(exc)
    field = _number_field(body, first["msg"]) if "number out of range" in first["msg"] else None
    if field is not None:
        return RequestInvalid(
            f"{shown(field)}: number out of range (too many digits to read); expected an ordinary number",
            field=field,
        )
    return BadRequest(f"JSON body: {first['msg']}", field="body")


def _b64(text: str, label: str) -> bytes:
    try:
        return base64.b64decode(text, validate=True)
    except (binascii.Error, ValueError) as exc:
        raise RequestInvalid(f"camera '{label}': not valid base64 ({exc})", field=label) from None


async def _json(request: Request, spec: FrameSpec, batch: bool) -> tuple[list[EncodedFrame], DetectOptions]:
    body = await request.body()
    try:
        doc: DetectJsonRequest | BatchJsonRequest = (
            BatchJsonRequest if batch else DetectJsonRequest
        ).model_validate_json(body)
    except ValidationError as exc:
        raise _json_refusal(exc, body) from None
    options = check_classes(DetectOptions.model_validate(doc.model_dump(include=set(OPTION_FIELDS))), spec)
    raw = [f.images for f in doc.frames] if isinstance(doc, BatchJsonRequest) else [doc.images]
    spec.check_frame_count(len(raw))
    return [{camera: _b64(text, camera) for camera, text in images.items()} for images in raw], options


async def read_request(request: Request, spec: FrameSpec, batch: bool) -> tuple[list[EncodedFrame], DetectOptions]:
    """Read, parse and check (without decoding) a /detect or /detect/batch body."""
    media = _media_type(request)
    encoding = request.headers.get("content-encoding", "identity").strip().lower()
    if encoding not in ("", "identity"):
        raise UnsupportedMediaType(
            f"Content-Encoding: got '{shown(encoding)}', expected none; send the body uncompressed "
            "(JPEG and PNG images are compressed already)",
            field="Content-Encoding",
        )
    types = None
    if media == "multipart/form-data":
        frames, options, types = await _multipart(request, spec, batch)
    elif media == "application/json" or media.endswith("+json"):
        frames, options = await _json(request, spec, batch)
    else:
        raise UnsupportedMediaType(
            f"Content-Type: got '{shown(media) or 'none'}', expected multipart/form-data or application/json",
            field="Content-Type",
        )
    if not frames:
        raise RequestInvalid(
            f"images: none given, expected one part per camera ({', '.join(spec.cameras)})", field="images"
        )
    check_frames(frames, spec, options, types)
    return frames, options
