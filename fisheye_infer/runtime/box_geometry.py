"""Box utilities: corners, BEV footprints, and 3D boxes drawn through a fisheye camera model.

Boxes are (K, 7) arrays ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame (x forward,
y left, z up; yaw about +z from +x, counter-clockwise), the detectors' output layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fisheye_infer.cameras.camera_models import AnyCameraModel
from fisheye_infer.cameras.rig import Rig

__all__ = [
    "BOX_EDGES",
    "check_boxes",
    "corners",
    "bev_corners",
    "centres",
    "box_diff",
    "Polylines",
    "project_edges",
    "project_boxes",
]

#: Corner index pairs of the 12 box edges; corners 0-3 are the bottom face, 4-7 the top,
#: 0 = front-left, 1 = front-right, 2 = rear-right, 3 = rear-left (in the box's own frame).
BOX_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))
#: Radians beyond the field of view a box's corners must all be for its edges to be skipped (rounding of the
#: models' own fov tests).
_CULL_MARGIN = 1e-9
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


@dataclass(frozen=True)
class Polylines:
    """Pixel polylines packed into arrays: line ``i`` is ``points[starts[i]:starts[i + 1]]`` and belongs to box
    ``boxes[i]``. Lines come in box order, a box's in edge order (``BOX_EDGES``), an edge's pieces in order along it.

    Attributes:
        points (np.ndarray): (P, 2) pixels (u, v) of every line, one after another.
        starts (np.ndarray): (L + 1,) int64 offsets of the lines in ``points``, ending with P.
        boxes (np.ndarray): (L,) int64 index of each line's box.
    """

    points: np.ndarray
    starts: np.ndarray
    boxes: np.ndarray

    def lines(self) -> list[np.ndarray]:
        """Each line's (M, 2) points, as views of ``points``.

        Returns:
            list[np.ndarray]: the L lines in order.
        """
        return np.split(self.points, self.starts[1:-1]) if len(self.boxes) else []


def project_edges(
    boxes: np.ndarray, rig: Rig, samples_per_edge: int = 16, pixels_per_sample: float | None = None
) -> dict[str, Polylines]:
    """Every box's edges as pixel polylines in every camera, following the lens's curvature, packed.

    Each edge is sampled at up to ``samples_per_edge`` points in 3D and all samples go through each camera's model
    in one call; a polyline is cut where its points leave the camera's valid area (outside the fov or the image),
    and a piece of a single point is dropped (unless it is the whole edge). With ``pixels_per_sample``, an edge
    whose two corners both project takes one point per that many pixels between them (at least 2), so a small or
    distant box costs a few points; an edge with a corner outside the valid area keeps every sample, which is where
    its cut falls.

    Args:
        boxes (np.ndarray): (K, 7) boxes ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame.
        rig (Rig): the cameras, their models and extrinsics.
        samples_per_edge (int): points sampled along each edge, its two corners included (the most, with
            ``pixels_per_sample``).
        pixels_per_sample (float | None): pixels between an edge's samples, in each camera; None: every edge gets
            ``samples_per_edge``.

    Returns:
        dict[str, Polylines]: per camera name, the visible pieces of the edges.
    """
    pts3d = corners(boxes)
    edges = len(BOX_EDGES)
    result: dict[str, Polylines] = {}
    for cam, lidar2cam in zip(rig.cameras, rig.lidar2cam()):
        in_cam = pts3d @ lidar2cam[:3, :3].T + lidar2cam[:3, 3]  # K 8 x 3
        seen = np.flatnonzero(_may_be_seen(cam.model, in_cam))
        ca = in_cam[seen][:, [e[0] for e in BOX_EDGES]].reshape(-1, 3)  # K' 12 x 3
        cb = in_cam[seen][:, [e[1] for e in BOX_EDGES]].reshape(-1, 3)
        count = _samples(cam.model, ca, cb, samples_per_edge, pixels_per_sample)
        offset = np.cumsum(count) - count  # each edge's first sample
        along = np.arange(int(count.sum())) - np.repeat(offset, count)
        t = (along / np.repeat(np.maximum(count - 1, 1), count))[:, None]
        uv, valid = cam.model.project(np.repeat(ca, count, axis=0) + np.repeat(cb - ca, count, axis=0) * t)
        padded = np.zeros((len(count), int(count.max(initial=0)) + 2), np.int8)  # each edge's flags, False around
        padded[np.repeat(np.arange(len(count)), count), along + 1] = valid
        step = np.diff(padded, axis=1)
        edge, first = np.nonzero(step == 1)  # where each run of valid points starts, edge by edge
        last = np.nonzero(step == -1)[1]  # and ends (exclusive); runs do not interleave, so they pair up in order
        length = last - first
        keep = (length > 1) | (length == count[edge])
        edge, first, length = edge[keep], first[keep], length[keep]
        starts = np.zeros(len(length) + 1, np.int64)
        np.cumsum(length, out=starts[1:])
        index = np.arange(starts[-1]) + np.repeat(offset[edge] + first - starts[:-1], length)
        result[cam.name] = Polylines(uv[index], starts, seen[edge // edges].astype(np.int64))
    return result


def _may_be_seen(model: AnyCameraModel, in_cam: np.ndarray) -> np.ndarray:
    """(K,) bool: False for a box whose eight camera-frame corners ``in_cam`` (K, 8, 3) all lie beyond the model's
    field of view (and behind the camera, for a field under 180 degrees). That region is a convex cone, so such a
    box is wholly in it and none of its edges' samples can be valid."""
    fov = getattr(model, "fov", None)
    limit = math.radians(max(fov / 2, 90.0) if fov is not None else 90.0) + _CULL_MARGIN
    angle = np.arctan2(np.hypot(in_cam[..., 0], in_cam[..., 1]), in_cam[..., 2])
    return ~(angle > limit).all(axis=1)


