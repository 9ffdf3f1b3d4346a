"""Frame validation and decoding: every form of input, every refusal with its message."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.preprocess import encoded_image_size, load_frame, load_frames, prepare_batch

CAMERAS = ("front", "left", "right", "rear")
WH = (64, 48)


def image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 255, (WH[1], WH[0], 3), dtype=np.uint8)


def png(a: np.ndarray) -> bytes:
    return cv2.imencode(".png", a)[1].tobytes()


@pytest.fixture
def arrays() -> list[np.ndarray]:
    return [image(i) for i in range(4)]


def test_arrays_bytes_paths_mapping_and_sequence_agree(arrays: list[np.ndarray], tmp_path: Path) -> None:
    paths = []
    for name, a in zip(CAMERAS, arrays):
        paths.append(tmp_path / f"{name}.png")
        cv2.imwrite(str(paths[-1]), a)
    forms = [
        arrays,
        dict(zip(CAMERAS, arrays)),
        [png(a) for a in arrays],
        dict(zip(CAMERAS, [str(p) for p in paths])),
        paths,
    ]
    reference, valid = prepare_batch([arrays], CAMERAS, WH)
    assert reference.shape == (1, 4, 48, 64, 3) and valid.all()
    for form in forms:
        images, _ = prepare_batch([form], CAMERAS, WH)
        np.testing.assert_array_equal(images, reference)


def test_missing_camera_is_degraded_mode(arrays: list[np.ndarray]) -> None:
    images, valid = prepare_batch([{"front": arrays[0], "rear": arrays[3], "left": None}], CAMERAS, WH)
    assert valid[0].tolist() == [True, False, False, True]
    assert not images[0, 1].any() and not images[0, 2].any()


@pytest.mark.parametrize(
    ("frame", "message"),
    [
        ({"front": image(0), "roof": image(1)}, "camera 'roof': not a camera of this model"),
        ([image(0)] * 3, "got 3 images, expected 4"),
        ({"front": image(0).astype(np.float32)}, "camera 'front': image dtype is float32, expected uint8"),
        ({"left": image(0)[..., 0]}, r"camera 'left': image shape is \(48, 64\), expected \(H, W, 3\)"),
        ({"right": np.zeros((96, 128, 3), np.uint8)}, "camera 'right': image is 128x96, model expects 64x48"),
        ({"rear": png(np.zeros((96, 128, 3), np.uint8))}, "camera 'rear': image is 128x96, model expects 64x48"),
        ({"front": b"not an image"}, "camera 'front': the bytes are not a decodable JPEG or PNG"),
        ({"front": cv2.imencode(".bmp", image(0))[1].tobytes()}, "camera 'front': .* no PNG or JPEG header"),
        ({"front": png(image(0))[:40]}, "camera 'front': the bytes are not a decodable"),
        ({"front": "/no/such/file.png"}, "camera 'front': cannot read /no/such/file.png"),
        ({"front": 3.5}, "camera 'front': expected an ndarray, encoded bytes or a path, got float"),
        ({}, "no camera image given"),
        ("front.png", "expected a mapping camera name -> image or a sequence"),
    ],
    ids=[
        "unknown-camera",
        "too-few",
        "dtype",
        "channels",
        "size",
        "size-from-header",
        "garbage",
        "bmp",
        "truncated",
        "missing-path",
        "wrong-type",
        "empty",
        "string",
    ],
)
def test_bad_input_names_the_problem(frame, message: str) -> None:
    with pytest.raises(FrameError, match=message):
        load_frame(frame, CAMERAS, WH)


def test_batch_errors_name_the_frame(arrays: list[np.ndarray]) -> None:
    with pytest.raises(FrameError, match="frame 1: camera 'roof'"):
        prepare_batch([arrays, {"roof": arrays[0]}], CAMERAS, WH)
    with pytest.raises(FrameError, match="non-empty sequence"):
        prepare_batch([], CAMERAS, WH)


def test_parallel_decoding_gives_the_sequential_result_and_first_error(arrays: list[np.ndarray]) -> None:
    """A thread pool's map decodes the images; the arrays and the error reported are those of the plain loop."""
    frames = [
        [png(a) for a in arrays],
        [png(a) for a in reversed(arrays)],
        {"front": arrays[0], "rear": png(arrays[1])},
    ]
    with ThreadPoolExecutor(4) as pool:
        parallel = load_frames(frames, CAMERAS, WH, pool.map)
        sequential = load_frames(frames, CAMERAS, WH)
        assert [[None if a is None else a.tolist() for a in f] for f in parallel] == [
            [None if a is None else a.tolist() for a in f] for f in sequential
        ]
        assert np.array_equal(parallel[1][0], arrays[3]) and parallel[2][1] is None
        # frame 1 has two bad images: the first in camera order is the one named, whichever thread finishes first
        bad = [frames[0], [png(arrays[0]), b"not an image", png(np.zeros((96, 128, 3), np.uint8)), png(arrays[3])], {}]
        for map_images in (pool.map, map):
            with pytest.raises(FrameError, match="^frame 1: camera 'left': the bytes are not a decodable"):
                load_frames(bad, CAMERAS, WH, map_images)
    # the given map runs only when more than one image needs decoding
    counted: list[int] = []

    def counting_map(fn, items):  # type: ignore[no-untyped-def]
        items = list(items)
        counted.append(len(items))
        return map(fn, items)

    load_frames([[png(a) for a in arrays]], CAMERAS, WH, counting_map)
    load_frames([arrays, [png(arrays[0]), *arrays[1:]]], CAMERAS, WH, counting_map)
    assert counted == [4]
    with pytest.raises(FrameError, match="^frame 1: frame: no camera image given"):
        load_frames([frames[0], {}], CAMERAS, WH)
    # a malformed frame is reported in its turn: frame 0's bad image comes first, as in a plain loop over the frames
    for later in ([png(arrays[0])] * 3, "not a frame", 5):
        with pytest.raises(FrameError, match="^frame 0: camera 'left': the bytes are not a decodable"):
            load_frames([bad[1], later], CAMERAS, WH, map)
    with pytest.raises(FrameError, match="^frame 1: frame: got 3 images, expected 4"):
        load_frames([frames[0], [png(arrays[0])] * 3, bad[1]], CAMERAS, WH, map)


@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_header_size_without_decoding(ext: str) -> None:
    data = cv2.imencode(ext, np.zeros((300, 500, 3), np.uint8))[1].tobytes()
    assert encoded_image_size(data) == (500, 300)
    assert encoded_image_size(b"GIF89a....") is None
