"""The metric's algorithm as vectorised numpy: match, accumulate, calc_ap, calc_tp.

Semantics are those of nuScenes' ``accumulate``/``calc_ap``/``calc_tp``, which the official
Fisheye3DOD evaluator calls unchanged:

- predictions of one class, from all samples, are visited by descending score; equal scores
  are visited later-row first (nuScenes sorts (score, index) ascending and reverses);
- each prediction takes the nearest not-yet-taken ground truth of its sample (x-y centre
  distance, first one on a tie) and is a true positive iff that distance is strictly below the
  threshold;
- precision/recall are resampled at 101 recall points with ``numpy.interp`` (right = 0, no
  precision envelope); AP averages max(0, p - min_precision) / (1 - min_precision) over the
  points above ``min_recall``;
- TP errors are cumulative means over the matches in score order, mapped onto the recall
  points through the confidence, averaged from just above ``min_recall`` to the maximum recall.

Greedy matching is sequential inside a sample but independent across samples, so ``match``
runs it in rounds: round k gives every sample its k-th prediction at once. The cost is one
vectorised step per round (at most the largest per-sample prediction count), not one Python
step per prediction. ``match_reference`` is the plain loop, kept to check it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.metric_report import TP_METRICS, MetricData

__all__ = [
    "center_distance",
    "angle_diff",
    "yaw_diff",
    "scale_iou",
    "cummean",
    "match",
    "match_reference",
    "accumulate",
    "accumulate_thresholds",
    "calc_ap",
    "calc_tp",
]


def center_distance(gt_translation: np.ndarray, pred_translation: np.ndarray) -> np.ndarray:
    """(K,) x-y distance between paired centres (K, 2+)."""
    d = np.asarray(pred_translation, np.float64)[:, :2] - np.asarray(gt_translation, np.float64)[:, :2]
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1])


def angle_diff(x: np.ndarray, y: np.ndarray, period: float) -> np.ndarray:
    """Signed smallest difference from angle ``y`` to angle ``x`` for the given period, in (-pi, pi]."""
    diff = (np.asarray(x, np.float64) - np.asarray(y, np.float64) + period / 2) % period - period / 2
    return np.where(diff > math.pi, diff - 2 * math.pi, diff)


def yaw_diff(gt_yaw: np.ndarray, pred_yaw: np.ndarray, period: float = 2 * math.pi) -> np.ndarray:
    """(K,) absolute yaw error in [0, pi]; with the default 2 pi period a box turned round costs pi."""
    return np.abs(angle_diff(gt_yaw, pred_yaw, period))


def scale_iou(gt_size: np.ndarray, pred_size: np.ndarray) -> np.ndarray:
    """(K,) IoU of paired boxes (K, 3) after aligning their centres and orientations."""
    g = np.asarray(gt_size, np.float64)
    p = np.asarray(pred_size, np.float64)
    if g.shape != p.shape or g.ndim != 2 or g.shape[1] != 3:
        raise ValueError(f"gt_size/pred_size: expected two (K, 3) arrays, got {g.shape} and {p.shape}")
    if np.any(g <= 0) or np.any(p <= 0):
        raise ValueError("gt_size/pred_size: every size must be positive")
    inter = np.prod(np.minimum(g, p), axis=1)
    return inter / (np.prod(g, axis=1) + np.prod(p, axis=1) - inter)


def cummean(x: np.ndarray) -> np.ndarray:
    """Cumulative mean ignoring NaNs; all NaN gives ones (an error of 1 at every point)."""
    x = np.asarray(x, np.float64)
    nan = np.isnan(x)
    if nan.all():
        return np.ones(len(x))
    total = np.nancumsum(x)
    count = np.cumsum(~nan)
    return np.divide(total, count, out=np.zeros_like(total), where=count != 0)


def _score_order(score: np.ndarray) -> np.ndarray:
    """Descending score; ties in reverse row order."""
    return np.argsort(score, kind="stable")[::-1]


def match(gt: EvalBoxes, pred: EvalBoxes, dist_ths: Sequence[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Greedy matching of one class at each threshold: (order (P,), tp (T, P) bool, gt_row (T, P) int64).

    ``order`` lists prediction rows in visiting order; ``tp[t, i]`` and ``gt_row[t, i]`` (-1 when
    unmatched) belong to prediction ``order[i]`` at threshold ``dist_ths[t]``. Both inputs must
    share their tokens. The sort, the ground-truth table and each prediction's distance to its
    nearest ground truth are computed once for all thresholds; a prediction whose nearest ground
    truth is already too far can only be a false positive, so only the others enter the rounds.
    """
    n_pred, n_th = len(pred), len(dist_ths)
    order = _score_order(pred.score)
    tp = np.zeros((n_th, n_pred), bool)
    gt_row = np.full((n_th, n_pred), -1, np.int64)
    if n_pred == 0 or len(gt) == 0:
        return order, tp, gt_row
    # Ground truth as a padded table: one row per sample that has any, columns in row order.
    by_sample = np.argsort(gt.sample, kind="stable")
    samples, first, count = np.unique(gt.sample[by_sample], return_index=True, return_counts=True)
    table_row = np.full(len(gt.tokens), -1, np.int64)
    table_row[samples] = np.arange(len(samples))
    rows = table_row[gt.sample[by_sample]]
    cols = np.arange(len(gt)) - first[rows]
    shape = (len(samples), int(count.max()))
    gx, gy = np.full(shape, np.inf), np.full(shape, np.inf)
    gx[rows, cols] = gt.translation[by_sample, 0]
    gy[rows, cols] = gt.translation[by_sample, 1]
    gidx = np.full(shape, -1, np.int64)
    gidx[rows, cols] = by_sample
    # Predictions in visiting order; the distance to the nearest ground truth of their sample.
    psample = pred.sample[order]
    prow = table_row[psample]
    px, py = pred.translation[order, 0], pred.translation[order, 1]
    nearest = np.full(n_pred, np.inf)
    with_gt = np.nonzero(prow >= 0)[0]
    for lo in range(0, len(with_gt), _CHUNK):
        idx = with_gt[lo : lo + _CHUNK]
        nearest[idx] = _distances(px[idx], py[idx], gx[prow[idx]], gy[prow[idx]]).min(axis=1)
    for t, th in enumerate(dist_ths):
        _greedy_rounds(np.nonzero(nearest < th)[0], psample, prow, px, py, gx, gy, gidx, th, tp[t], gt_row[t])
    return order, tp, gt_row


