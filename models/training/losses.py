"""FisheyeBEVDet's training losses, as the official config defines them (``model.bbox_head`` / ``train_cfg.pts``).

    loss_heatmap  GaussianFocalLoss (alpha 2, gamma 4) of clamp(sigmoid(dense heatmap), 1e-4, 1 - 1e-4)
                  against the Gaussian target; weight 1, divided by the number of peak cells (== 1)
    loss_cls      sigmoid FocalLoss (gamma 2, alpha 0.25) of every proposal's class logits; matched
                  proposals aim at their box's class, the others at "no class"; weight 1, / positives
    loss_bbox     L1 of the 8-number box code of matched proposals, code_weights all 1; weight 0.25, / positives

Proposals are matched by `train.assign.hungarian_assign` on their decoded boxes; the
returned ``matched_iou`` is the mean 3D IoU of the matches (a progress figure, not a loss).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from ..transfusion import TransFusionHead
from .assign import AssignerConfig, hungarian_assign
from .targets import CODE_SIZE, HeadGrid, encode_boxes, heatmap_target

__all__ = ["LossConfig", "gaussian_focal_loss", "sigmoid_focal_loss", "TransFusionLoss"]

_AVG_EPS = float(torch.finfo(torch.float32).eps)  # mmdet adds it to avg_factor


@dataclass(frozen=True)
class LossConfig:
    """Loss weights and target settings of the official ``fisheye_bevdet.py``."""

    heatmap_weight: float = 1.0
    cls_weight: float = 1.0
    bbox_weight: float = 0.25
    focal_gamma: float = 2.0
    focal_alpha: float = 0.25
    gaussian_overlap: float = 0.1
    min_radius: int = 2
    code_weights: tuple[float, ...] = (1.0,) * CODE_SIZE
    assigner: AssignerConfig = field(default_factory=AssignerConfig)


def gaussian_focal_loss(
    logits: torch.Tensor, target: torch.Tensor, alpha: float = 2.0, gamma: float = 4.0
) -> torch.Tensor:
    """Summed mmdet GaussianFocalLoss of ``clip_sigmoid(logits)`` against a Gaussian ``target`` (same
    shape), not yet averaged."""
    pred = torch.sigmoid(logits).clamp(1e-4, 1 - 1e-4)
    pos = target.eq(1).to(pred.dtype)
    neg_weights = (1 - target).pow(gamma)
    pos_loss = -(pred + 1e-12).log() * (1 - pred).pow(alpha) * pos
    neg_loss = -(1 - pred + 1e-12).log() * pred.pow(alpha) * neg_weights
    return (pos_loss + neg_loss).sum()


def sigmoid_focal_loss(
    logits: torch.Tensor, labels: torch.Tensor, gamma: float = 2.0, alpha: float = 0.25
) -> torch.Tensor:
    """Summed mmdet sigmoid FocalLoss: ``logits`` (N, K), ``labels`` (N,) with K meaning background."""
    k = logits.shape[1]
    target = F.one_hot(labels.clamp(max=k), k + 1)[:, :k].to(logits.dtype)
    p = torch.sigmoid(logits)
    pt = (1 - p) * target + p * (1 - target)
    weight = (alpha * target + (1 - alpha) * (1 - target)) * pt.pow(gamma)
    return (F.binary_cross_entropy_with_logits(logits, target, reduction="none") * weight).sum()


class TransFusionLoss:
    """Targets, assignment and the three losses for a batch of raw head outputs.

    loss = TransFusionLoss(model.bbox_head, HeadGrid.from_head(cfg.head))
    terms = loss(model.forward_raw(images), gt_boxes, gt_labels)   # terms["loss"].backward()
    """

    def __init__(self, head: TransFusionHead, grid: HeadGrid, config: LossConfig = LossConfig()) -> None:
        self.head, self.grid, self.config = head, grid, config
        self.num_classes = head.num_classes

    def targets(
        self, raw: Mapping[str, torch.Tensor], gt_boxes: Sequence[np.ndarray], gt_labels: Sequence[np.ndarray]
    ) -> dict[str, torch.Tensor]:
        """Heatmap (B x K x X x Y), class labels (B x P, K = none), box codes and weights (B x P x 8), match IoUs."""
        cfg, k = self.config, self.num_classes
        with torch.no_grad():
            decoded = self.head.decode(
                {n: raw[n].detach() for n in ("center", "height", "dim", "rot", "heatmap")},
                raw["peak"].detach(),
                raw["query_labels"],
            )
        boxes = decoded["boxes"].cpu().numpy()
        logits = raw["heatmap"].detach().transpose(1, 2).cpu().numpy()  # B x P x K
        b, p = boxes.shape[0], boxes.shape[1]
        heat = np.zeros((b, k, *self.grid.bev_size), np.float32)
        labels = np.full((b, p), k, np.int64)
        codes = np.zeros((b, p, CODE_SIZE), np.float32)
        weights = np.zeros((b, p, CODE_SIZE), np.float32)
        ious: list[float] = []
        start, span = self.grid.pc_range, self.grid.span
        for i in range(b):
            gtb = np.asarray(gt_boxes[i], np.float64).reshape(-1, 7)
            gtl = np.asarray(gt_labels[i], np.int64).reshape(-1)
            heat[i] = heatmap_target(gtb, gtl, self.grid, k, cfg.gaussian_overlap, cfg.min_radius)
            match = hungarian_assign(boxes[i], logits[i], gtb, gtl, start, span, cfg.assigner)
            pos = match.positive
            labels[i, pos] = gtl[match.gt_index[pos]]
            codes[i, pos] = encode_boxes(gtb[match.gt_index[pos]], self.grid)
            weights[i, pos] = np.asarray(cfg.code_weights, np.float32)
            ious.extend(match.iou[pos].tolist())
        t = torch.from_numpy
        return {
            "heatmap": t(heat),
            "labels": t(labels),
            "codes": t(codes),
            "weights": t(weights),
            "num_pos": torch.tensor(float((labels < k).sum())),
            "matched_iou": torch.tensor(float(np.mean(ious)) if ious else 0.0),
        }

    def __call__(
        self, raw: Mapping[str, torch.Tensor], gt_boxes: Sequence[np.ndarray], gt_labels: Sequence[np.ndarray]
    ) -> dict[str, torch.Tensor]:
        """Raw head outputs and per-frame ground truth -> ``loss`` (the sum to minimise) and its terms."""
        if len(gt_boxes) != raw["center"].shape[0] or len(gt_labels) != len(gt_boxes):
            raise ValueError(
                f"ground truth for {len(gt_boxes)} frames ({len(gt_labels)} label sets); "
                f"the batch has {raw['center'].shape[0]}"
            )
        cfg, k = self.config, self.num_classes
        tg = self.targets(raw, gt_boxes, gt_labels)
        dense = raw["dense_heatmap"]
        peaks = max(float(tg["heatmap"].eq(1).sum()), 1.0)
        loss_heatmap = (
            cfg.heatmap_weight * gaussian_focal_loss(dense, tg["heatmap"].to(dense.device)) / (peaks + _AVG_EPS)
        )
        num_pos = max(float(tg["num_pos"]), 1.0)
        cls_logits = raw["heatmap"].permute(0, 2, 1).reshape(-1, k)
        loss_cls = (
            cfg.cls_weight
            * sigmoid_focal_loss(
                cls_logits, tg["labels"].reshape(-1).to(cls_logits.device), cfg.focal_gamma, cfg.focal_alpha
            )
            / (num_pos + _AVG_EPS)
        )
        preds = torch.cat([raw["center"], raw["height"], raw["dim"], raw["rot"]], dim=1).permute(0, 2, 1)  # B x P x 8
        l1 = (preds - tg["codes"].to(preds.device)).abs() * tg["weights"].to(preds.device)
        loss_bbox = cfg.bbox_weight * l1.sum() / (num_pos + _AVG_EPS)
        return {
            "loss": loss_heatmap + loss_cls + loss_bbox,
            "loss_heatmap": loss_heatmap,
            "loss_cls": loss_cls,
            "loss_bbox": loss_bbox,
            "matched_iou": tg["matched_iou"],
            "num_pos": tg["num_pos"],
        }
