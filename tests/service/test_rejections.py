"""Every refusal: the documented status, an ErrorOut naming the camera or field, and a server that
keeps serving afterwards."""

from __future__ import annotations

import base64
import gzip
import struct
import zlib
from collections.abc import Callable, Iterator
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from service_live import LiveServer, multipart

FRONT = "fisheye_camera_front"


def png_header_claiming(width: int, height: int) -> bytes:
    """A 60-byte PNG whose header claims width x height: a decompression bomb's calling card."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b"")
    )


def jpeg_header_claiming(width: int, height: int) -> bytes:
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 11, 8, height, width, 1) + b"\x01\x11\x00"
    return b"\xff\xd8" + sof + b"\xff\xd9"


def truncated_jpeg(images: dict[str, bytes]) -> bytes:
    image = cv2.imdecode(np.frombuffer(images[FRONT], np.uint8), cv2.IMREAD_COLOR)
    data = cv2.imencode(".jpg", image)[1].tobytes()
    return data[: data.index(b"\xff\xda") + 200]  # a valid 160x160 header, then the scan breaks off


def corrupt_png(images: dict[str, bytes]) -> bytes:
    data = bytearray(images[FRONT])
    at = data.index(b"IDAT")
    data[at + 10 : at + 40] = bytes(30)
    return bytes(data)


def header_then_noise(images: dict[str, bytes]) -> bytes:
    """A valid 160x160 JPEG header and scan header, then random bytes: OpenCV decodes it to a picture."""
    image = cv2.imdecode(np.frombuffer(images[FRONT], np.uint8), cv2.IMREAD_COLOR)
    data = cv2.imencode(".jpg", image)[1].tobytes()
    sos = data.index(b"\xff\xda")
    header_end = sos + 2 + ((data[sos + 2] << 8) | data[sos + 3])
    return data[:header_end] + np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes() + b"\xff\xd9"


def many_scans(images: dict[str, bytes], copies: int = 1000) -> bytes:
    """A 160x160 progressive JPEG with a thousand scans (its first scan repeated), under the 1 MiB body limit."""
    image = cv2.imdecode(np.frombuffer(images[FRONT], np.uint8), cv2.IMREAD_COLOR)
    data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    first = data.index(b"\xff\xda")
    second = data.index(b"\xff\xda", first + 2)
    return data[:second] + data[first:second] * copies + data[second:]


def raw_multipart(images: dict[str, bytes]) -> tuple[bytes, str]:
    request = httpx.Request("POST", "http://127.0.0.1/detect", files=multipart(images))
    return request.read(), request.headers["content-type"]


def unterminated(images: dict[str, bytes]) -> dict[str, Any]:
    body, content_type = raw_multipart(images)
    return {"content": body[:-300], "headers": {"content-type": content_type}}


def gzipped(images: dict[str, bytes]) -> dict[str, Any]:
    body, content_type = raw_multipart(images)
    return {"content": gzip.compress(body), "headers": {"content-type": content_type, "content-encoding": "gzip"}}


def with_front(images: dict[str, bytes], data: bytes, content_type: str = "image/png") -> dict[str, Any]:
    """All four parts, the front camera's replaced by ``data`` (the front part goes first)."""
    return {"files": multipart({**images, FRONT: data}, content_type=content_type)}


def b64(images: dict[str, bytes]) -> dict[str, str]:
    return {c: base64.b64encode(b).decode() for c, b in images.items()}