_CHUNK = 1 << 16


def _distances(px: np.ndarray, py: np.ndarray, gx: np.ndarray, gy: np.ndarray) -> np.ndarray:
    """(m, G) x-y distances from m predictions to the padded ground-truth rows."""
    dx = px[:, None] - gx
    dy = py[:, None] - gy
    return np.sqrt(dx * dx + dy * dy)


def _greedy_rounds(
    pos: np.ndarray,
    psample: np.ndarray,
    prow: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    gx: np.ndarray,
    gy: np.ndarray,
    gidx: np.ndarray,
    dist_th: float,
    tp: np.ndarray,
    gt_row: np.ndarray,
) -> None:
    """Greedy matching of the candidate positions ``pos`` (visiting order), filling ``tp``/``gt_row``.

    Round k takes the k-th candidate of every sample at once; within a sample the candidates keep
    their visiting order, so each sample sees exactly the sequential greedy pass.
    """
    if len(pos) == 0:
        return
    pos = pos[np.argsort(psample[pos], kind="stable")]
    grouped = psample[pos]
    rank = np.arange(len(pos)) - np.searchsorted(grouped, grouped, side="left")
    by_rank = np.argsort(rank, kind="stable")
    pos, rank = pos[by_rank], rank[by_rank]
    bounds = np.searchsorted(rank, np.arange(int(rank[-1]) + 2))
    taken = np.zeros(gx.shape, bool)
    for k in range(len(bounds) - 1):
        sel = pos[bounds[k] : bounds[k + 1]]  # at most one prediction per sample
        r = prow[sel]
        dist = _distances(px[sel], py[sel], gx[r], gy[r])  # m x G
        dist[taken[r]] = np.inf
        j = np.argmin(dist, axis=1)
        hit = dist[np.arange(len(sel)), j] < dist_th
        sel, r, j = sel[hit], r[hit], j[hit]
        tp[sel] = True
        taken[r, j] = True
        gt_row[sel] = gidx[r, j]


