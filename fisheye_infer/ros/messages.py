"""ROS 2 messages in, with ``rosbags`` (pure Python, CDR): camera images to frames; the types the messages out
are (``vision_msgs/Detection3DArray`` and ``visualization_msgs/MarkerArray``, encoded by ``cdr``).

    store = typestore()                                  # ROS 2 Humble's types plus vision_msgs
    image = image_from_message(msg)                      # sensor_msgs/Image or CompressedImage -> BGR uint8

Images: ``sensor_msgs/Image`` in ``bgr8``, ``rgb8`` or ``mono8``; ``sensor_msgs/CompressedImage`` in JPEG or
PNG (``compressed_image_transport``'s formats), decoded through the service's checked decoder
(``runtime.codec``: the size read from the header before decoding, the JPEG scan limit, strict decoding);
anything else is refused by name, with a short reason to count it by (``ImageRefused.reason``).
"""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import cv2
import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from fisheye_infer.errors import FrameError
from fisheye_infer.ros.autoware import AUTOWARE_MSGS
from fisheye_infer.runtime.codec import JPEG_SIGNATURE, PNG_SIGNATURE, decode_image, encoded_image_size

__all__ = [
    "DETECTION_ARRAY",
    "IMAGE_TYPES",
    "ImageRefused",
    "MARKER_ARRAY",
    "image_from_message",
    "ros2_image",
    "stamp_ns",
    "typestore",
]

DETECTION_ARRAY = "vision_msgs/msg/Detection3DArray"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")

#: ``vision_msgs`` (ROS 2, 4.x) definitions the ROS 2 type stores lack.
_VISION_MSGS = {
    "vision_msgs/msg/ObjectHypothesis": "string class_id\nfloat64 score\n",
    "vision_msgs/msg/ObjectHypothesisWithPose": (
        "vision_msgs/ObjectHypothesis hypothesis\ngeometry_msgs/PoseWithCovariance pose\n"
    ),
    "vision_msgs/msg/BoundingBox3D": "geometry_msgs/Pose center\ngeometry_msgs/Vector3 size\n",
    "vision_msgs/msg/Detection3D": (
        "std_msgs/Header header\nvision_msgs/ObjectHypothesisWithPose[] results\n"
        "vision_msgs/BoundingBox3D bbox\nstring id\n"
    ),
    "vision_msgs/msg/Detection3DArray": "std_msgs/Header header\nvision_msgs/Detection3D[] detections\n",
}


@lru_cache(maxsize=1)
def typestore() -> Typestore:
    """ROS 2 Humble's message types with ``vision_msgs`` and Autoware's tracked objects registered."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    types: dict[str, Any] = {}
    for name, text in {**_VISION_MSGS, **AUTOWARE_MSGS}.items():
        types.update(get_types_from_msg(text, name))
    store.register(types)
    return store


def stamp_ns(header: Any) -> int:
    """A ``std_msgs/Header``'s stamp in integer nanoseconds."""
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class ImageRefused(FrameError):
    """A camera message that does not give the model an image.

    Args:
        reason: A short name to count it by (``encoding 16UC1``, ``wrong size``, ``JPEG does not decode``).
        message: What is wrong, in full.
    """

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


#: What the first bytes of a compressed image say it is.
_SIGNATURES = (
    (PNG_SIGNATURE, "PNG"),
    (JPEG_SIGNATURE, "JPEG"),
    (b"GIF8", "GIF"),
    (b"II*\x00", "TIFF"),
    (b"MM\x00*", "TIFF"),
    (b"BM", "BMP"),
)


def _kind_of(data: bytes) -> str:
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "WebP"
    return next((kind for signature, kind in _SIGNATURES if data.startswith(signature)), "unrecognised")


