"""How many of a reference's top boxes a candidate finds again: the criterion a reduced-precision file
(int8, fp16) is judged by against its fp32 file, and a model against another in the benchmarks.

Exact numeric agreement is not expected of a reduced-precision file; what a user of the detections
needs is the same boxes. Each frame's top-``TOP_K`` valid reference boxes are matched greedily, in
score order, to the nearest unused candidate box of the same label within ``MATCH_RADIUS_M``
(bird's-eye centre distance, as nuScenes matches), and the share found again is reported with its
standard error over the frames and per band of the reference box's score.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fisheye_infer.runtime.box_geometry import box_diff

__all__ = [
    "MATCH_RADIUS_M",
    "SCORE_BANDS",
    "TOP_K",
    "TopMatch",
    "TopMatched",
    "match_top",
    "per_score_band",
    "top_matched",
]

TOP_K = 50
MATCH_RADIUS_M = 0.5
#: Bands of the reference box's score the share kept is also counted by: what a detection threshold
#: keeps. Low-scoring boxes fill most of a top-50 and move first.
SCORE_BANDS = {
    "score >= 0.3": (0.3, math.inf),
    "0.15-0.3": (0.15, 0.3),
    "0.05-0.15": (0.05, 0.15),
    "< 0.05": (-math.inf, 0.05),
}


@dataclass(frozen=True)
class TopMatch:
    """One of a frame's top reference boxes and what the candidate made of it."""

    label: int
    matched: bool
    box_diff: float = 0.0  # matched pairs: max abs difference of the 7 box values
    score_diff: float = 0.0  # matched pairs: abs score difference
    score: float = 0.0  # the reference box's own score
    frame: int = 0  # which frame the reference box is in


def match_top(
    reference: Sequence[np.ndarray],
    candidate: Sequence[np.ndarray],
    top_k: int = TOP_K,
    radius_m: float = MATCH_RADIUS_M,
) -> list[TopMatch]:
    """Match each frame's top-``top_k`` valid reference boxes (by score) to candidate boxes.

    A reference box is matched by the nearest unused valid candidate box of the same label whose
    centre lies within ``radius_m`` (bird's-eye distance, as nuScenes' centre distance), greedily
    in reference score order. One entry per reference box considered, frame by frame in rank order.
    """
    rb, rs, rl, rv = reference
    cb, cs, cl, cv = candidate
    found: list[TopMatch] = []
    for f in range(len(rb)):
        order = [i for i in np.argsort(-rs[f], kind="stable") if rv[f][i]][:top_k]
        pool = np.flatnonzero(cv[f])
        used = np.zeros(len(pool), bool)
        for i in order:
            same = (cl[f][pool] == rl[f][i]) & ~used
            dist = np.hypot(*(cb[f][pool, :2] - rb[f][i, :2]).T)
            dist[~same] = np.inf
            if len(pool) and dist.min() <= radius_m:
                j = int(np.argmin(dist))
                used[j] = True
                found.append(
                    TopMatch(
                        int(rl[f][i]),
                        True,
                        float(box_diff(cb[f][pool[j]], rb[f][i])),
                        abs(float(cs[f][pool[j]]) - float(rs[f][i])),
                        float(rs[f][i]),
                        f,
                    )
                )
            else:
                found.append(TopMatch(int(rl[f][i]), False, score=float(rs[f][i]), frame=f))
    return found


def per_score_band(pairs: Sequence[TopMatch]) -> dict[str, list[TopMatch]]:
    """``pairs`` grouped by the band of ``SCORE_BANDS`` their reference box's score falls in."""
    return {band: [p for p in pairs if low <= p.score < high] for band, (low, high) in SCORE_BANDS.items()}


@dataclass(frozen=True)
class TopMatched:
    """``match_top`` summed over the frames."""

    matched: int
    considered: int
    standard_error: float  # of ``fraction``, from how it varies between frames (boxes of one frame are not independent)
    max_box_diff: float  # over matched pairs
    max_score_diff: float  # over matched pairs
    by_score: dict[str, tuple[int, int]]  # (matched, considered) per band of ``SCORE_BANDS``

    @property
    def fraction(self) -> float:
        return self.matched / self.considered if self.considered else 1.0


def top_matched(
    reference: Sequence[np.ndarray],
    candidate: Sequence[np.ndarray],
    top_k: int = TOP_K,
    radius_m: float = MATCH_RADIUS_M,
) -> TopMatched:
    """``match_top`` summed, with the standard error of the share kept.

    The error is the ratio estimator's over frames as clusters: sqrt(F / (F - 1) * sum_f (m_f -
    p c_f)^2) / C, with m_f of c_f boxes kept in frame f, C = sum_f c_f and p the share kept; 0 for
    one frame, where it cannot be estimated.
    """
    pairs = match_top(reference, candidate, top_k, radius_m)
    frames = len(reference[0])
    kept = np.zeros(frames)
    seen = np.zeros(frames)
    box = score = 0.0
    for p in pairs:
        seen[p.frame] += 1
        if p.matched:
            kept[p.frame] += 1
            box, score = max(box, p.box_diff), max(score, p.score_diff)
    total = seen.sum()
    share = kept.sum() / total if total else 1.0
    spread = (
        float(np.sqrt(frames / (frames - 1) * np.sum((kept - share * seen) ** 2)) / total)
        if frames > 1 and total
        else 0.0
    )
    bands = {band: (sum(p.matched for p in group), len(group)) for band, group in per_score_band(pairs).items()}
    return TopMatched(int(kept.sum()), int(total), spread, box, score, bands)
