"""Request bodies -> checked encoded images -> decoded frames, refusing early and by name.

Order of the checks, cheapest first, so a bad request costs little:

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
   data: 422; see ``fisheye_infer.runtime.codec``).

The body size limit (413) is enforced earlier, while the body is read (``middleware.py``).
Messages repeat at most a bounded part of what the client sent (``errors.shown``/``listed``).
"""

from __future__ import annotations

import base64
import binascii
import re
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError
from python_multipart.multipart import parse_options_header
from starlette.datastructures import UploadFile
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.requests import Request

from fisheye_infer.errors import FisheyeInferError, FrameError
from fisheye_infer.runtime.detector import DetectorInfo
from fisheye_infer.runtime.preprocess import decode_image, encoded_image_size
from fisheye_infer.service.errors import BadRequest, RequestInvalid, ServiceError, UnsupportedMediaType, listed, shown
from fisheye_infer.service.schemas import BatchJsonRequest, DetectJsonRequest, DetectOptions

__all__ = [
    "FrameSpec",
    "EncodedFrame",
    "OPTION_FIELDS",
    "read_request",
    "parse_options",
    "check_frame",
    "decode_frames",
]

EncodedFrame = dict[str, bytes]
OPTION_FIELDS = ("score_threshold", "classes", "nms", "allow_missing_cameras")
PART_TYPES = ("image/jpeg", "image/png", "image/jpg", "image/pjpeg", "application/octet-stream")
_PNG, _JPEG = b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"
MAX_INDEX_DIGITS = 6  # frame indices in batch part names
_KEY_BEFORE_NUMBER = re.compile(rb'"((?:[^"\\]|\\.){1,200})"\s*:\s*\[?\s*[-+0-9.eE]*$')
_JSON_POSITION = re.compile(r"line (\d+) column (\d+)")


@dataclass(frozen=True)
class FrameSpec:
    """What a frame must look like for this model and service."""

    cameras: tuple[str, ...]
    image_size: tuple[int, int]  # (width, height)
    classes: tuple[str, ...]
    max_batch_frames: int

    @classmethod
    def of(cls, info: DetectorInfo, max_batch_frames: int) -> FrameSpec:
        return cls(info.cameras, info.image_size, info.classes, max_batch_frames)

    def check_frame_count(self, count: int) -> None:
        """At most ``max_batch_frames`` frames in one request (422 beyond)."""
        if count > self.max_batch_frames:
            raise RequestInvalid(
                f"frames: got {count}, at most max_batch_frames={self.max_batch_frames} per request", field="frames"
            )


# -- options ------------------------------------------------------------------------------------


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


def _invalid(exc: ValidationError, prefix: str = "", body: bytes = b"") -> ServiceError:
    first = exc.errors()[0]
    if first["type"] == "json_invalid":
        field = _number_field(body, first["msg"]) if "number out of range" in first["msg"] else None
        if field is not None:
            return RequestInvalid(
                f"{shown(field)}: number out of range (too many digits to read); expected an ordinary number",
                field=field,
            )
        return BadRequest(f"JSON body: {first['msg']}", field="body")
    loc = prefix + ".".join(str(x) for x in first["loc"])
    got = repr(first.get("input"))
    got = got if len(got) <= 60 else got[:57] + "..."
    return RequestInvalid(f"{loc or 'body'}: {first['msg']} (got {got})", field=loc or "body")


def _check_classes(options: DetectOptions, spec: FrameSpec) -> DetectOptions:
    unknown = sorted(set(options.classes or ()) - set(spec.classes))
    if unknown:
        raise RequestInvalid(
            f"classes: unknown {listed(unknown)}; the model's classes are {', '.join(spec.classes)}", field="classes"
        )
    return options


def parse_options(fields: Mapping[str, str], spec: FrameSpec) -> DetectOptions:
    """Options given as strings (form fields, query parameters); empty values count as absent."""
    raw: dict[str, object] = {k: v for k, v in fields.items() if v != ""}
    if "classes" in raw:
        raw["classes"] = [c.strip() for c in str(raw["classes"]).split(",") if c.strip()]
    try:
        return _check_classes(DetectOptions.model_validate(raw), spec)
    except ValidationError as exc:
        raise _invalid(exc) from None


# -- images -------------------------------------------------------------------------------------


