"""CLEAR-MOT event accumulation and the counts built on it, as py-motmetrics computes them for nuScenes.

    acc = MotAccumulator()                          # one per sequence
    acc.update(gt_ids, pred_ids, distances)         # one call per frame; NaN distance: may not pair
    summary = summarize([acc, ...])                 # counts and rates over all sequences

``update`` follows ``motmetrics.MOTAccumulator.update`` (1.4): pairs that matched before and are
still within reach match again first; the rest are paired by the minimum total distance
(``linear_sum_assignment``, unpairable pairs priced out as motmetrics does), and a pair whose object
last matched another hypothesis is an identity switch; objects left over are misses, hypotheses
left over false positives. ``summarize`` gives the numbers nuScenes' tracking evaluation reads:
matches, switches, false positives, misses, objects, predictions, frames, MOTA (clipped at 0),
MOTAR, MOTP, recall, fragmentations, mostly tracked/lost and false alarms per frame.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass, field

import numpy as np

__all__ = ["MotAccumulator", "MotSummary", "summarize", "MATCH", "SWITCH", "MISS", "FP"]

MATCH, SWITCH, MISS, FP = 0, 1, 2, 3


def _priced_out(cost: np.ndarray) -> np.ndarray:
    """motmetrics' ``add_expensive_edges``: NaN pairs cost more than any assignment of real ones."""
    valid = np.isfinite(cost)
    if valid.all():
        return cost.copy()
    if not valid.any():
        return np.zeros_like(cost)
    c = float(np.abs(cost[valid]).max()) + 1
    return np.where(valid, cost, 2 * min(cost.shape) * c + 1)


@dataclass
class MotAccumulator:
    """The events of one sequence: per event its frame, type, object, hypothesis and distance."""

    frames: int = 0
    events: list[tuple[int, int, Hashable, Hashable, float]] = field(default_factory=list)
    _m: dict[Hashable, Hashable] = field(default_factory=dict)  # object -> hypothesis it last matched

    def update(self, oids: Sequence[Hashable], hids: Sequence[Hashable], dists: np.ndarray) -> list[int]:
        """Add one frame; returns the indices of the hypotheses that got a MATCH event (not a switch).

        Args:
            oids (Sequence[Hashable]): Ground-truth object ids of the frame.
            hids (Sequence[Hashable]): Hypothesis (track) ids of the frame.
            dists (np.ndarray): (len(oids), len(hids)) distances; NaN where a pair may not match.

        Returns:
            list[int]: Indices into ``hids`` of this frame's MATCH events.
        """
        from scipy.optimize import linear_sum_assignment

        frame = self.frames
        self.frames += 1
        d = np.array(dists, np.float64).reshape(len(oids), len(hids))
        o_used, h_used = np.zeros(len(oids), bool), np.zeros(len(hids), bool)
        matched: list[int] = []
        if len(oids) and len(hids):
            for i, o in enumerate(oids):
                if o not in self._m:
                    continue
                js = [j for j, h in enumerate(hids) if not h_used[j] and h == self._m[o]]
                if js and math.isfinite(d[i, js[0]]):
                    j = js[0]
                    o_used[i] = h_used[j] = True
                    self.events.append((frame, MATCH, o, hids[j], float(d[i, j])))
                    matched.append(j)
            d[o_used, :] = np.nan
            d[:, h_used] = np.nan
            rows, cols = linear_sum_assignment(_priced_out(d))
            for i, j in zip(rows.tolist(), cols.tolist()):
                if not math.isfinite(d[i, j]):
                    continue
                o, h = oids[i], hids[j]
                kind = SWITCH if o in self._m and self._m[o] != h else MATCH
                self.events.append((frame, kind, o, h, float(d[i, j])))
                if kind == MATCH:
                    matched.append(j)
                o_used[i] = h_used[j] = True
                self._m[o] = h
        self.events += [(frame, MISS, o, None, math.nan) for i, o in enumerate(oids) if not o_used[i]]
        self.events += [(frame, FP, None, h, math.nan) for j, h in enumerate(hids) if not h_used[j]]
        return matched


@dataclass(frozen=True)
class MotSummary:
    """Counts and rates over a set of sequences (one score threshold of one class)."""

    gt: int
    tp: int
    ids: int
    fp: int
    fn: int
    predictions: int
    frames: int
    mota: float
    motar: float
    motp: float
    recall: float
    frag: int
    mt: int
    ml: int
    faf: float


def summarize(accumulators: Sequence[MotAccumulator]) -> MotSummary:
    """The nuScenes tracking numbers of all events (object ids are told apart per sequence)."""
    counts = np.zeros(4, np.int64)
    distance = 0.0
    frag = mt = ml = 0
    frames = 0
    for acc in accumulators:
        frames += acc.frames
        per_object: dict[Hashable, list[int]] = {}
        for _, kind, o, _, d in acc.events:
            counts[kind] += 1
            if kind in (MATCH, SWITCH):
                distance += d
            if o is not None:
                per_object.setdefault(o, []).append(kind)
        for kinds in per_object.values():
            hit = np.array([k != MISS for k in kinds])
            ratio = hit.mean()
            mt, ml = mt + int(ratio >= 0.8), ml + int(ratio < 0.2)
            if hit.any():
                first, last = np.flatnonzero(hit)[[0, -1]]
                span = hit[first : last + 1]
                frag += int(np.sum(~span[1:] & span[:-1]))
    tp, ids, fn, fp = (int(v) for v in counts)
    gt, found = tp + ids + fn, tp + ids
    recall = found / gt if gt else math.nan
    mota = max(0.0, 1 - (fn + ids + fp) / gt) if gt else math.nan
    if tp:  # motmetrics' MOTAR takes its recall from the matches alone, switches left out
        motar = max(0.0, 1 - ((fn + ids + fp) - (1 - tp / gt) * gt) / tp)
    else:
        motar = math.nan
    return MotSummary(
        gt=gt, tp=tp, ids=ids, fp=fp, fn=fn, predictions=tp + ids + fp, frames=frames, mota=mota, motar=motar,
        motp=distance / found if found else math.nan, recall=recall, frag=frag, mt=mt, ml=ml,
        faf=fp / frames * 100 if frames else math.nan,
    )  # fmt: skip
