"""Frames in, the graph's inputs out: decode, validate, stack. No resizing, ever.

A frame is either a mapping camera name -> image, or a sequence in the model's camera order.
An image is an ndarray (H, W, 3) uint8 in the model's colour order (BGR for the Fisheye3DOD
models), encoded JPEG/PNG bytes, or a path. A camera that is missing or ``None`` is marked
invalid (degraded mode) and its slot is zeros. Every refusal is a ``FrameError`` that names
the camera and says what was expected.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.codec import decode_image, encoded_image_size

__all__ = [
    "ImageInput",
    "Frame",
    "encoded_image_size",
    "decode_image",
    "load_frame",
    "load_frames",
    "stack_frames",
    "prepare_batch",
    "frames_from_paths",
]

ImageInput = np.ndarray | bytes | bytearray | memoryview | str | os.PathLike | None
Frame = Mapping[str, ImageInput] | Sequence[ImageInput]


#: Images that need decoding: encoded bytes, and paths to encoded files.
_BYTES = (bytes, bytearray, memoryview)
_PATHS = (str, os.PathLike)


def _to_array(image: ImageInput, camera: str, expected_wh: tuple[int, int]) -> np.ndarray:
    if isinstance(image, _BYTES):
        return decode_image(bytes(image), camera, expected_wh)
    if isinstance(image, _PATHS):
        path = Path(image)
        try:
            data = path.read_bytes()
        except OSError as exc:
            raise FrameError(f"camera '{camera}': cannot read {path} ({exc.strerror})") from exc
        return decode_image(data, camera, expected_wh)
    if isinstance(image, np.ndarray):
        return image
    raise FrameError(f"camera '{camera}': expected an ndarray, encoded bytes or a path, got {type(image).__name__}")


def _check_array(image: np.ndarray, camera: str, expected_wh: tuple[int, int]) -> np.ndarray:
    width, height = expected_wh
    if image.dtype != np.uint8:
        raise FrameError(f"camera '{camera}': image dtype is {image.dtype}, expected uint8")
    if image.ndim != 3 or image.shape[2] != 3:
        raise FrameError(f"camera '{camera}': image shape is {image.shape}, expected (H, W, 3) with 3 colour channels")
    if image.shape[:2] != (height, width):
        raise FrameError(
            f"camera '{camera}': image is {image.shape[1]}x{image.shape[0]}, model expects {width}x{height}"
        )
    return image


def _as_mapping(frame: Frame, cameras: Sequence[str]) -> Mapping[str, ImageInput]:
    if isinstance(frame, Mapping):
        unknown = [name for name in frame if name not in cameras]
        if unknown:
            raise FrameError(f"camera '{unknown[0]}': not a camera of this model (cameras: {', '.join(cameras)})")
        return frame
    if isinstance(frame, (str, bytes, np.ndarray)) or not isinstance(frame, Sequence):
        raise FrameError(
            f"frame: expected a mapping camera name -> image or a sequence of {len(cameras)} images, "
            f"got {type(frame).__name__}"
        )
    if len(frame) != len(cameras):
        raise FrameError(f"frame: got {len(frame)} images, expected {len(cameras)} in the order {', '.join(cameras)}")
    return dict(zip(cameras, frame))


def load_frame(
    frame: Frame,
    cameras: Sequence[str],
    image_wh: tuple[int, int],
    camera_sizes: Sequence[tuple[int, int]] | None = None,
) -> list[np.ndarray | None]:
    """Decode and validate one frame: one (H, W, 3) uint8 array per camera, ``None`` where missing.

    Args:
        frame: A mapping camera -> image, or the images in camera order.
        cameras: The model's camera names, in order.
        image_wh: (width, height) of every camera's images.
        camera_sizes: (width, height) of each camera's images where they differ (a file with virtual cameras);
            None: ``image_wh`` for all.

    Returns:
        list[np.ndarray | None]: One image per camera, None where missing.
    """
    return load_frames([frame], cameras, image_wh, camera_sizes=camera_sizes)[0]


def load_frames(
    frames: Sequence[Frame],
    cameras: Sequence[str],
    image_wh: tuple[int, int],
    map_images: Callable[[Callable[[Any], np.ndarray | None], Iterable[Any]], Iterable[np.ndarray | None]] = map,
    camera_sizes: Sequence[tuple[int, int]] | None = None,
) -> list[list[np.ndarray | None]]:
    """Decode and validate several frames; errors name the frame (when there are several) and the camera.

    Each camera's images must be ``image_wh``, or its own entry of ``camera_sizes`` where given.

    ``map_images`` runs the per-image work when more than one image needs decoding: a thread
    pool's ``map`` decodes them in parallel (OpenCV and libjpeg-turbo release the GIL while they
    decode; four 800 x 800 PNGs took under a third of the sequential time on a 16-core machine).
    Results and errors are those of the sequential order either way: the first bad image in
    frame and camera order is reported.
    """

    def named(b: int, exc: FrameError) -> FrameError:
        return FrameError(f"frame {b}: {exc}") if len(frames) > 1 else exc

    mappings: list[Mapping[str, ImageInput] | FrameError] = []
    for frame in frames:
        try:
            mappings.append(_as_mapping(frame, cameras))
        except FrameError as exc:  # raised when its turn comes, after the frames before it
            mappings.append(exc)

    size_of = dict(zip(cameras, camera_sizes or [image_wh] * len(cameras)))

    def one(task: tuple[str, ImageInput]) -> np.ndarray | None:
        camera, image = task
        wh = size_of[camera]
        return None if image is None else _check_array(_to_array(image, camera, wh), camera, wh)

    tasks = [
        (camera, images.get(camera)) for images in mappings if not isinstance(images, FrameError) for camera in cameras
    ]
    encoded = sum(isinstance(image, (*_BYTES, *_PATHS)) for _, image in tasks)
    results = iter((map_images if encoded > 1 else map)(one, tasks))
    loaded: list[list[np.ndarray | None]] = []
    for b, images in enumerate(mappings):
        if isinstance(images, FrameError):
            raise named(b, images) from None
        try:
            row = [next(results) for _ in cameras]
        except FrameError as exc:
            raise named(b, exc) from None
        if all(image is None for image in row):
            raise named(b, FrameError(f"frame: no camera image given (cameras: {', '.join(cameras)})"))
        loaded.append(row)
    return loaded


def stack_frames(frames: Sequence[list[np.ndarray | None]], image_wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Loaded frames -> ``(B, N, H, W, 3)`` uint8 (zeros for missing cameras) and ``(B, N)`` bool validity.

    Each image is copied exactly once, into its slot of the batch buffer; an image smaller than ``image_wh`` (a
    camera of its own size behind virtual cameras) fills the slot's top-left corner, the rest is zeros.
    """
    width, height = image_wh
    n = len(frames[0])
    padded = any(image is not None and image.shape[:2] != (height, width) for frame in frames for image in frame)
    images = (np.zeros if padded else np.empty)((len(frames), n, height, width, 3), np.uint8)
    valid = np.zeros((len(frames), n), dtype=bool)
    for b, frame in enumerate(frames):
        for i, image in enumerate(frame):
            if image is None:
                images[b, i] = 0
            else:
                images[b, i, : image.shape[0], : image.shape[1]] = image
                valid[b, i] = True
    return images, valid


