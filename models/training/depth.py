"""Depth targets of an LSS view transform from the renderer: which depth bin each lifted ray should pick.

The official BEVDet models learn their depth distribution only through the detection losses.
Synthetic frames know the true distance of every ray, so training can also supervise the depth
head directly, as BEVDepth does with lidar points: a far denser signal for the image features,
which matters most when the backbone starts untrained (no ImageNet weights here).

Every LSS geometry here lifts a feature cell along one ray from its view's centre: the fisheye
LSS (radial depth on an angular grid), the pinhole LSS of the pinhole and perspective-rectified
baselines (depth along the optical axis) and the cylindrical LSS (the cylinder's radius). The
targets need no more than that: the lidar-frame points of the frustum (a cell's bins are the
distances of its points from the view's centre, so each geometry's own depth convention and bin
spacing carry over) and the same frustum at a finer feature size (the rays inside each cell).

A cell spans several degrees (10 x 5.5 for the compact model's 10 x 40 angular grid), so one ray
per cell would mostly see the ground in front of an object. The target follows BEVDepth's choice
of the nearest lidar point in a patch, with objects first: each cell is sampled by ``k x k`` rays
(the pictures' own intersection code, ``Renderer.ray_depth``); if any of them meets a box, the
cell's target is the nearest box hit (nearest in the geometry's own depth: along the optical axis
for a pinhole view), otherwise the distance at which its centre ray meets the ground; the bin is
the one whose point on the centre ray lies nearest that depth. A cell whose rays meet nothing
within the bins, or whose pixels lie mostly outside the lens's field of view (the fisheye LSS's mask,
or the black beyond the lens in a rectified view wider than it), carries no target (-1).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fisheye_infer.geometry.frustum import frustum_to_lidar
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry, view_points
from fisheye_infer.scenes.render import Renderer
from fisheye_infer.scenes.scene import Scene

__all__ = ["DepthTargets", "depth_loss", "lidar_frustum"]


def lidar_frustum(geometry: Any, feature_size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(V, D, H, W, 3) lidar-frame points of an LSS geometry's frustum, at ``feature_size`` (default its own),
    and the centres (V, 3) of its V views."""
    params = geometry.params
    if feature_size is not None:
        params = params.model_copy(update={"feature_size": tuple(feature_size)})
    frustum = geometry.frustum if feature_size is None else params.frustum()
    if isinstance(geometry, PinholeLSSGeometry):
        return view_points(frustum, geometry.views).astype(np.float64), geometry.views.cam2lidar[:, :3, 3]
    cam2lidar = np.asarray(geometry.cam2lidar, np.float64)
    return frustum_to_lidar(frustum, cam2lidar).astype(np.float64), cam2lidar[:, :3, 3]


def _inside_lens(geometry: Any, views: int) -> np.ndarray:
    """(V, H*W) bool: the cells of each of the V views that show its camera's lens (every cell of a pinhole
    camera's view), from the geometry's ``inside_lens`` (one mask per view)."""
    h, w = geometry.params.feature_size
    inside = geometry.inside_lens
    if inside is None:
        return np.ones((views, h * w), bool)
    return np.asarray(inside, bool).reshape(views, h * w)


class DepthTargets:
    """Per-frame depth-bin targets (V, H, W) int64 for one model's lift geometry (V views: cameras, or
    the perspective views of each camera, in the geometry's order).

    targets = DepthTargets(model.view_transform.geometry)
    bins = targets(sample.scene)        # -1 where there is no target
    """

    def __init__(self, geometry: Any, samples: int = 4) -> None:
        points, origins = lidar_frustum(geometry)  # V x D x H x W x 3
        v, d, h, w, _ = points.shape
        k = int(samples)
        distance = np.linalg.norm(points - origins[:, None, None, None], axis=-1)  # V x D x H x W
        self.edges = ((distance[:, 1:] + distance[:, :-1]) / 2).reshape(v, d - 1, h * w)
        self.lowest = (distance[:, 0] - (distance[:, 1] - distance[:, 0]) / 2).reshape(v, h * w)
        self.highest = (distance[:, -1] + (distance[:, -1] - distance[:, -2]) / 2).reshape(v, h * w)
        centre = points[:, 0] - origins[:, None, None]
        self.first = np.linalg.norm(centre, axis=-1).reshape(v, h * w)  # distance of the first bin
        self.centre = (centre / self.first.reshape(v, h, w, 1)).reshape(v, h * w, 3)
        fine_points, _ = lidar_frustum(geometry, (h * k, w * k))
        fine = fine_points[:, 0] - origins[:, None, None]
        # fine rays grouped by the coarse cell they fall in: V x (H*W*k*k), with their first bin's distance
        fine = fine.reshape(v, h, k, w, k, 3).transpose(0, 1, 3, 2, 4, 5).reshape(v, -1, 3)
        self.fine_first = np.linalg.norm(fine, axis=-1)
        self.fine = fine / self.fine_first[..., None]
        self.inside = _inside_lens(geometry, v)
        self.origins, self.shape, self.k2 = origins, (h, w), k * k
        self.renderer = Renderer()

    def __call__(self, scene: Scene, inside_lens: np.ndarray | None = None) -> np.ndarray:
        """(V, H, W) bins of ``scene``; ``inside_lens`` (V, H, W) replaces the geometry's cells inside the lens
        (the frame's lenses, when they are not the geometry's)."""
        inside = self.inside if inside_lens is None else np.asarray(inside_lens, bool).reshape(self.inside.shape)
        ground = Scene(np.zeros((0, 7)), np.zeros(0, np.int64), scene.ground_z)
        out = np.full((len(self.origins), self.centre.shape[1]), -1, np.int64)
        for n, o in enumerate(self.origins):
            fine = self.fine[n].T
            with_boxes = self.renderer.ray_depth(o, fine, scene)
            box_hit = with_boxes < self.renderer.ray_depth(o, fine, ground)
            # nearest in the geometry's own depth: a hit's distance over its ray's first-bin distance
            depth = np.where(box_hit, with_boxes / self.fine_first[n], np.inf)
            nearest_box = depth.reshape(-1, self.k2).min(axis=1) * self.first[n]  # along the cell's centre ray
            t = np.where(np.isfinite(nearest_box), nearest_box, self.renderer.ray_depth(o, self.centre[n].T, scene))
            bins = (t[None] > self.edges[n]).sum(axis=0)
            ok = np.isfinite(t) & (t >= self.lowest[n]) & (t < self.highest[n]) & inside[n]
            out[n, ok] = bins[ok]
        return out.reshape(len(self.origins), *self.shape)


def depth_loss(probs: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """BEVDepth's depth loss: binary cross-entropy of the softmax depth ``probs`` (M, D, H, W)
    against one-hot bins ``target`` (M, H, W) (-1: none), summed and divided by the rays with a target."""
    d = probs.shape[1]
    valid = target >= 0
    if not bool(valid.any()):
        return probs.sum() * 0.0
    p = probs.permute(0, 2, 3, 1)[valid].clamp(1e-6, 1 - 1e-6)  # R x D
    onehot = torch.nn.functional.one_hot(target[valid], d).to(p.dtype)
    return torch.nn.functional.binary_cross_entropy(p, onehot, reduction="sum") / valid.sum()
