"""Pictures drawn with OpenCV: the rig seen from above, and where a sampling grid reads a fisheye image.

Everything returns a BGR uint8 image; ``save_png`` writes one. No plotting library is needed,
so the pictures work on a robot with the core install.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

from fisheye_infer.camera import OCamModel
from fisheye_infer.rig import Rig

__all__ = ["camera_colours", "draw_rig", "draw_sampling_grid", "save_png"]

_PALETTE = [(66, 133, 244), (52, 168, 83), (251, 188, 5), (234, 67, 53), (171, 71, 188), (0, 172, 193)]


def camera_colours(n: int) -> list[tuple[int, int, int]]:
    """One BGR colour per camera, stable across pictures."""
    return [_PALETTE[i % len(_PALETTE)][::-1] for i in range(n)]


def _text(img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int] = (30, 30, 30), scale: float = 0.5) -> None:
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def draw_rig(rig: Rig, size: int = 800, extent_m: float = 6.0) -> np.ndarray:
    """Top view: lidar x points up the picture, y to the left; each camera's position, optical axis
    and horizontal field of view as a wedge."""
    img = np.full((size, size, 3), 255, np.uint8)
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


def draw_sampling_grid(camera: OCamModel, grid: np.ndarray, image: np.ndarray | None = None, every: int = 1) -> np.ndarray:
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), image):
        raise OSError(f"cannot write {path}")
    return path