def _samples(
    model: AnyCameraModel, ca: np.ndarray, cb: np.ndarray, most: int, pixels_per_sample: float | None
) -> np.ndarray:
    """(E,) samples of each edge from camera-frame corners ``ca`` to ``cb`` (``project_edges``)."""
    if pixels_per_sample is None:
        return np.full(len(ca), most, np.int64)
    uv, valid = model.project(np.concatenate([ca, cb]))
    n = len(ca)
    with np.errstate(invalid="ignore"):
        span = np.nan_to_num(np.hypot(*(uv[:n] - uv[n:]).T), nan=np.inf, posinf=np.inf)
        count = np.minimum(np.ceil(np.minimum(span / pixels_per_sample, most)).astype(np.int64) + 1, most)
    return np.where(valid[:n] & valid[n:], np.maximum(count, min(2, most)), most).astype(np.int64)


def project_boxes(
    boxes: np.ndarray, rig: Rig, samples_per_edge: int = 16, pixels_per_sample: float | None = None
) -> dict[str, list[list[np.ndarray]]]:
    """Each box's edges as pixel polylines in every camera, following the lens's curvature (``project_edges``).

    Args:
        boxes (np.ndarray): (K, 7) boxes ``x, y, z_bottom, l, w, h, yaw`` in the lidar frame.
        rig (Rig): the cameras, their models and extrinsics.
        samples_per_edge (int): points sampled along each edge, its two corners included.
        pixels_per_sample (float | None): pixels between an edge's samples (``project_edges``).

    Returns:
        dict[str, list[list[np.ndarray]]]: per camera name, one list per box of (M, 2) float arrays.
    """
    result: dict[str, list[list[np.ndarray]]] = {}
    for name, packed in project_edges(boxes, rig, samples_per_edge, pixels_per_sample).items():
        per_box: list[list[np.ndarray]] = [[] for _ in range(len(boxes))]
        for k, line in zip(packed.boxes.tolist(), packed.lines(), strict=True):
            per_box[k].append(line)
        result[name] = per_box
    return result
