"""FisheyePETR's training losses, as the official config defines them (``pts_bbox_head``, ``train_cfg.pts``).

Per decoder layer (all six, the auxiliary ones included, each with the shared branches), summed:

    loss_cls   sigmoid FocalLoss (gamma 2, alpha 0.25) of every query's class logits; matched queries
               aim at their box's class, the others at "no class"; weight 2, / max(positives, 1)
    loss_bbox  L1 of the 8-number code [x, y, log l, log w, z_c, log h, sin r, cos r] of matched
               queries (x, y, z in metres, r = -yaw - pi/2 as ``normalize_bbox``), code weights all 1;
               weight 0.25, / max(positives, 1)

Each layer is matched on its own by `detr_assign` (``HungarianAssigner3D``): the cost is
``FocalLossCost`` (weight 2) of the class logits plus ``BBox3DL1Cost`` (weight 0.25), the L1
distance of the first eight numbers of the code; the IoU cost has weight 0.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ..petr_head import FisheyePETRHead
from .assign import focal_cost
from .losses import _AVG_EPS, sigmoid_focal_loss

__all__ = ["PETRLossConfig", "normalize_boxes", "detr_assign", "PETRLoss"]

CODE_SIZE = 8


@dataclass(frozen=True)
class PETRLossConfig:
    """Loss and matching weights of the official ``fisheye_petr.py``."""

    cls_weight: float = 2.0
    bbox_weight: float = 0.25
    focal_gamma: float = 2.0
    focal_alpha: float = 0.25
    code_weights: tuple[float, ...] = (1.0,) * CODE_SIZE
    match_cls_weight: float = 2.0
    match_reg_weight: float = 0.25


def normalize_boxes(boxes: np.ndarray) -> np.ndarray:
    """(G, 7) runtime boxes [x, y, z_bottom, l, w, h, yaw] -> (G, 8) official regression targets."""
    b = np.asarray(boxes, np.float64).reshape(-1, 7)
    rot = -b[:, 6] - np.pi / 2
    rot = rot - np.floor(rot / (2 * np.pi) + 0.5) * 2 * np.pi
    z_centre = b[:, 2] + b[:, 5] / 2
    return np.stack(
        [b[:, 0], b[:, 1], np.log(b[:, 3]), np.log(b[:, 4]), z_centre, np.log(b[:, 5]), np.sin(rot), np.cos(rot)],
        axis=1,
    )


def detr_assign(
    logits: np.ndarray, codes: np.ndarray, gt_codes: np.ndarray, gt_labels: np.ndarray, config: PETRLossConfig
) -> np.ndarray:
    """Queries' class logits (Q, K) and codes (Q, 8), ground-truth codes (G, 8) and labels (G,) -> (Q,) index of
    the matched box (-1: background)."""
    from scipy.optimize import linear_sum_assignment

    index = np.full(len(logits), -1, np.int64)
    if not len(gt_codes):
        return index
    l1 = np.abs(np.asarray(codes, np.float64)[:, None, :] - np.asarray(gt_codes, np.float64)[None]).sum(-1)
    cost = (
        config.match_cls_weight * focal_cost(logits, gt_labels, config.focal_gamma, config.focal_alpha)
        + config.match_reg_weight * l1
    )
    rows, cols = linear_sum_assignment(np.nan_to_num(cost, nan=100.0, posinf=100.0, neginf=-100.0))
    index[rows] = cols
    return index


class PETRLoss:
    """Assignment and the two losses of every decoder layer.

    loss = PETRLoss(model.pts_bbox_head)
    terms = loss(cls, codes, gt_boxes, gt_labels)   # cls (L, B, Q, K), codes (L, B, Q, 8): head.predict of all layers
    """

    terms: tuple[str, ...] = ("loss", "loss_cls", "loss_bbox", "matched_error")

    def __init__(self, head: FisheyePETRHead, config: PETRLossConfig = PETRLossConfig()) -> None:  # noqa: B008
        self.num_classes = head.config.num_classes
        self.config = config

    def __call__(
        self,
        cls: torch.Tensor,
        codes: torch.Tensor,
        gt_boxes: Sequence[np.ndarray],
        gt_labels: Sequence[np.ndarray],
    ) -> dict[str, torch.Tensor]:
        """-> ``loss`` (the sum to minimise over layers), its two terms summed over layers, and
        ``matched_error``: the last layer's mean centre distance (m) of matched queries, a progress figure."""
        if cls.ndim != 4 or codes.shape[:3] != cls.shape[:3] or codes.shape[-1] != CODE_SIZE:
            raise ValueError(f"expected cls (L, B, Q, K) and codes (L, B, Q, 8), got {cls.shape} and {codes.shape}")
        if len(gt_boxes) != cls.shape[1] or len(gt_labels) != len(gt_boxes):
            raise ValueError(f"ground truth for {len(gt_boxes)} frames; the batch has {cls.shape[1]}")
        cfg, k = self.config, self.num_classes
        targets = [normalize_boxes(b) for b in gt_boxes]
        labels_gt = [np.asarray(g, np.int64).reshape(-1) for g in gt_labels]
        weights = torch.tensor(cfg.code_weights, dtype=codes.dtype, device=codes.device)
        loss_cls = loss_bbox = codes.new_zeros(())
        error = codes.new_zeros(())
        for layer in range(cls.shape[0]):
            labels, target, matched = self._layer_targets(cls[layer], codes[layer], targets, labels_gt)
            num_pos = max(float(matched.sum()), 1.0)
            layer_cls = sigmoid_focal_loss(
                cls[layer].reshape(-1, k), labels.to(cls.device), cfg.focal_gamma, cfg.focal_alpha
            )
            diff = (codes[layer].reshape(-1, CODE_SIZE) - target.to(codes.device)).abs() * weights
            layer_bbox = (diff * matched.to(codes.device)[:, None]).sum()
            loss_cls = loss_cls + cfg.cls_weight * layer_cls / (num_pos + _AVG_EPS)
            loss_bbox = loss_bbox + cfg.bbox_weight * layer_bbox / (num_pos + _AVG_EPS)
            if layer == cls.shape[0] - 1 and matched.any():
                centre = (codes[layer].reshape(-1, CODE_SIZE)[:, :2] - target[:, :2].to(codes.device)).norm(dim=-1)
                error = centre[matched.to(codes.device)].mean().detach()
        return {"loss": loss_cls + loss_bbox, "loss_cls": loss_cls, "loss_bbox": loss_bbox, "matched_error": error}

    def _layer_targets(
        self, cls: torch.Tensor, codes: torch.Tensor, targets: list[np.ndarray], labels_gt: list[np.ndarray]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One layer's (B*Q,) class targets (K: none), (B*Q, 8) code targets and (B*Q,) matched mask."""
        b, q = cls.shape[:2]
        logits = cls.detach().float().cpu().numpy()
        preds = codes.detach().float().cpu().numpy()
        labels = np.full((b, q), self.num_classes, np.int64)
        target = np.zeros((b, q, CODE_SIZE), np.float32)
        for i in range(b):
            index = detr_assign(logits[i], preds[i], targets[i], labels_gt[i], self.config)
            pos = index >= 0
            labels[i, pos] = labels_gt[i][index[pos]]
            target[i, pos] = targets[i][index[pos]]
        return (
            torch.from_numpy(labels.reshape(-1)),
            torch.from_numpy(target.reshape(-1, CODE_SIZE)),
            torch.from_numpy(labels.reshape(-1) < self.num_classes),
        )
