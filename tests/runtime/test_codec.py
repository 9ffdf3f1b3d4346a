"""Encoded images: strict JPEG decoding, the scan bound, and PNG through OpenCV."""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.codec import MAX_JPEG_SCANS, decode_image, jpeg_scan_count


@pytest.fixture(scope="module")
def picture() -> np.ndarray:
    rng = np.random.default_rng(7)
    image = cv2.GaussianBlur(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8), (9, 9), 3)
    return cv2.putText(image, "fisheye", (5, 50), cv2.FONT_HERSHEY_SIMPLEX, 1.0, (255, 255, 255), 2)


def many_scans(picture: np.ndarray, copies: int) -> bytes:
    """A progressive JPEG whose first scan is repeated ``copies`` times."""
    data = cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    first = data.index(b"\xff\xda")
    second = data.index(b"\xff\xda", first + 2)
    return data[:second] + data[first:second] * copies + data[second:]


def header_then_noise(picture: np.ndarray) -> bytes:
    """A valid JPEG up to its scan header, then random bytes: OpenCV decodes it to a picture."""
    data = cv2.imencode(".jpg", picture)[1].tobytes()
    sos = data.index(b"\xff\xda")
    header_end = sos + 2 + ((data[sos + 2] << 8) | data[sos + 3])
    return data[:header_end] + np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes() + b"\xff\xd9"


def test_clean_jpeg_decodes_as_opencv_does(picture: np.ndarray) -> None:
    for params in ([], [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]):
        data = cv2.imencode(".jpg", picture, params)[1].tobytes()
        np.testing.assert_array_equal(
            decode_image(data, "front", (128, 96)), cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        )


def test_scans_are_counted(picture: np.ndarray) -> None:
    assert jpeg_scan_count(cv2.imencode(".jpg", picture)[1].tobytes()) == 1
    assert 2 <= jpeg_scan_count(cv2.imencode(".jpg", picture, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()) <= 16
    assert jpeg_scan_count(many_scans(picture, 5000), stop_after=10**6) > 5000


def test_thousands_of_scans_are_refused_before_decoding(picture: np.ndarray) -> None:
    data = many_scans(picture, 5000)
    started = time.perf_counter()
    with pytest.raises(FrameError, match=f"camera 'front': JPEG with more than {MAX_JPEG_SCANS} scans"):
        decode_image(data, "front", (128, 96))
    assert time.perf_counter() - started < 5  # refused by the count, not decoded


@pytest.mark.parametrize(
    "make, opencv_accepts",
    [
        (header_then_noise, True),  # OpenCV only logs "Corrupt JPEG data" and returns a picture
        (lambda p: cv2.imencode(".jpg", p)[1].tobytes()[:-400], False),  # cut short
    ],
)
def test_corrupt_jpeg_is_refused(picture: np.ndarray, make, opencv_accepts: bool) -> None:
    data = make(picture)
    assert (cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR) is not None) is opencv_accepts
    with pytest.raises(FrameError, match="camera 'front': the bytes are not a decodable JPEG image: corrupt data"):
        decode_image(data, "front", (128, 96))


def test_png_still_decodes_through_opencv(picture: np.ndarray) -> None:
    data = cv2.imencode(".png", picture)[1].tobytes()
    np.testing.assert_array_equal(decode_image(data, "left"), picture)