def _check_image(data: bytes, label: str, spec: FrameSpec, declared: str | None = None) -> None:
    media = (declared or "").split(";")[0].strip().lower()
    if media and media not in PART_TYPES:
        raise UnsupportedMediaType(
            f"camera '{label}': content type {shown(media)}, expected image/jpeg or image/png", field=label
        )
    if not data:
        raise RequestInvalid(
            f"camera '{label}': empty image, expected a {spec.image_size[0]}x{spec.image_size[1]} JPEG or PNG",
            field=label,
        )
    if not (data.startswith(_PNG) or data.startswith(_JPEG)):
        raise UnsupportedMediaType(
            f"camera '{label}': not a JPEG or PNG image (first bytes {data[:8].hex()})", field=label
        )
    size = encoded_image_size(data)
    width, height = spec.image_size
    if size is None:
        raise RequestInvalid(
            f"camera '{label}': image header is truncated or unreadable (no width and height found), "
            f"expected a {width}x{height} image",
            field=label,
        )
    if size != (width, height):
        raise RequestInvalid(
            f"camera '{label}': image is {size[0]}x{size[1]}, model expects {width}x{height}", field=label
        )


def check_frame(
    images: Mapping[str, bytes], spec: FrameSpec, options: DetectOptions, types: Mapping[str, str | None] | None = None
) -> None:
    """Names, presence, content types and header sizes of one frame's images (no decoding)."""
    unknown = [name for name in images if name not in spec.cameras]
    if unknown:
        raise RequestInvalid(
            f"camera '{shown(unknown[0])}': not a camera of this model (cameras: {', '.join(spec.cameras)})",
            field=unknown[0],
        )
    if not images:
        raise RequestInvalid(f"images: none given, expected one per camera ({', '.join(spec.cameras)})", field="images")
    missing = [c for c in spec.cameras if c not in images]
    if missing and not options.allow_missing_cameras:
        raise RequestInvalid(
            f"camera '{missing[0]}': missing (expected all of {', '.join(spec.cameras)}; "
            f"set allow_missing_cameras to run without {', '.join(missing)})",
            field=missing[0],
        )
    for camera, data in images.items():
        _check_image(data, camera, spec, (types or {}).get(camera))


def _in_frame(index: int, exc: FisheyeInferError) -> FisheyeInferError:
    """The same refusal, naming the frame of a batch (``field`` becomes ``<frame>.<camera>``)."""
    if not isinstance(exc, ServiceError):
        return RequestInvalid(f"frame {index}: {exc}", field=str(index))
    field = f"{index}.{exc.field}" if exc.field else str(index)
    return type(exc)(f"frame {index}: {exc}", field=field, retry_after=exc.retry_after)


def check_frames(
    frames: list[EncodedFrame],
    spec: FrameSpec,
    options: DetectOptions,
    types: list[dict[str, str | None]] | None = None,
) -> None:
    spec.check_frame_count(len(frames))
    for i, frame in enumerate(frames):
        try:
            check_frame(frame, spec, options, types[i] if types else None)
        except FisheyeInferError as exc:
            raise (_in_frame(i, exc) if len(frames) > 1 else exc) from None


def decode_frames(
    frames: list[EncodedFrame],
    spec: FrameSpec,
    map_images: Callable[..., Iterable[Any]] = map,
) -> tuple[list[list[np.ndarray | None]], list[float]]:
    """Decode checked frames (call off the event loop); returns the frames and each one's decode time in ms.

    ``map_images`` runs the per-image decoding (the Detector's ``map_images``: its decode threads,
    so a request's cameras decode in parallel); the error reported is the first bad image in
    frame and camera order. Each frame's time is the request's decoding wall time shared evenly.
    """

    def one(task: tuple[int, str, bytes | None]) -> np.ndarray | None:
        index, camera, data = task
        try:
            return None if data is None else decode_image(data, camera, spec.image_size)
        except FrameError as exc:
            error = RequestInvalid(str(exc), field=camera)
            raise (_in_frame(index, error) if len(frames) > 1 else error) from None

    if not frames:
        return [], []
    t0 = time.perf_counter()
    decoded = list(
        map_images(one, [(i, camera, frame.get(camera)) for i, frame in enumerate(frames) for camera in spec.cameras])
    )
    per_frame = (time.perf_counter() - t0) * 1e3 / len(frames)
    n = len(spec.cameras)
    return [decoded[i * n : (i + 1) * n] for i in range(len(frames))], [per_frame] * len(frames)


# -- request bodies -----------------------------------------------------------------------------


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
    if not dot or not (index.isascii() and index.isdigit()) or len(index) > MAX_INDEX_DIGITS:
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
        raise _invalid(exc, body=body) from None
    options = _check_classes(DetectOptions.model_validate(doc.model_dump(include=set(OPTION_FIELDS))), spec)
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
