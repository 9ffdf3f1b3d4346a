"""Depth targets of the fisheye LSS from the renderer: which depth bin each lifted ray should pick.

The official FisheyeBEVDet learns its depth distribution only through the detection losses.
Synthetic frames know the true distance of every ray, so training can also supervise the depth
head directly, as BEVDepth does with lidar points: a far denser signal for the image features,
which matters most when the backbone starts untrained (no ImageNet weights here).

A cell of the compact model's angular grid spans several degrees (10 x 5.5 for the compact
10 x 40 grid), so one ray per cell would mostly see the ground in front of an object. The target
follows BEVDepth's choice of the nearest lidar point in a patch, with objects first: each cell is
sampled by ``k x k`` rays (the pictures' own intersection code, ``Renderer.ray_depth``); if any of
them meets a box, the cell's target is the nearest box hit, otherwise the depth where its centre
ray meets the ground. A cell whose rays meet nothing within the bins, or that lies outside the
lens's field of view, carries no target (-1).
"""

from __future__ import annotations

import numpy as np
import torch

from fisheye_infer.geometry.grids import spherical_directions
from fisheye_infer.geometry.lss import LSSGeometry
from fisheye_infer.scenes.render import Renderer
from fisheye_infer.scenes.scene import Scene

from ..bevdet_config import ViewTransformConfig

__all__ = ["DepthTargets", "depth_loss"]


class DepthTargets:
    """Per-frame depth-bin targets (N, H, W) int64 for one model's lift geometry.

    targets = DepthTargets(model.view_transform.geometry, config.view_transform)
    bins = targets(sample.scene)        # -1 where there is no target
    """

    def __init__(self, geometry: LSSGeometry, vt: ViewTransformConfig, samples: int = 4) -> None:
        h, w = (int(v) for v in vt.feature_size)
        k = int(samples)
        fine = spherical_directions((h * k, w * k), vt.azimuth_range, vt.elevation_range)
        # fine rays grouped by the coarse cell they fall in: (H*W, k*k, 3) -> 3 x (H*W*k*k)
        self.fine = fine.reshape(h, k, w, k, 3).transpose(0, 2, 1, 3, 4).reshape(-1, 3).T
        frustum = np.asarray(geometry.frustum, np.float64)  # D x H x W x 3, radial depth
        centre = frustum[0] / np.linalg.norm(frustum[0], axis=-1, keepdims=True)
        self.centre = centre.reshape(-1, 3).T  # 3 x HW
        self.shape, self.k2 = (h, w), k * k
        self.cam2lidar = np.asarray(geometry.cam2lidar, np.float64)
        self.inside = np.asarray(geometry.valid_fov_mask, np.float32).reshape(-1) > 0.5
        start, _, step = (float(v) for v in vt.dbound)
        self.start, self.step, self.num_bins = start, step, frustum.shape[0]
        self.renderer = Renderer()

    def __call__(self, scene: Scene) -> np.ndarray:
        ground = Scene(np.zeros((0, 7)), np.zeros(0, np.int64), scene.ground_z)
        out = np.full((len(self.cam2lidar), self.centre.shape[1]), -1, np.int64)
        for n, m in enumerate(self.cam2lidar):
            o, r = m[:3, 3], m[:3, :3]
            fine = r @ self.fine
            with_boxes = self.renderer.ray_depth(o, fine, scene)
            box_hit = with_boxes < self.renderer.ray_depth(o, fine, ground)
            nearest_box = np.where(box_hit, with_boxes, np.inf).reshape(-1, self.k2).min(axis=1)
            t = np.where(np.isfinite(nearest_box), nearest_box, self.renderer.ray_depth(o, r @ self.centre, scene))
            bins = np.rint((t - self.start) / self.step)
            ok = np.isfinite(bins) & (bins >= 0) & (bins < self.num_bins) & self.inside
            out[n, ok] = bins[ok].astype(np.int64)
        return out.reshape(len(self.cam2lidar), *self.shape)


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
