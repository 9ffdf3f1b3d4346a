"""Pairing detections with predicted tracks: the optimal assignment and the greedy one.

    rows, cols = assign(cost, valid)           # minimum total cost over the valid pairs (Hungarian)
    rows, cols = greedy_assign(cost, valid)    # each row in turn takes its nearest free column
    d, valid = centre_cost(track_xy, track_labels, det_xy, det_labels, gates)

``assign`` is scipy's ``linear_sum_assignment`` (imported on first use, so ``import fisheye_infer`` stays light);
invalid pairs cost more than any set of valid ones and are dropped from its answer.
"""

from __future__ import annotations

import numpy as np

__all__ = ["assign", "greedy_assign", "centre_cost"]


def centre_cost(
    track_xy: np.ndarray, track_labels: np.ndarray, det_xy: np.ndarray, det_labels: np.ndarray, gates: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Bird's-eye-view centre distances (T, D) and which pairs are allowed: same class, within the track's gate."""
    d = np.hypot(track_xy[:, None, 0] - det_xy[None, :, 0], track_xy[:, None, 1] - det_xy[None, :, 1])
    valid = (track_labels[:, None] == det_labels[None, :]) & (d < gates[:, None])
    return d, valid


def assign(cost: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the minimum-cost assignment among the ``valid`` pairs, by row."""
    if not valid.any():
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    from scipy.optimize import linear_sum_assignment

    big = 2 * min(cost.shape) * (float(np.abs(cost[valid]).max()) + 1) + 1
    rows, cols = linear_sum_assignment(np.where(valid, cost, big))
    keep = valid[rows, cols]
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def greedy_assign(cost: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row in order takes the valid free column of least cost (CenterPoint's greedy matching)."""
    taken = np.zeros(cost.shape[1], bool)
    rows, cols = [], []
    for i in range(cost.shape[0]):
        options = np.where(valid[i] & ~taken, cost[i], np.inf)
        if options.size and np.isfinite(options.min()):
            j = int(np.argmin(options))
            taken[j] = True
            rows.append(i)
            cols.append(j)
    return np.array(rows, np.int64), np.array(cols, np.int64)
