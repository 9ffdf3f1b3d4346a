"""The /stream frame format: round trips, and every malformed message refused with the field named."""

from __future__ import annotations

import struct
from contextlib import ExitStack as DoesNotRaise

import pytest

from fisheye_infer.service.protocol import HEADER, MAGIC, StreamProtocolError, decode_frame, encode_frame, peek_frame_id

IMAGES = {"front": b"\x89PNG-front", "left": b"\xff\xd8-left"}
GOOD = encode_frame(2**64 - 1, IMAGES)


def test_round_trip_keeps_id_names_and_bytes() -> None:
    frame = decode_frame(GOOD)
    assert frame.frame_id == 2**64 - 1 and frame.images == IMAGES
    assert peek_frame_id(GOOD) == 2**64 - 1


def test_layout_is_the_documented_one() -> None:
    message = encode_frame(7, {"ab": b"xyz"})
    assert message == b"FEYE" + b"\x01" + (7).to_bytes(8, "big") + b"\x01" + b"\x00\x02ab" + b"\x00\x00\x00\x03xyz"
    assert HEADER.size == 14


@pytest.mark.parametrize(
    "message, expectation, field",
    [
        (GOOD, DoesNotRaise(), None),  # well formed
        (
            GOOD[:10],
            pytest.raises(StreamProtocolError, match="a frame header is 14"),
            "header",
        ),  # cut inside the header
        (b"JFIF" + GOOD[4:], pytest.raises(StreamProtocolError, match="magic"), "magic"),  # another protocol
        (
            MAGIC + b"\x02" + GOOD[5:],
            pytest.raises(StreamProtocolError, match="version: got 2"),
            "version",
        ),  # future version
        (GOOD[:-3], pytest.raises(StreamProtocolError, match="camera 'left': image of"), "left"),  # image cut short
        (
            GOOD + b"\x00",
            pytest.raises(StreamProtocolError, match="1 bytes after the last image"),
            "message",
        ),  # trailing bytes
        (
            GOOD[:14] + struct.pack("!H", 500) + b"front",
            pytest.raises(StreamProtocolError, match="overrun"),
            "name",
        ),  # name too long
        (
            GOOD[:14] + b"\x00\x02\xff\xfe" + GOOD[20:],
            pytest.raises(StreamProtocolError, match="not UTF-8"),
            "name",
        ),  # bad name bytes
        (
            encode_frame(1, {"a": b"1"})[:13] + b"\x02" + encode_frame(1, {"a": b"1"})[14:] * 2,
            pytest.raises(StreamProtocolError, match="twice"),
            "a",
        ),
        (
            GOOD[:13] + b"\x03" + GOOD[14:],
            pytest.raises(StreamProtocolError, match="camera 2: message ends"),
            "name_length",
        ),  # count too high
    ],
)
def test_decode(message: bytes, expectation, field: str | None) -> None:
    with expectation as info:
        decode_frame(message)
    if field is not None:
        assert info.value.field == field and info.value.status == 400


@pytest.mark.parametrize("frame_id, images", [(-1, IMAGES), (2**64, IMAGES), (1, {})])
def test_encode_refuses_what_cannot_be_sent(frame_id: int, images: dict[str, bytes]) -> None:
    with pytest.raises(ValueError):
        encode_frame(frame_id, images)


def test_importable_without_the_web_stack() -> None:
    import subprocess
    import sys

    code = (
        "import sys, fisheye_infer.service.protocol as p; p.decode_frame(p.encode_frame(1, {'a': b'x'}));"
        "print(sorted(m for m in ('fastapi', 'starlette', 'uvicorn') if m in sys.modules))"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert result.stdout.strip() == "[]"


def test_a_long_camera_name_is_not_repeated_whole() -> None:
    name = "n" * 60_000
    one = encode_frame(7, {name: b"x"})  # header, then one camera
    overrun = one[:-5] + struct.pack("!I", 10**6)  # its image length past the end
    twice = one[: HEADER.size - 1] + bytes([2]) + one[HEADER.size :] * 2  # the same camera twice
    for message, words in ((overrun, "bytes overruns the message"), (twice, "given twice")):
        with pytest.raises(StreamProtocolError, match=words) as raised:
            decode_frame(message)
        assert len(str(raised.value)) < 200 and "(60000 characters)" in str(raised.value)