def _cut(text: object, limit: int = 40) -> str:
    text = str(text)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def image_from_message(msg: Any, topic: str = "image", expected_wh: tuple[int, int] | None = None) -> np.ndarray:
    """A camera message as an (H, W, 3) BGR uint8 image, through the checks the service makes.

    Args:
        msg: a ``sensor_msgs/Image`` (``bgr8``, ``rgb8`` or ``mono8``) or ``sensor_msgs/CompressedImage``
            (JPEG or PNG, the format it declares matching its bytes).
        topic: named in the refusals.
        expected_wh: the model's (width, height): an image of another size is refused before it is
            decoded or copied (the size is read from the message or from the JPEG/PNG header), so a
            small message claiming 30000x30000 pixels costs nothing.

    Returns:
        The image, ``expected_wh`` in size when given.

    Raises:
        ImageRefused: an encoding or format this does not read, a size other than ``expected_wh``, a
            size its data or step contradicts, or bytes that do not decode (``runtime.codec``'s checks).
    """
    if hasattr(msg, "encoding"):  # sensor_msgs/Image
        return _raw_image(msg, topic, expected_wh)
    fmt = str(msg.format).lower()
    wants = {kind for kind, words in (("JPEG", ("jpeg", "jpg")), ("PNG", ("png",))) if any(w in fmt for w in words)}
    if not wants or "depth" in fmt:
        raise ImageRefused(
            f"format {_cut(msg.format)}",
            f"{topic}: compressed format {_cut(msg.format)!r} is not read (expected JPEG or PNG)",
        )
    data = np.asarray(msg.data, np.uint8).tobytes()
    kind = _kind_of(data)
    if kind not in wants:
        raise ImageRefused(
            f"format {_cut(msg.format)} holding {kind} bytes",
            f"{topic}: format {_cut(msg.format)!r} declared, the {len(data)} bytes are {kind} data",
        )
    size = encoded_image_size(data)
    if expected_wh is not None and size is not None and size != tuple(expected_wh):
        raise ImageRefused(
            "wrong size", f"{topic}: image is {size[0]}x{size[1]}, model expects {expected_wh[0]}x{expected_wh[1]}"
        )
    try:
        return decode_image(data, topic, expected_wh)
    except FrameError as exc:  # the codec names the topic as its camera
        reason = str(exc).removeprefix(f"camera '{topic}': ")
        raise ImageRefused(f"{kind} does not decode", f"{topic}: {reason}") from None


def _raw_image(msg: Any, topic: str, expected_wh: tuple[int, int] | None) -> np.ndarray:
    """A ``sensor_msgs/Image``'s pixels as BGR; its sizes are checked against each other before any copy."""
    channels = {"bgr8": 3, "rgb8": 3, "mono8": 1}.get(msg.encoding)
    if channels is None:
        raise ImageRefused(
            f"encoding {_cut(msg.encoding)}",
            f"{topic}: image encoding {_cut(msg.encoding)!r} is not read (expected bgr8, rgb8 or mono8)",
        )
    width, height, step = int(msg.width), int(msg.height), int(msg.step)
    if expected_wh is not None and (width, height) != tuple(expected_wh):
        raise ImageRefused(
            "wrong size", f"{topic}: image is {width}x{height}, model expects {expected_wh[0]}x{expected_wh[1]}"
        )
    if width == 0 or height == 0:
        raise ImageRefused("empty image", f"{topic}: image is {width}x{height}")
    if step < width * channels:
        raise ImageRefused(
            "step shorter than a row",
            f"{topic}: step {step} is shorter than a row of {width} {msg.encoding} pixels ({width * channels} bytes)",
        )
    data = np.asarray(msg.data, np.uint8)
    if len(data) < step * height:
        raise ImageRefused(
            "data shorter than its size",
            f"{topic}: image {width}x{height} {msg.encoding} with step {step} needs {step * height} bytes, "
            f"holds {len(data)}",
        )
    rows = data[: step * height].reshape(height, step)[:, : width * channels]
    pixels = rows.reshape(height, width, channels)
    if msg.encoding == "rgb8":
        return np.ascontiguousarray(pixels[:, :, ::-1])
    if msg.encoding == "mono8":
        return cv2.cvtColor(np.ascontiguousarray(pixels[:, :, 0]), cv2.COLOR_GRAY2BGR)
    return np.ascontiguousarray(pixels)


def ros2_image(msg: Any) -> Any:
    """A camera message read from any bag (a ROS 1 one too, whose header has a ``seq``) as the ROS 2 message of
    the same type, to be written in CDR."""
    header = _header(stamp_ns(msg.header), msg.header.frame_id)
    types = typestore().types
    if hasattr(msg, "encoding"):
        return types[IMAGE_TYPES[0]](
            header=header,
            height=msg.height,
            width=msg.width,
            encoding=msg.encoding,
            is_bigendian=msg.is_bigendian,
            step=msg.step,
            data=msg.data,
        )
    return types[IMAGE_TYPES[1]](header=header, format=msg.format, data=msg.data)


def _header(stamp: int, frame_id: str) -> Any:
    store = typestore().types
    time = store["builtin_interfaces/msg/Time"](sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
    return store["std_msgs/msg/Header"](stamp=time, frame_id=frame_id)
