"""What a frame and its options must be, checked before decoding and refused by name; then decoding.

Shared by every way frames arrive: the /detect bodies (``bodies``: multipart and JSON, which
read the request and call these checks) and /stream's frames (``routers/stream.py``), so a
frame is refused the same way, with the same message, whichever route it came by:

- options (``parse_options``): known fields, valid values, classes the model has, else 422;
- images (``check_frame``): every camera known, none missing (unless ``allow_missing_cameras``),
  each image's declared content type and first bytes a PNG or JPEG (415), its width and height
  read from its header, before any decoding, the model's (422). A tiny file claiming 60000x60000
  pixels (a decompression bomb) is refused here and never reaches the decoder;
- decoding (``decode_frames``), in a thread, before the request takes a queue place (too many
  JPEG scans, corrupt data: 422; see ``fisheye_infer.runtime.codec``).

Messages repeat at most a bounded part of what the client sent (``errors.shown``/``listed``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from fisheye_infer.errors import FisheyeInferError, FrameError
from fisheye_infer.runtime.detector import DetectorInfo
from fisheye_infer.runtime.preprocess import decode_image, encoded_image_size
from fisheye_infer.service.errors import RequestInvalid, ServiceError, UnsupportedMediaType, listed, shown
from fisheye_infer.service.schemas import DetectOptions

__all__ = [
    "FrameSpec",
    "EncodedFrame",
    "OPTION_FIELDS",
    "parse_options",
    "check_classes",
    "refusal",
    "check_frame",
    "check_frames",
    "decode_frames",
]

EncodedFrame = dict[str, bytes]
OPTION_FIELDS = ("score_threshold", "classes", "nms", "allow_missing_cameras")
PART_TYPES = ("image/jpeg", "image/png", "image/jpg", "image/pjpeg", "application/octet-stream")
_PNG, _JPEG = b"\x89PNG\r\n\x1a\n", b"\xff\xd8\xff"


@dataclass(frozen=True)
class FrameSpec:
    """What a frame must look like for this model and service."""

    cameras: tuple[str, ...]
    camera_sizes: tuple[tuple[int, int], ...]  # (width, height) of each camera's images, in camera order
    classes: tuple[str, ...]
    max_batch_frames: int

    @classmethod
    def of(cls, info: DetectorInfo, max_batch_frames: int) -> FrameSpec:
        return cls(info.cameras, info.camera_sizes, info.classes, max_batch_frames)

    def size_of(self, camera: str) -> tuple[int, int]:
        """(width, height) of ``camera``'s images (the first camera's for a name the model does not have)."""
        return dict(zip(self.cameras, self.camera_sizes)).get(camera, self.camera_sizes[0])

    def check_frame_count(self, count: int) -> None:
        """At most ``max_batch_frames`` frames in one request (422 beyond)."""
        if count > self.max_batch_frames:
            raise RequestInvalid(
                f"frames: got {count}, at most max_batch_frames={self.max_batch_frames} per request", field="frames"
            )


# -- options ------------------------------------------------------------------------------------


def refusal(exc: ValidationError, prefix: str = "") -> ServiceError:
    """A failed validation as a 422 naming the first bad field (``prefix`` + its location) and, briefly, its value."""
    first = exc.errors()[0]
    loc = prefix + ".".join(str(x) for x in first["loc"])
    got = repr(first.get("input"))
    got = got if len(got) <= 60 else got[:57] + "..."
    return RequestInvalid(f"{loc or 'body'}: {first['msg']} (got {got})", field=loc or "body")


def check_classes(options: DetectOptions, spec: FrameSpec) -> DetectOptions:
    """The options, if the classes they select are the model's (422 naming the unknown ones)."""
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
        return check_classes(DetectOptions.model_validate(raw), spec)
    except ValidationError as exc:
        raise refusal(exc) from None


# -- images -------------------------------------------------------------------------------------


def _check_image(data: bytes, label: str, spec: FrameSpec, declared: str | None = None) -> None:
    media = (declared or "").split(";")[0].strip().lower()
    if media and media not in PART_TYPES:
        raise UnsupportedMediaType(
            f"camera '{label}': content type {shown(media)}, expected image/jpeg or image/png", field=label
        )
    if not data:
        raise RequestInvalid(
            f"camera '{label}': empty image, expected a {spec.size_of(label)[0]}x{spec.size_of(label)[1]} JPEG or PNG",
            field=label,
        )
    if not (data.startswith(_PNG) or data.startswith(_JPEG)):
        raise UnsupportedMediaType(
            f"camera '{label}': not a JPEG or PNG image (first bytes {data[:8].hex()})", field=label
        )
    size = encoded_image_size(data)
    width, height = spec.size_of(label)
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
    """``check_frame`` on each frame of a request; in a batch of several, the refusal names the frame."""
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
            return None if data is None else decode_image(data, camera, spec.size_of(camera))
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