def chunks(total: int) -> Iterator[bytes]:
    for _ in range(total // 65536 + 1):
        yield b"x" * 65536


Request = Callable[[dict[str, bytes]], dict[str, Any]]

# (case id, path, request builder, status, field (None: any), words in the message)
CASES: list[tuple[str, str, Request, int, str | None, str]] = [
    (
        "unknown camera",
        "/detect",
        lambda im: {"files": multipart({**im, "fisheye_camera_roof": im[FRONT]})},
        422,
        "fisheye_camera_roof",
        "not a camera",
    ),
    (
        "missing part",
        "/detect",
        lambda im: {"files": multipart({c: b for c, b in im.items() if c != FRONT})},
        422,
        FRONT,
        "missing",
    ),
    (
        "no image at all",
        "/detect",
        lambda im: {"files": {"score_threshold": (None, "0.1")}},
        422,
        "images",
        "none given",
    ),
    (
        "malformed multipart",
        "/detect",
        lambda im: {"content": b"--x\r\nbroken", "headers": {"content-type": "multipart/form-data"}},
        400,
        "body",
        "multipart",
    ),
    (
        "camera as text field",
        "/detect",
        lambda im: {"files": multipart({c: b for c, b in im.items() if c != FRONT}), "data": {FRONT: "abc"}},
        422,
        FRONT,
        "file part",
    ),
    (
        "camera twice",
        "/detect",
        lambda im: {"files": multipart(im) + multipart({FRONT: im[FRONT]})},
        422,
        FRONT,
        "twice",
    ),
    ("empty image", "/detect", lambda im: with_front(im, b""), 422, FRONT, "empty"),
    (
        "corrupt JPEG",
        "/detect",
        lambda im: with_front(im, truncated_jpeg(im), "image/jpeg"),
        422,
        FRONT,
        "not a decodable",
    ),
    ("corrupt PNG", "/detect", lambda im: with_front(im, corrupt_png(im)), 422, FRONT, "not a decodable"),
    (
        "PNG bomb header",
        "/detect",
        lambda im: with_front(im, png_header_claiming(60000, 60000)),
        422,
        FRONT,
        "60000x60000, model expects 160x160",
    ),
    (
        "JPEG bomb header",
        "/detect",
        lambda im: with_front(im, jpeg_header_claiming(65000, 65000), "image/jpeg"),
        422,
        FRONT,
        "65000x65000",
    ),
    (
        "JPEG without size",
        "/detect",
        lambda im: with_front(im, b"\xff\xd8\xff\xe0" + bytes(40), "image/jpeg"),
        422,
        FRONT,
        "header",
    ),
    (
        "wrong image size",
        "/detect",
        lambda im: with_front(im, cv2.imencode(".png", np.zeros((320, 320, 3), np.uint8))[1].tobytes()),
        422,
        FRONT,
        "320x320",
    ),
    ("GIF image", "/detect", lambda im: with_front(im, b"GIF89a" + bytes(64)), 415, FRONT, "not a JPEG or PNG"),
    ("part content type", "/detect", lambda im: with_front(im, im[FRONT], "text/plain"), 415, FRONT, "text/plain"),
    (
        "request content type",
        "/detect",
        lambda im: {"content": b"hello", "headers": {"content-type": "text/plain"}},
        415,
        "Content-Type",
        "text/plain",
    ),
    ("no content type", "/detect", lambda im: {"content": b"hello"}, 415, "Content-Type", "none"),
    (
        "body over the limit",
        "/detect",
        lambda im: {"files": multipart({FRONT: bytes(1536 * 1024)})},
        413,
        "body",
        "max_body_bytes",
    ),
    (
        "chunked body over the limit",
        "/detect",
        lambda im: {"content": chunks(1536 * 1024), "headers": {"content-type": "application/json"}},
        413,
        "body",
        "max_body_bytes",
    ),
    (
        "malformed JSON",
        "/detect",
        lambda im: {"content": b'{"images": ', "headers": {"content-type": "application/json"}},
        400,
        "body",
        "JSON",
    ),
    (
        "unknown JSON field",
        "/detect",
        lambda im: {"json": {"images": b64(im), "colour": "red"}},
        422,
        "colour",
        "Extra inputs",
    ),
    ("images not a mapping", "/detect", lambda im: {"json": {"images": ["a", "b"]}}, 422, "images", "object"),
    (
        "too many parts",
        "/detect",
        lambda im: {"files": multipart(im, "") + [(f"x{i}", ("x.png", b"x", "image/png")) for i in range(8)]},
        422,
        "images",
        "more than 8 image parts",
    ),
    ("bad base64", "/detect", lambda im: {"json": {"images": {**b64(im), FRONT: "@@@"}}}, 422, FRONT, "base64"),
    (
        "threshold out of range",
        "/detect",
        lambda im: {"files": multipart(im), "data": {"score_threshold": "1.5"}},
        422,
        "score_threshold",
        "less than or equal to 1",
    ),
    (
        "threshold not a number",
        "/detect",
        lambda im: {"files": multipart(im), "data": {"score_threshold": "high"}},
        422,
        "score_threshold",
        "number",
    ),
    (
        "unknown class",
        "/detect",
        lambda im: {"files": multipart(im), "data": {"classes": "Car,Dragon"}},
        422,
        "classes",
        "Dragon",
    ),
    ("unknown nms", "/detect", lambda im: {"files": multipart(im), "data": {"nms": "square"}}, 422, "nms", "rotated"),
    (
        "unknown form field",
        "/detect",
        lambda im: {"files": multipart(im), "data": {"colour": "red"}},
        422,
        "colour",
        "not an image part or option",
    ),
    (
        "batch: part without index",
        "/detect/batch",
        lambda im: {"files": multipart(im)},
        422,
        FRONT,
        "<frame index>.<camera>",
    ),
    (
        "batch: gap in frames",
        "/detect/batch",
        lambda im: {"files": multipart(im, "0.") + multipart(im, "2.")},
        422,
        "1",
        "without gaps",
    ),
    (
        "batch: too many frames",
        "/detect/batch",
        lambda im: {"json": {"frames": [{"images": {FRONT: "AA=="}}] * 9}},
        422,
        "frames",
        "max_batch_frames=8",
    ),
    (
        "batch: bad frame named",
        "/detect/batch",
        lambda im: {"files": multipart(im, "0.") + multipart({**im, FRONT: png_header_claiming(60000, 60000)}, "1.")},
        422,
        f"1.{FRONT}",
        "frame 1",
    ),
    # the images decode in parallel; the first undecodable one in frame and camera order is the one named
    (
        "batch: first undecodable image named",
        "/detect/batch",
        lambda im: {
            "files": multipart(im, "0.")
            + multipart({**im, "fisheye_camera_rear": corrupt_png(im)}, "1.")
            + multipart({**im, FRONT: corrupt_png(im)}, "2.")
        },
        422,
        "1.fisheye_camera_rear",
        "frame 1",
    ),
    ("batch: empty frame list", "/detect/batch", lambda im: {"json": {"frames": []}}, 422, "frames", "at least 1"),
    (
        "corrupt JPEG data",
        "/detect",
        lambda im: with_front(im, header_then_noise(im), "image/jpeg"),
        422,
        FRONT,
        "corrupt data",
    ),
    (
        "JPEG with a thousand scans",
        "/detect",
        lambda im: with_front(im, many_scans(im), "image/jpeg"),
        422,
        FRONT,
        "more than 64 scans",
    ),
    (
        "batch: non-ASCII digit",
        "/detect/batch",
        lambda im: {"files": multipart(im, "\u00b2.")},
        422,
        f"\u00b2.{FRONT}",
        "digits 0-9",
    ),
    (
        "batch: index of many digits",
        "/detect/batch",
        lambda im: {"files": multipart(im, "9" * 30 + ".")},
        422,
        None,
        "frame index of 30 digits; at most 6 digits are read, and a batch holds frames 0..7 (max_batch_frames=8)",
    ),
    (
        "batch: camera twice, 0 and 00",
        "/detect/batch",
        lambda im: {"files": multipart(im, "0.") + multipart({FRONT: im[FRONT]}, "00.")},
        422,
        f"0.{FRONT}",
        f"camera '{FRONT}' given twice",
    ),
    (
        "10 kB part name",
        "/detect",
        lambda im: {"files": multipart(im) + [("x" * 10000, ("x.png", im[FRONT], "image/png"))]},
        422,
        "x" * 64 + "... (10000 characters)",
        "too long",
    ),
    ("gzip body", "/detect", gzipped, 415, "Content-Encoding", "gzip"),
    ("unterminated multipart", "/detect", unterminated, 400, "body", "ended before its closing boundary"),
    (
        "5000-digit JSON number",
        "/detect",
        lambda im: {
            "content": b'{"images": {}, "score_threshold": ' + b"9" * 5000 + b"}",
            "headers": {"content-type": "application/json"},
        },
        422,
        "score_threshold",
        "number out of range",
    ),
    (
        "100k unknown classes",
        "/detect",
        lambda im: {"json": {"images": b64(im), "classes": [f"c{i}" for i in range(100_000)]}},
        422,
        "classes",
        "and 99980 more",
    ),
]


@pytest.mark.parametrize("path, build, status, field, words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_refusal(
    client: httpx.Client,
    images: dict[str, bytes],
    path: str,
    build: Request,
    status: int,
    field: str | None,
    words: str,
) -> None:
    response = client.post(path, **build(images))
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error", "status", "type", "field"} and body["status"] == status
    if field is not None:
        assert body["field"] == field, body
    assert words in body["error"], body
    assert len(response.content) < 4096  # what a message repeats of the request is capped
    assert client.get("/healthz").status_code == 200


def test_server_still_detects_after_the_refusals(
    server: LiveServer, client: httpx.Client, images: dict[str, bytes]
) -> None:
    assert client.post("/detect", files=multipart(images)).status_code == 200
    assert server.wait_metric("fisheye_inflight", lambda v: v == 0) == 0
    assert server.metric("fisheye_queue_depth") == 0
    assert server.metric("fisheye_requests_total", endpoint="/detect", status="413") >= 2
