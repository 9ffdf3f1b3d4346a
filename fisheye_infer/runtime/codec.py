"""Encoded images (JPEG, PNG) -> (H, W, 3) uint8 BGR arrays, refusing anything costly or corrupt first.

    decode_image(data, "fisheye_camera_front", expected_wh=(1280, 960))

What is checked, cheapest first, so that hostile bytes cost little:

1. the format: only PNG and JPEG, whose headers state the image size;
2. the size read from the header, before any decoding (a tiny file claiming 60000x60000 pixels,
   a decompression bomb, never reaches a decoder);
3. for JPEG, the number of scans (``SOS`` markers), counted by walking the markers: a progressive
   JPEG made of thousands of tiny scans costs decode time in proportion to their count, so more
   than ``MAX_JPEG_SCANS`` is refused before decoding (an ordinary progressive JPEG has about 10);
4. the decode itself, strict: JPEG through libjpeg-turbo (``simplejpeg``) with ``strict=True``,
   which turns libjpeg's "Corrupt JPEG data" and "Premature end of JPEG file" warnings into
   errors, where OpenCV would return a half-grey image; PNG through OpenCV, which checks the
   CRCs and refuses truncated data.

Every refusal is a ``FrameError`` naming the camera.
"""

from __future__ import annotations

import re
import struct

import cv2
import numpy as np
import simplejpeg

from fisheye_infer.errors import FrameError

__all__ = ["MAX_JPEG_SCANS", "PNG_SIGNATURE", "JPEG_SIGNATURE", "encoded_image_size", "jpeg_scan_count", "decode_image"]

MAX_JPEG_SCANS = 64
PNG_SIGNATURE, JPEG_SIGNATURE = b"\x89PNG\r\n\x1a\n", b"\xff\xd8"
# In entropy-coded data a 0xFF byte is followed by 0x00 (stuffing) or a restart marker; anything
# else is the next marker (0xFF fill bytes included, skipped by the walk).
_MARKER_AFTER_SCAN = re.compile(rb"\xff[^\x00\xd0-\xd7]")
_STANDALONE = {0x01, *range(0xD0, 0xD8)}
_SOF = {*range(0xC0, 0xD0)} - {0xC4, 0xC8, 0xCC}


def encoded_image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) read from a PNG or JPEG header without decoding; None if not recognised."""
    if data[:8] == PNG_SIGNATURE and len(data) >= 24 and data[12:16] == b"IHDR":
        width, height = struct.unpack(">II", data[16:24])
        return int(width), int(height)
    if data[:2] == JPEG_SIGNATURE:
        i = 2
        while i + 9 < len(data):
            if data[i] != 0xFF:
                return None
            marker = data[i + 1]
            if marker in (0xD8, 0xFF) or marker in _STANDALONE:
                i += 1 if marker == 0xFF else 2
                continue
            length = struct.unpack(">H", data[i + 2 : i + 4])[0]
            if marker in _SOF:
                height, width = struct.unpack(">HH", data[i + 5 : i + 9])
                return int(width), int(height)
            i += 2 + length
    return None


def jpeg_scan_count(data: bytes, stop_after: int = MAX_JPEG_SCANS) -> int:
    """The number of scans (SOS segments) of a JPEG, counting stops once past ``stop_after``.

    Walks the marker segments by their lengths and skips each scan's entropy-coded data with one
    regular-expression search, so the cost is a single pass over the bytes. Malformed structure
    ends the walk; the strict decoder refuses such files afterwards.
    """
    scans, i, n = 0, 2, len(data)
    while i + 1 < n and scans <= stop_after:
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0xD9:  # end of image
            break
        if marker in _STANDALONE or marker == 0xD8:
            i += 2
            continue
        if i + 4 > n:
            break
        i += 2 + ((data[i + 2] << 8) | data[i + 3])
        if marker == 0xDA:
            scans += 1
            found = _MARKER_AFTER_SCAN.search(data, i)
            if found is None:
                break
            i = found.start()
    return scans


def _decode_jpeg(data: bytes, camera: str) -> np.ndarray:
    scans = jpeg_scan_count(data)
    if scans > MAX_JPEG_SCANS:
        raise FrameError(
            f"camera '{camera}': JPEG with more than {MAX_JPEG_SCANS} scans (each costs a pass of decoding); "
            "re-encode it as a baseline or ordinary progressive JPEG"
        )
    try:
        return simplejpeg.decode_jpeg(data, colorspace="BGR", strict=True)
    except ValueError as exc:
        reason = str(exc).strip() or "unreadable data"
        raise FrameError(
            f"camera '{camera}': the bytes are not a decodable JPEG image: corrupt data ({reason[:120]})"
        ) from None


def decode_image(data: bytes, camera: str, expected_wh: tuple[int, int] | None = None) -> np.ndarray:
    """Decode JPEG/PNG bytes to (H, W, 3) uint8 BGR after the checks of the module docstring."""
    buf = bytes(data)
    size = encoded_image_size(buf)
    if size is None:
        # Only PNG and JPEG are decoded: their headers state the size, so nothing of unknown size
        # (a decompression bomb in another format) ever reaches the decoder.
        raise FrameError(
            f"camera '{camera}': the bytes are not a decodable JPEG or PNG image "
            f"({len(buf)} bytes, no PNG or JPEG header)"
        )
    if expected_wh is not None and size != tuple(expected_wh):
        raise FrameError(
            f"camera '{camera}': image is {size[0]}x{size[1]}, model expects {expected_wh[0]}x{expected_wh[1]}"
        )
    if buf[:2] == JPEG_SIGNATURE:
        return _decode_jpeg(buf, camera)
    image = cv2.imdecode(np.frombuffer(buf, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise FrameError(f"camera '{camera}': the bytes are not a decodable JPEG or PNG image ({len(buf)} bytes)")
    return image