def match_reference(gt: EvalBoxes, pred: EvalBoxes, dist_th: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``match`` at one threshold as a plain loop over predictions, for checking the vectorised version."""
    order = _score_order(pred.score)
    tp = np.zeros(len(pred), bool)
    gt_row = np.full(len(pred), -1, np.int64)
    per_sample: dict[int, list[int]] = {}
    for row, s in enumerate(gt.sample.tolist()):
        per_sample.setdefault(s, []).append(row)
    taken: set[int] = set()
    for i, p in enumerate(order.tolist()):
        best, best_row = math.inf, -1
        for g in per_sample.get(int(pred.sample[p]), []):
            if g in taken:
                continue
            d = float(center_distance(gt.translation[g : g + 1], pred.translation[p : p + 1])[0])
            if d < best:
                best, best_row = d, g
        if best < dist_th:
            taken.add(best_row)
            tp[i], gt_row[i] = True, best_row
    return order, tp, gt_row


def accumulate(
    gt: EvalBoxes, pred: EvalBoxes, dist_th: float, class_id: int | None = None, period: float = 2 * math.pi
) -> MetricData:
    """Precision, confidence and TP-error curves of one class at one distance threshold.

    ``gt`` and ``pred`` hold one class already, or ``class_id`` selects it.
    """
    return accumulate_thresholds(gt, pred, (dist_th,), class_id, period)[0]


def accumulate_thresholds(
    gt: EvalBoxes, pred: EvalBoxes, dist_ths: Sequence[float], class_id: int | None = None, period: float = 2 * math.pi
) -> list[MetricData]:
    """``accumulate`` at several thresholds, sharing the sort and the distance work between them."""
    if class_id is not None:
        gt, pred = gt[gt.label == class_id], pred[pred.label == class_id]
    npos = len(gt)
    if npos == 0:
        return [MetricData.no_predictions() for _ in dist_ths]
    order, tp, gt_row = match(gt, pred, dist_ths)
    return [_curves(gt, pred, npos, order, tp[t], gt_row[t], period) for t in range(len(dist_ths))]


def _curves(
    gt: EvalBoxes, pred: EvalBoxes, npos: int, order: np.ndarray, tp: np.ndarray, gt_row: np.ndarray, period: float
) -> MetricData:
    if not tp.any():
        return MetricData.no_predictions()
    tp_cum = np.cumsum(tp).astype(np.float64)
    fp_cum = np.cumsum(~tp).astype(np.float64)
    prec = tp_cum / (tp_cum + fp_cum)
    rec = tp_cum / float(npos)
    conf = pred.score[order]
    rec_interp = np.linspace(0, 1, MetricData.nelem)
    prec = np.interp(rec_interp, rec, prec, right=0)
    conf = np.interp(rec_interp, rec, conf, right=0)
    matched, truth = order[tp], gt_row[tp]
    errors = {
        "trans_err": center_distance(gt.translation[truth], pred.translation[matched]),
        "scale_err": 1 - scale_iou(gt.size[truth], pred.size[matched]),
        "orient_err": yaw_diff(gt.yaw[truth], pred.yaw[matched], period),
    }
    match_conf = pred.score[matched]
    curves = {k: np.interp(conf[::-1], match_conf[::-1], cummean(v)[::-1])[::-1] for k, v in errors.items()}
    return MetricData(rec_interp, prec, conf, **curves)


def calc_ap(md: MetricData, min_recall: float, min_precision: float) -> float:
    """Mean of max(0, precision - min_precision) / (1 - min_precision) over the recall points above ``min_recall``."""
    if not 0 <= min_precision < 1:
        raise ValueError(f"min_precision: expected a value in [0, 1), got {min_precision}")
    if not 0 <= min_recall <= 1:
        raise ValueError(f"min_recall: expected a value in [0, 1], got {min_recall}")
    prec = md.precision[round(100 * min_recall) + 1 :] - min_precision
    if len(prec) == 0:
        return 0.0
    return float(np.mean(np.maximum(prec, 0))) / (1.0 - min_precision)


def calc_tp(md: MetricData, min_recall: float, metric_name: str) -> float:
    """Mean TP error from just above ``min_recall`` to the maximum recall reached; 1.0 if it is never passed."""
    if metric_name not in TP_METRICS:
        raise ValueError(f"metric_name: expected one of {', '.join(TP_METRICS)}, got {metric_name!r}")
    first = round(100 * min_recall) + 1
    last = md.max_recall_ind
    if last < first:
        return 1.0
    return float(np.mean(getattr(md, metric_name)[first : last + 1]))
