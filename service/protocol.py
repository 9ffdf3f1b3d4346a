"""The ``/stream`` binary frame format, version 1: encode (clients) and decode (server).

One WebSocket binary message carries one frame. All integers are unsigned, big-endian
(network order):

    offset  size  field
    0       4     magic         b"FEYE"
    4       1     version       1
    5       8     frame_id      u64, chosen by the client (echoed in the answer)
    13      1     camera_count  u8, 1..255
    14      ...   camera_count times:
                    2   name_length   u16
                    n   name          UTF-8, a camera name of the model (see GET /model)
                    4   image_length  u32
                    m   image         encoded JPEG or PNG bytes, the model's image size

Nothing may follow the last image. The server answers every frame it runs with one JSON text
message (``StreamResult``: ``kind="result"``, ``frame_id``, ``detections``, ``records``,
``cameras_used``, ``timings_ms``, ``batch_size``, ``model_id`` and ``dropped``, the ids of
frames replaced by newer ones since its previous answer) or refuses it with ``StreamError``
(``kind="error"``, ``frame_id``, ``status``, ``error``, ``field``). This module needs no web
framework, so clients can import it with the core package alone.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass

from fisheye_infer.service.errors import ServiceError, shown

__all__ = [
    "MAGIC",
    "VERSION",
    "HEADER",
    "StreamFrame",
    "StreamProtocolError",
    "encode_frame",
    "peek_frame_id",
    "decode_frame",
]

MAGIC = b"FEYE"
VERSION = 1
HEADER = struct.Struct("!4sBQB")  # magic, version, frame_id, camera_count
_NAME = struct.Struct("!H")
_IMAGE = struct.Struct("!I")


class StreamProtocolError(ServiceError):
    """A stream message does not follow the frame format; the field at fault is named."""

    status = 400


@dataclass(frozen=True)
class StreamFrame:
    frame_id: int
    images: dict[str, bytes]


def encode_frame(frame_id: int, images: Mapping[str, bytes]) -> bytes:
    """One frame as a binary message (the client side)."""
    if not 0 <= frame_id < 2**64:
        raise ValueError(f"frame_id: expected 0 <= id < 2**64, got {frame_id}")
    if not 1 <= len(images) <= 255:
        raise ValueError(f"images: expected 1..255 cameras, got {len(images)}")
    parts = [HEADER.pack(MAGIC, VERSION, frame_id, len(images))]
    for name, data in images.items():
        raw = name.encode()
        parts += [_NAME.pack(len(raw)), raw, _IMAGE.pack(len(data)), bytes(data)]
    return b"".join(parts)


def peek_frame_id(message: bytes) -> int:
    """The frame id, after checking magic and version only (cheap: the receiver calls it per message)."""
    if len(message) < HEADER.size:
        raise StreamProtocolError(
            f"header: message is {len(message)} bytes, a frame header is {HEADER.size}", field="header"
        )
    magic, version, frame_id, _ = HEADER.unpack_from(message)
    if magic != MAGIC:
        raise StreamProtocolError(f"magic: got {magic!r}, expected {MAGIC!r}", field="magic")
    if version != VERSION:
        raise StreamProtocolError(f"version: got {version}, this server speaks {VERSION}", field="version")
    return int(frame_id)


def decode_frame(message: bytes) -> StreamFrame:
    """The whole message: every length checked against what is left, nothing trailing."""
    frame_id = peek_frame_id(message)
    count = HEADER.unpack_from(message)[3]
    view = memoryview(message)
    at = HEADER.size
    images: dict[str, bytes] = {}
    for i in range(count):
        if at + _NAME.size > len(view):
            raise StreamProtocolError(
                f"camera {i}: message ends inside its name length (byte {at})", field="name_length"
            )
        (n,) = _NAME.unpack_from(view, at)
        at += _NAME.size
        if at + n + _IMAGE.size > len(view):
            raise StreamProtocolError(
                f"camera {i}: name of {n} bytes and image length overrun the message ({len(view)} bytes)", field="name"
            )
        try:
            name = bytes(view[at : at + n]).decode()
        except UnicodeDecodeError:
            raise StreamProtocolError(f"camera {i}: name is not UTF-8", field="name") from None
        at += n
        (m,) = _IMAGE.unpack_from(view, at)
        at += _IMAGE.size
        if at + m > len(view):
            raise StreamProtocolError(
                f"camera '{shown(name)}': image of {m} bytes overruns the message ({len(view) - at} bytes left)",
                field=shown(name),
            )
        if name in images:
            raise StreamProtocolError(f"camera '{shown(name)}': given twice", field=shown(name))
        images[name] = bytes(view[at : at + m])
        at += m
    if at != len(view):
        raise StreamProtocolError(f"message: {len(view) - at} bytes after the last image", field="message")
    return StreamFrame(frame_id, images)
