"""What virtual cameras make of a robot's pictures: each robot image beside the training view resampled from it.

    views = resample_views(front, {"cam0": image, ...})     # the training cameras' pictures, as the graph makes them
    picture = draw_virtual_cameras(front, images)           # robot image | training view, one row per camera

The resampling is cv2.remap with OpenCV 4.x's 1/32-px fixed-point maps and the front end's fill: what an exported
file's front end computes ([`fisheye_infer.geometry.virtual`][fisheye_infer.geometry.virtual]), outside the graph.
"""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np

from fisheye_infer.cameras.virtual_view import UNSEEN_FILL
from fisheye_infer.geometry.virtual import VirtualFront

__all__ = ["resample_views", "draw_virtual_cameras"]


def resample_views(front: VirtualFront, images: Mapping[str, np.ndarray]) -> list[np.ndarray]:
    """Each slot's training picture from its robot camera's image.

    Args:
        front: The virtual cameras ([`virtual_front`][fisheye_infer.geometry.virtual.virtual_front]).
        images: Robot camera name -> (H, W, 3) uint8 image at that camera's size.

    Returns:
        list[np.ndarray]: One (Ht, Wt, 3) uint8 picture per slot, in slot order.
    """
    views = []
    for report, view in zip(front.reports, front.views):
        fixed = cv2.convertMaps(view.map_x, view.map_y, cv2.CV_16SC2)
        out = cv2.remap(images[report.camera], *fixed, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        out[view.unseen] = UNSEEN_FILL
        views.append(out)
    return views


def draw_virtual_cameras(front: VirtualFront, images: Mapping[str, np.ndarray], height: int = 320) -> np.ndarray:
    """One row per slot: the robot camera's image, then the training view resampled from it, each scaled to
    ``height`` and labelled with the camera, its coverage and the rotation compensated.

    Args:
        front: The virtual cameras.
        images: Robot camera name -> its image.
        height: Height of each picture in the result, pixels.

    Returns:
        np.ndarray: A BGR uint8 picture.
    """
    rows = []
    band = 22
    for report, view in zip(front.reports, resample_views(front, images)):
        pair = []
        for img, text in (
            (images[report.camera], f"{report.camera}, {report.image_size[0]}x{report.image_size[1]}"),
            (view, f"as {report.slot}: {report.coverage:.0%} seen, {report.rotation_deg:.1f} deg turned"),
        ):
            size = (round(img.shape[1] * height / img.shape[0]), height)
            scaled = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
            labelled = np.full((height + band, max(scaled.shape[1], 9 * len(text)), 3), 255, np.uint8)
            labelled[band:, : scaled.shape[1]] = scaled
            cv2.putText(labelled, text, (4, 15), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (30, 30, 30), 1, cv2.LINE_AA)
            pair.append(labelled)
        rows.append(pair)
    gap = 8
    widths = [max(r[k].shape[1] for r in rows) for k in (0, 1)]
    canvas = np.full((len(rows) * (height + band + gap) - gap, widths[0] + gap + widths[1], 3), 255, np.uint8)
    for i, (left, right) in enumerate(rows):
        y = i * (height + band + gap)
        canvas[y : y + height + band, : left.shape[1]] = left
        canvas[y : y + height + band, widths[0] + gap : widths[0] + gap + right.shape[1]] = right
    return canvas
