"""Box utilities: corners, BEV footprints, and 3D boxes drawn through a fisheye camera model.

Boxes are (K, 7) arrays ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame (x forward,
y left, z up; yaw about +z from +x, counter-clockwise), the detectors' output layout.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.cameras.rig import Rig

__all__ = ["BOX_EDGES", "check_boxes", "corners", "bev_corners", "centres", "box_diff", "project_boxes"]

#: Corner index pairs of the 12 box edges; corners 0-3 are the bottom face, 4-7 the top,
#: 0 = front-left, 1 = front-right, 2 = rear-right, 3 = rear-left (in the box's own frame).
BOX_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))
_SIGNS = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=np.float64)


def check_boxes(boxes: np.ndarray, name: str = "boxes") -> np.ndarray:
    arr = np.asarray(boxes)
    if arr.ndim != 2 or arr.shape[1] != 7:
        raise ValueError(f"{name}: expected shape (K, 7) as x, y, z_bottom, l, w, h, yaw; got {arr.shape}")
    return arr


def box_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Largest absolute difference of each pair of boxes (..., 7) -> (...,), in float64; yaw is
    compared on the circle (+pi and -pi are the same angle)."""
    d = np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64))
    d[..., 6] = np.minimum(d[..., 6], np.abs(2 * np.pi - d[..., 6]))
    return d.max(axis=-1)


def bev_corners(boxes: np.ndarray) -> np.ndarray:
    """(K, 4, 2) footprint corners in the x-y plane, in corner order 0-3."""
    b = check_boxes(boxes).astype(np.float64)
    half = 0.5 * b[:, None, 3:5] * _SIGNS[None]  # K x 4 x 2, box frame
    c, s = np.cos(b[:, 6])[:, None], np.sin(b[:, 6])[:, None]
    x = c * half[..., 0] - s * half[..., 1] + b[:, None, 0]
    y = s * half[..., 0] + c * half[..., 1] + b[:, None, 1]
    return np.stack([x, y], axis=-1)


def corners(boxes: np.ndarray) -> np.ndarray:
    """(K, 8, 3) corners: bottom face 0-3, then the top face 4-7 above them."""
    b = check_boxes(boxes).astype(np.float64)
    foot = bev_corners(b)
    bottom = np.concatenate([foot, np.broadcast_to(b[:, None, 2:3], (len(b), 4, 1))], axis=-1)
    top = bottom + np.concatenate([np.zeros((len(b), 4, 2)), np.broadcast_to(b[:, None, 5:6], (len(b), 4, 1))], axis=-1)
    return np.concatenate([bottom, top], axis=1)


def centres(boxes: np.ndarray) -> np.ndarray:
    """(K, 3) gravity centres (z_bottom + h / 2)."""
    b = check_boxes(boxes).astype(np.float64)
    return np.stack([b[:, 0], b[:, 1], b[:, 2] + b[:, 5] / 2], axis=-1)


def project_boxes(boxes: np.ndarray, rig: Rig, samples_per_edge: int = 16) -> dict[str, list[list[np.ndarray]]]:
    """Each box's edges as pixel polylines in every camera, following the lens's curvature.

    Edges are sampled in 3D and projected through the camera model; a polyline is cut where
    its points leave the camera's valid area (outside the fov or the image). Returns, per
    camera name, one list per box of (M, 2) float arrays.
    """
    pts3d = corners(boxes)
    t = np.linspace(0.0, 1.0, samples_per_edge)
    a = pts3d[:, [e[0] for e in BOX_EDGES]]  # K x 12 x 3
    b = pts3d[:, [e[1] for e in BOX_EDGES]]
    samples = a[:, :, None] + (b - a)[:, :, None] * t[None, None, :, None]  # K x 12 x S x 3
    flat = samples.reshape(-1, 3)
    result: dict[str, list[list[np.ndarray]]] = {}
    for cam, lidar2cam in zip(rig.cameras, rig.lidar2cam()):
        cam_pts = flat @ lidar2cam[:3, :3].T + lidar2cam[:3, 3]
        uv, valid = cam.model.project(cam_pts)
        uv = uv.reshape(len(samples), len(BOX_EDGES), samples_per_edge, 2)
        valid = valid.reshape(len(samples), len(BOX_EDGES), samples_per_edge)
        whole: np.ndarray = np.all(valid, axis=2)  # (K, 12): most edges are all in view or none
        seen: np.ndarray = np.any(valid, axis=2)
        per_box = []
        for k in range(len(samples)):
            lines: list[np.ndarray] = []
            for e in np.flatnonzero(seen[k]):
                if whole[k, e]:
                    lines.append(uv[k, e])
                    continue
                runs = np.split(
                    np.arange(samples_per_edge), np.flatnonzero(np.diff(valid[k, e].astype(np.int8)) != 0) + 1
                )
                lines.extend(uv[k, e, run] for run in runs if len(run) > 1 and valid[k, e, run[0]])
            per_box.append(lines)
        result[cam.name] = per_box
    return result
