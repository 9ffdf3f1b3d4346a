"""Request and response models: the service's OpenAPI schema, in one place.

Families:

- options: ``DetectOptions`` -> ``DetectJsonRequest`` (one frame), ``BatchJsonRequest`` (several);
- results: ``DetectionOut`` (``Detections.to_dicts()`` rows) and ``RecordOut``
  (``Detections.to_nuscenes()`` records) -> ``FrameResult`` -> ``DetectResponse``,
  ``BatchResponse``, ``StreamResult``;
- service: ``ModelInfo`` (+ ``Limits``), ``Health``, ``Ready``, ``ErrorOut``, ``StreamError``.

Images in JSON bodies are base64 strings; multipart bodies carry the same options as form
fields (``classes`` comma-separated there).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

__all__ = [
    "DetectOptions",
    "DetectJsonRequest",
    "FrameIn",
    "BatchJsonRequest",
    "DetectionOut",
    "RecordOut",
    "Timings",
    "FrameResult",
    "DetectResponse",
    "BatchResponse",
    "StreamResult",
    "TrackOut",
    "StreamError",
    "ImageSize",
    "Limits",
    "ModelInfo",
    "Health",
    "Ready",
    "ErrorOut",
]


class _In(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DetectOptions(_In):
    """Per-request choices; the default is the official output set (no threshold, no NMS)."""

    score_threshold: float | None = Field(default=None, ge=0.0, le=1.0, description="drop boxes scoring below this")
    classes: list[str] | None = Field(
        default=None, description="keep only these class names (multipart: comma-separated)"
    )
    nms: Literal["rotated", "circle"] | None = Field(
        default=None, description="optional BEV NMS (the official output has none)"
    )
    allow_missing_cameras: bool = Field(
        default=False,
        description="run with the cameras given (degraded mode) instead of refusing a frame that lacks some",
    )


class FrameIn(_In):
    images: dict[str, str] = Field(description="camera name -> base64 of a JPEG or PNG image")


class DetectJsonRequest(DetectOptions):
    """One frame as JSON, for clients that cannot send multipart."""

    images: dict[str, str] = Field(description="camera name -> base64 of a JPEG or PNG image")


class BatchJsonRequest(DetectOptions):
    """Several frames as JSON; the options apply to every frame."""

    frames: list[FrameIn] = Field(min_length=1, description="frames in order; one result per frame, same order")


class DetectionOut(BaseModel):
    """One box as ``Detections.to_dicts()`` gives it: bottom-centred, lidar frame (x forward, y left, z up; m, rad)."""

    x: float
    y: float
    z_bottom: float
    l: float  # noqa: E741 (the box layout's name)
    w: float
    h: float
    yaw: float
    score: float
    label: int
    class_name: str


class RecordOut(BaseModel):
    """One box as ``Detections.to_nuscenes()`` gives it: gravity centre, size (w, l, h), quaternion."""

    translation: tuple[float, float, float]
    size: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    detection_name: str
    detection_score: float


class Timings(BaseModel):
    """Milliseconds per stage. With micro-batching, preprocess/inference/postprocess are the shared run's."""

    queue_wait: float = Field(description="admitted until a worker picked the frame up")
    decode: float = Field(description="header checks and JPEG/PNG decoding")
    preprocess: float
    inference: float
    postprocess: float


class FrameResult(BaseModel):
    detections: list[DetectionOut]
    records: list[RecordOut]
    cameras_used: list[str]
    timings_ms: Timings
    batch_size: int = Field(description="frames in the detect_batch call that produced this result")


class DetectResponse(FrameResult):
    model_id: str


class BatchResponse(BaseModel):
    model_id: str
    frames: list[FrameResult]


class TrackOut(DetectionOut):
    """One track as ``Tracks.to_dicts()`` gives it: its id, box (ego frame) and velocity over ground (m/s)."""

    track_id: int
    vx: float
    vy: float
    age: int = Field(description="frames since the track started")
    position_covariance: list[list[float]] | None = Field(
        default=None, description="2x2 covariance of the bird's-eye-view centre (m^2, ego frame)"
    )
    velocity_covariance: list[list[float]] | None = Field(
        default=None, description="2x2 covariance of the velocity ((m/s)^2, ego frame)"
    )


class StreamResult(DetectResponse):
    """The answer to one stream frame."""

    kind: Literal["result"] = "result"
    frame_id: int
    dropped: list[int] = Field(
        description="frame ids replaced by newer frames since the previous answer (latest frame wins)"
    )
    tracks: list[TrackOut] | None = Field(default=None, description="with track=true: the connection's tracks")


class ErrorOut(BaseModel):
    """Every refusal: the message names the field or camera and says what was expected."""

    error: str
    status: int
    type: str = Field(description="the error class, e.g. FrameError, RequestInvalid, Unavailable")
    field: str | None = Field(default=None, description="camera or field concerned, when there is one")


class StreamError(ErrorOut):
    """A stream frame that was refused; the connection stays open unless the header was unreadable."""

    kind: Literal["error"] = "error"
    frame_id: int | None
    dropped: list[int] = Field(default_factory=list)


class ImageSize(BaseModel):
    width: int
    height: int


class Limits(BaseModel):
    max_body_bytes: int
    max_batch_frames: int
    queue_size: int
    microbatch_max_size: int
    microbatch_max_wait_ms: float
    body_timeout_s: float = Field(description="a request's body must arrive within this time (408 beyond)")
    max_jpeg_scans: int = Field(description="scans per JPEG image (a progressive JPEG with more is refused, 422)")
    stream_protocol_version: int


class ModelInfo(BaseModel):
    architecture: str
    model_id: str
    classes: list[str]
    cameras: list[str] = Field(description="camera names in the model's input order: the multipart part names")
    image_size: ImageSize
    colour_order: str
    num_boxes: int
    rig_name: str
    rig_hash: str
    providers: list[str]
    limits: Limits


class Health(BaseModel):
    status: Literal["ok"] = "ok"


class Ready(BaseModel):
    status: Literal["ready", "draining", "loading"]
    model_id: str | None = None