def prepare_batch(
    frames: Sequence[Frame],
    cameras: Sequence[str],
    image_wh: tuple[int, int],
    camera_sizes: Sequence[tuple[int, int]] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frames -> ``(B, N, H, W, 3)`` uint8 and ``(B, N)`` bool; errors name the frame index too."""
    if isinstance(frames, Mapping) or len(frames) == 0:
        raise FrameError("frames: expected a non-empty sequence of frames")
    loaded = []
    for b, frame in enumerate(frames):
        try:
            loaded.append(load_frame(frame, cameras, image_wh, camera_sizes))
        except FrameError as exc:
            raise FrameError(f"frame {b}: {exc}") from None
    return stack_frames(loaded, image_wh)


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _short(name: str) -> str:
    return name.rsplit("_", 1)[-1]


def frames_from_paths(paths: Sequence[str | os.PathLike], cameras: Sequence[str]) -> list[tuple[str, dict[str, Path]]]:
    """Frames named by their files: ``(frame name, {camera: image path})``.

    Accepted: one folder with an image per camera (named by the camera, e.g.
    ``fisheye_camera_front.png``, or its last word, ``front.png``); one folder with a sub-folder
    per camera holding equally named images (several frames); or one file per camera, in the
    model's camera order.
    """
    items = [Path(p) for p in paths]
    if len(items) == 1 and items[0].is_dir():
        folder = items[0]
        subdirs = {c: folder / c for c in cameras if (folder / c).is_dir()}
        if len(subdirs) == len(cameras):
            stems = sorted(p.name for p in subdirs[cameras[0]].iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not stems:
                raise FrameError(f"{subdirs[cameras[0]]}: no PNG or JPEG images")
            return [(Path(stem).stem, {c: subdirs[c] / stem for c in cameras}) for stem in stems]
        files = [p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES]
        frame = {}
        for camera in cameras:
            found = [p for p in files if p.stem in (camera, _short(camera))]
            if not found:
                raise FrameError(
                    f"camera '{camera}': no image in {folder} "
                    f"(expected {camera}.png, {_short(camera)}.png or a folder {camera}/)"
                )
            frame[camera] = found[0]
        return [(folder.name, frame)]
    if len(items) != len(cameras):
        raise FrameError(
            f"images: got {len(items)} paths; give one folder, "
            f"or {len(cameras)} files in the order {', '.join(cameras)}"
        )
    for path in items:
        if not path.is_file():
            raise FrameError(f"images: {path} is not a file")
    return [(items[0].parent.name, dict(zip(cameras, items)))]
