"""Pictures drawn with OpenCV: the rig from above, a sampling grid on a fisheye image, and detections
(boxes projected into each fisheye image through the camera model, and a bird's-eye view).

Everything returns a BGR uint8 image; ``save_png`` writes one. No plotting library is needed,
so the pictures work on a robot with the core install.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.scenes.scene import CLASS_COLOURS

if TYPE_CHECKING:
    from fisheye_infer.runtime.detections import Detections

__all__ = [
    "bev_pixels",
    "class_colour",
    "camera_colours",
    "draw_bev",
    "draw_detections",
    "draw_rig",
    "draw_sampling_grid",
    "save_png",
]

_PALETTE = [(66, 133, 244), (52, 168, 83), (251, 188, 5), (234, 67, 53), (171, 71, 188), (0, 172, 193)]


def camera_colours(n: int) -> list[tuple[int, int, int]]:
    """One BGR colour per camera, stable across pictures."""
    return [_PALETTE[i % len(_PALETTE)][::-1] for i in range(n)]


def _text(
    img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int] = (30, 30, 30), scale: float = 0.5
) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def draw_rig(rig: Rig, size: int = 800, extent_m: float = 6.0) -> np.ndarray:
    """A rig seen from above: each camera's position, optical axis and horizontal field of view as a wedge.

    Lidar x points up the picture, y to the left; rings every metre.

    Args:
        rig (Rig): The cameras.
        size (int): Side of the square picture, pixels.
        extent_m (float): Metres from the centre to the picture's edge.

    Returns:
        np.ndarray: `(size, size, 3)` uint8 BGR picture.
    """
    img: np.ndarray = np.full((size, size, 3), 255, np.uint8)
    scale = size / (2 * extent_m)

    def px(x: float, y: float) -> tuple[int, int]:
        return int(round(size / 2 - y * scale)), int(round(size / 2 - x * scale))

    for r in range(1, int(extent_m) + 1):  # 1 m rings
        cv2.circle(img, px(0, 0), int(r * scale), (230, 230, 230), 1, cv2.LINE_AA)
    xs = [c.position[0] for c in rig.cameras]
    ys = [c.position[1] for c in rig.cameras]
    cv2.rectangle(img, px(max(xs), max(ys)), px(min(xs), min(ys)), (180, 180, 180), 2)
    cv2.arrowedLine(img, px(0, 0), px(1, 0), (0, 0, 200), 2, tipLength=0.15)
    cv2.arrowedLine(img, px(0, 0), px(0, 1), (0, 160, 0), 2, tipLength=0.15)
    _text(img, "x", px(1.15, 0.1), (0, 0, 200))
    _text(img, "y", px(0.1, 1.2), (0, 160, 0))
    wedge = 1.8
    for cam, colour in zip(rig.cameras, camera_colours(len(rig))):
        x, y, _ = cam.position
        half = math.radians(getattr(cam.model, "fov", 90.0) / 2.0)
        centre = px(x, y)
        points = [centre]
        for a in np.linspace(cam.heading - half, cam.heading + half, 64):
            points.append(px(x + wedge * math.cos(a), y + wedge * math.sin(a)))
        overlay = img.copy()
        cv2.fillPoly(overlay, [np.array(points, np.int32)], colour)
        img = cv2.addWeighted(overlay, 0.18, img, 0.82, 0)
        tip = px(x + 0.9 * math.cos(cam.heading), y + 0.9 * math.sin(cam.heading))
        cv2.arrowedLine(img, centre, tip, colour, 2, tipLength=0.2)
        cv2.circle(img, centre, 5, colour, -1, cv2.LINE_AA)
        label = px(x + 1.2 * math.cos(cam.heading), y + 1.2 * math.sin(cam.heading))
        _text(img, cam.name.removeprefix("fisheye_camera_"), (label[0] - 20, label[1]), colour)
    _text(img, f"{rig.name}  ({rig.hash})  rings: 1 m", (10, 20))
    return img


def draw_sampling_grid(
    camera: OCamModel, grid: np.ndarray, image: np.ndarray | None = None, every: int = 1
) -> np.ndarray:
    """The fisheye image (or its valid area) with the pixel each grid cell samples.

    ``grid`` is a normalised (H, W, 2) table as ``grid_sample`` receives it; cells outside the
    lens's fov (the (-1, -1) sentinel) are drawn in red at the image corner they map to.
    """
    if image is None:
        base = camera.valid_area()
        canvas = cv2.cvtColor((base // 4 + 160).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    else:
        canvas = np.ascontiguousarray(image.copy())
    size = np.array([camera.width, camera.height], dtype=np.float64)
    uv = (grid.astype(np.float64) + 1.0) * size / 2.0
    h, w = grid.shape[:2]
    for i in range(0, h, every):
        row = uv[i, ::every]
        cv2.polylines(canvas, [np.round(row).astype(np.int32)], False, (200, 120, 0), 1, cv2.LINE_AA)
    for j in range(0, w, max(every, w // 20)):
        col = uv[::every, j]
        cv2.polylines(canvas, [np.round(col).astype(np.int32)], False, (0, 140, 0), 1, cv2.LINE_AA)
    outside = int(np.all(np.isclose(uv, -1.0, atol=1e-3), axis=-1).sum())
    if outside:
        cv2.circle(canvas, (0, 0), 6, (0, 0, 255), -1)
    _text(canvas, f"sampling grid {h}x{w}: rows blue, columns green; {outside} cells outside the fov", (10, 20))
    return canvas


def save_png(path: str | Path, image: np.ndarray) -> Path:
    """Write a picture as PNG, creating missing folders.

    Args:
        path (str | Path): The file to write.
        image (np.ndarray): `(H, W, 3)` uint8 BGR picture (or `(H, W)` grey).

    Returns:
        Path: The file written.

    Raises:
        OSError: OpenCV cannot write the file.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise OSError(f"cannot write {path}")
    return path


