"""Hungarian assignment of the TransFusion proposals to ground-truth boxes (official ``LSSHungarianAssigner3D``).

The cost of giving proposal p the ground-truth box g is the weighted sum of three terms, each as
the official config defines it (``train_cfg.pts.assigner``):

- class: mmdet's ``FocalLossCost`` on the proposal's class logits (gamma 2, alpha 0.25, weight 0.15):
  ``alpha (1-s)^gamma (-log s) - (1-alpha) s^gamma (-log(1-s))`` at the box's class, s = sigmoid;
- centre: ``BBoxBEVL1Cost`` (weight 0.25), the L1 distance of the BEV centres after normalising
  x and y by the point-cloud range to [0, 1];
- overlap: ``IoU3DCost`` (weight 0.25), minus the 3D IoU of the two boxes.

scipy's ``linear_sum_assignment`` then matches each ground-truth box to one proposal (there are
more proposals than boxes); the other proposals are background.

The 3D IoU is the exact rotated one (``BboxOverlaps3D`` in the LiDAR frame): the BEV intersection
of the two rotated rectangles from OpenCV's ``rotatedRectangleIntersection`` times the overlap of
their height ranges, over the union of the volumes. Pairs whose bounding circles do not touch
are skipped (their IoU is 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["AssignerConfig", "Assignment", "iou_3d", "focal_cost", "bev_l1_cost", "hungarian_assign"]

_EPS = 1e-12


@dataclass(frozen=True)
class AssignerConfig:
    """Cost weights and focal parameters of the official assigner."""

    cls_weight: float = 0.15
    reg_weight: float = 0.25
    iou_weight: float = 0.25
    gamma: float = 2.0
    alpha: float = 0.25


@dataclass(frozen=True)
class Assignment:
    """Per proposal (P,): the ground-truth index it was matched to (-1: background) and their 3D IoU (0 when
    unmatched)."""

    gt_index: np.ndarray
    iou: np.ndarray

    @property
    def positive(self) -> np.ndarray:
        return np.nonzero(self.gt_index >= 0)[0]


def _bev_area(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection area of two rotated BEV rectangles (x, y, l, w, yaw)."""
    ra = ((float(a[0]), float(a[1])), (float(a[3]), float(a[4])), math.degrees(float(a[6])))
    rb = ((float(b[0]), float(b[1])), (float(b[3]), float(b[4])), math.degrees(float(b[6])))
    kind, points = cv2.rotatedRectangleIntersection(ra, rb)
    if kind == cv2.INTERSECT_NONE or points is None or len(points) < 3:
        return 0.0
    return float(cv2.contourArea(cv2.convexHull(points)))


def iou_3d(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """(A, 7) x (B, 7) runtime boxes (x, y, z_bottom, l, w, h, yaw) -> (A, B) 3D IoU."""
    a = np.asarray(boxes_a, np.float64).reshape(-1, 7)
    b = np.asarray(boxes_b, np.float64).reshape(-1, 7)
    out = np.zeros((len(a), len(b)), np.float64)
    if not len(a) or not len(b):
        return out
    ra = np.hypot(a[:, 3], a[:, 4]) / 2
    rb = np.hypot(b[:, 3], b[:, 4]) / 2
    dist = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    dz = np.minimum(a[:, None, 2] + a[:, None, 5], b[None, :, 2] + b[None, :, 5]) - np.maximum(
        a[:, None, 2], b[None, :, 2]
    )
    vol_a, vol_b = a[:, 3] * a[:, 4] * a[:, 5], b[:, 3] * b[:, 4] * b[:, 5]
    for i, j in zip(*np.nonzero((dist < ra[:, None] + rb[None, :]) & (dz > 0))):
        inter = _bev_area(a[i], b[j]) * dz[i, j]
        union = vol_a[i] + vol_b[j] - inter
        out[i, j] = inter / union if union > 0 else 0.0
    return out


def focal_cost(logits: np.ndarray, gt_labels: np.ndarray, gamma: float = 2.0, alpha: float = 0.25) -> np.ndarray:
    """(P, K) class logits, (G,) labels -> (P, G) mmdet ``FocalLossCost`` (unweighted)."""
    s = 1.0 / (1.0 + np.exp(-np.asarray(logits, np.float64)))
    neg = -np.log(1 - s + _EPS) * (1 - alpha) * s**gamma
    pos = -np.log(s + _EPS) * alpha * (1 - s) ** gamma
    return pos[:, gt_labels] - neg[:, gt_labels]


def bev_l1_cost(
    pred_xy: np.ndarray, gt_xy: np.ndarray, pc_start: tuple[float, float], pc_span: tuple[float, float]
) -> np.ndarray:
    """(P, 2), (G, 2) BEV centres (m) -> (P, G) L1 distance in units of the point-cloud range (unweighted)."""
    start, span = np.asarray(pc_start, np.float64), np.asarray(pc_span, np.float64)
    p = (np.asarray(pred_xy, np.float64) - start) / span
    g = (np.asarray(gt_xy, np.float64) - start) / span
    return np.abs(p[:, None, :] - g[None, :, :]).sum(-1)


def hungarian_assign(
    pred_boxes: np.ndarray,
    pred_logits: np.ndarray,
    gt_boxes: np.ndarray,
    gt_labels: np.ndarray,
    pc_start: tuple[float, float],
    pc_span: tuple[float, float],
    config: AssignerConfig = AssignerConfig(),
) -> Assignment:
    """Decoded proposals (P, 7) with class logits (P, K), ground truth (G, 7) and labels (G,) -> one-to-one
    assignment."""
    from scipy.optimize import linear_sum_assignment

    pred_boxes = np.asarray(pred_boxes, np.float64).reshape(-1, 7)
    gt_boxes = np.asarray(gt_boxes, np.float64).reshape(-1, 7)
    gt_labels = np.asarray(gt_labels, np.int64).reshape(-1)
    logits = np.asarray(pred_logits, np.float64)
    if logits.ndim != 2 or logits.shape[0] != len(pred_boxes):
        raise ValueError(f"pred_logits: expected ({len(pred_boxes)}, K), got {logits.shape}")
    if len(gt_labels) != len(gt_boxes):
        raise ValueError(f"gt_labels: {len(gt_labels)} labels for {len(gt_boxes)} boxes")
    index = np.full(len(pred_boxes), -1, np.int64)
    overlap = np.zeros(len(pred_boxes), np.float64)
    if not len(gt_boxes) or not len(pred_boxes):
        return Assignment(index, overlap)
    if gt_labels.min() < 0 or gt_labels.max() >= logits.shape[1]:
        raise ValueError(
            f"gt_labels: expected class ids in [0, {logits.shape[1]}), got {sorted(set(gt_labels.tolist()))}"
        )
    iou = iou_3d(pred_boxes, gt_boxes)
    cost = (
        config.cls_weight * focal_cost(logits, gt_labels, config.gamma, config.alpha)
        + config.reg_weight * bev_l1_cost(pred_boxes[:, :2], gt_boxes[:, :2], pc_start, pc_span)
        - config.iou_weight * iou
    )
    rows, cols = linear_sum_assignment(cost)
    index[rows] = cols
    overlap[rows] = iou[rows, cols]
    return Assignment(index, overlap)