def class_colour(name: str) -> tuple[int, int, int]:
    """The colour (BGR, 0-255) the synthetic scenes paint the class with, and every overlay draws it with;
    grey for other classes."""
    return CLASS_COLOURS.get(name, (160, 160, 160))


def bev_pixels(x: np.ndarray, y: np.ndarray, size: int = 800, extent_m: float = 50.0) -> np.ndarray:
    """Where ego-frame points fall in ``draw_bev``'s picture.

    Args:
        x (np.ndarray): Lidar x of the points, metres (up the picture).
        y (np.ndarray): Lidar y of the points, metres (to the left).
        size (int): Side of the square picture, pixels.
        extent_m (float): Metres from the ego to the picture's edge.

    Returns:
        np.ndarray: `(..., 2)` float pixel column and row per point.
    """
    scale = size / (2 * extent_m)
    return np.stack([size / 2 - np.asarray(y) * scale, size / 2 - np.asarray(x) * scale], axis=-1)


def draw_bev(
    detections: Detections,
    size: int = 800,
    extent_m: float = 50.0,
    rig: Rig | None = None,
    labels: Sequence[str] | None = None,
) -> np.ndarray:
    """A bird's-eye view of detections: boxes with class and score, range rings every 10 m.

    Lidar x points up the picture, y to the left; a line marks each box's front.

    Args:
        detections (Detections): The boxes ([`Detections`][fisheye_infer.runtime.detections.Detections]).
        size (int): Side of the square picture, pixels.
        extent_m (float): Metres from the ego to the picture's edge.
        rig (Rig | None): Draw the ego footprint spanned by the rig's cameras.
        labels (Sequence[str] | None): The text beside each box (default: class and score).

    Returns:
        np.ndarray: `(size, size, 3)` uint8 BGR picture.
    """
    from fisheye_infer.runtime.box_geometry import bev_corners

    img = np.full((size, size, 3), 250, np.uint8)
    scale = size / (2 * extent_m)

    def px(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return bev_pixels(x, y, size, extent_m)

    for r in range(10, int(extent_m) + 1, 10):
        cv2.circle(img, (size // 2, size // 2), int(r * scale), (215, 215, 215), 1, cv2.LINE_AA)
        _text(img, f"{r} m", (size // 2 + 3, int(size / 2 - r * scale) + 14), (150, 150, 150), 0.4)
    if rig is not None:
        pos = np.array([c.position for c in rig.cameras])
        (x0, y0), (x1, y1) = pos[:, :2].min(axis=0), pos[:, :2].max(axis=0)
        corners = px(np.array([x1, x1, x0, x0]), np.array([y1, y0, y0, y1]))
        cv2.fillPoly(img, [np.round(corners).astype(np.int32)], (90, 90, 90))
    cv2.arrowedLine(img, (size // 2, size // 2), (size // 2, size // 2 - int(4 * scale)), (0, 0, 0), 2, tipLength=0.3)
    for box, name, label in zip(bev_corners(detections.boxes), detections.names, _labels(detections, labels)):
        colour = class_colour(name)
        poly = np.round(px(box[:, 0], box[:, 1])).astype(np.int32)
        cv2.polylines(img, [poly], True, colour, 2, cv2.LINE_AA)
        front = np.round(poly[:2].mean(axis=0)).astype(int)
        cv2.line(img, tuple(np.round(poly.mean(axis=0)).astype(int)), tuple(front), colour, 1, cv2.LINE_AA)
        _text(img, label, tuple(poly.max(axis=0) + np.array([2, 0])), colour, 0.35)
    _text(img, f"bird's-eye view, {len(detections)} boxes (x up, y left)", (10, 20))
    return img


def _labels(detections: Detections, labels: Sequence[str] | None) -> Sequence[str]:
    """The text beside each box: ``labels``, or class and score."""
    if labels is None:
        return [f"{name} {score:.2f}" for name, score in zip(detections.names, detections.scores)]
    if len(labels) != len(detections):
        raise ValueError(f"labels: expected {len(detections)} (one per box), got {len(labels)}")
    return labels


def draw_detections(
    detections: Detections,
    rig: Rig,
    images: Mapping[str, np.ndarray | None] | None = None,
    tile: int = 400,
    labels: Sequence[str] | None = None,
) -> np.ndarray:
    """The camera images with the boxes projected through the rig's camera models, beside the bird's-eye view.

    Args:
        detections (Detections): The boxes ([`Detections`][fisheye_infer.runtime.detections.Detections]).
        rig (Rig): The cameras to project through (a detector's ``info.rig``).
        images (Mapping[str, np.ndarray | None] | None): Camera name -> `(H, W, 3)` uint8 BGR image; cameras
            without one are drawn on black.
        tile (int): Side of each camera's tile, pixels.
        labels (Sequence[str] | None): The text beside each box (default: class and score).

    Returns:
        np.ndarray: One BGR uint8 picture: a 2-column grid of camera tiles on the left, the bird's-eye view on
            the right.

    Examples:
        ```python
        dets = detector.detect(images)
        save_png("detections.png", draw_detections(dets, detector.info.rig, images))
        ```
    """
    from fisheye_infer.runtime.box_geometry import project_boxes

    lines = project_boxes(detections.boxes, rig)
    texts = _labels(detections, labels)
    tiles = []
    for cam in rig.cameras:
        model = cam.model
        image = None if images is None else images.get(cam.name)
        canvas = (
            np.zeros((model.height, model.width, 3), np.uint8) if image is None else np.ascontiguousarray(image.copy())
        )
        thickness = max(1, model.width // 400)
        for polylines, name, text in zip(lines[cam.name], detections.names, texts):
            colour = class_colour(name)
            for line in polylines:
                cv2.polylines(canvas, [np.round(line).astype(np.int32)], False, colour, thickness, cv2.LINE_AA)
            if polylines:
                top = np.concatenate(polylines).min(axis=0)
                _text(canvas, text, (int(top[0]), max(12, int(top[1]) - 4)), colour, 0.4 * thickness)
        canvas = cv2.resize(canvas, (tile, tile), interpolation=cv2.INTER_AREA)
        _text(canvas, cam.name, (8, tile - 10), (255, 255, 255))
        tiles.append(canvas)
    while len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    grid = np.vstack([np.hstack(tiles[i : i + 2]) for i in range(0, len(tiles), 2)])
    bev = draw_bev(detections, size=grid.shape[0], rig=rig, labels=texts)
    return np.hstack([grid, bev])
