"""Tracking metrics as nuScenes' tracking evaluation computes them: AMOTA, AMOTP, MOTA, MOTP, IDS, FRAG, recall.

    report = evaluate_tracking(sequences, EvalConfig())        # at 0-30 and 0-48 m (config.distance_breakdown)
    report.overall[48.0]["amota"], report.classes[48.0]["Car"]["ids"]
    evaluate_tracking(sequences, hota=True).hota[48.0]["overall"]["hota"]   # and TrackEval's HOTA (eval.hota)

Each ``SequenceResults`` holds, per frame in time order, its stamp, its ego pose and two lists of
records in the frame's lidar frame: ground truth (``tracking_id``, ``tracking_name``, ``translation``)
and tracks (the same and ``tracking_score``: ``Tracks.to_nuscenes``). The steps are the devkit's
(``nuscenes/eval/tracking``, ``TrackingEvaluation``): boxes beyond their class's range (x-y distance
from the ego, the detection metric's ranges scaled to 30 or 48 m) are dropped; a track's score
becomes its mean over the sequence; gaps in ground-truth and predicted tracks are filled by its
``interpolate_tracks`` (with its weights); per class, the scores of the matches made with every box
give 40 score thresholds at recalls 0.1 to 1 (``compute_thresholds``); at each, the CLEAR-MOT events
of centre distances below 2 m in the world frame (``mot.MotAccumulator``) give MOTAR, MOTP and the
counts. AMOTA and AMOTP average MOTAR and MOTP over the thresholds (unreached ones at their worst, 0
and 2 m); MOTA, MOTP, IDS, FRAG, recall and the counts are those of the threshold with the best
MOTA. Overall values average the classes (rates) or add them (counts), skipping classes without
ground truth.
"""

from __future__ import annotations

import json
import math
from bisect import bisect
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fisheye_infer.eval.metric_config import EvalConfig
from fisheye_infer.eval.mot import MotAccumulator, MotSummary, summarize

__all__ = ["SequenceResults", "TrackingReport", "evaluate_tracking", "TRACKING_METRICS"]

#: Per class and overall, in the report's order; counts are summed over classes, the rest averaged.
TRACKING_METRICS = (
    "amota",
    "amotp",
    "mota",
    "motp",
    "motar",
    "recall",
    "ids",
    "frag",
    "tp",
    "fp",
    "fn",
    "gt",
    "mt",
    "ml",
    "faf",
)
_COUNTS = ("ids", "frag", "tp", "fp", "fn", "gt", "mt", "ml")
_WORST = {
    "amota": 0.0,
    "amotp": 2.0,
    "recall": 0.0,
    "motar": 0.0,
    "mota": 0.0,
    "motp": 2.0,
    "mt": 0.0,
    "faf": 500.0,
    "tp": 0.0,
}
NUM_THRESHOLDS, MIN_RECALL = 40, 0.1


@dataclass(frozen=True)
class SequenceResults:
    """One sequence's frames in time order, the input of
    [`evaluate_tracking`][fisheye_infer.eval.tracking.evaluate_tracking].

    Records are in each frame's lidar frame: ground truth with ``tracking_id``, ``tracking_name`` and
    ``translation``; tracks the same and ``tracking_score``, as
    [`Tracks.to_nuscenes`][fisheye_infer.tracking.tracks.Tracks.to_nuscenes] writes them.

    Attributes:
        name (str): The sequence's name.
        stamps (Sequence[float]): Each frame's time, seconds.
        poses (np.ndarray): `(F, 4, 4)` ego-to-world pose of each frame.
        gt (Sequence[Sequence[Mapping[str, Any]]]): Per frame, the ground-truth records.
        pred (Sequence[Sequence[Mapping[str, Any]]]): Per frame, the track records.
    """

    name: str
    stamps: Sequence[float]
    poses: np.ndarray
    gt: Sequence[Sequence[Mapping[str, Any]]]
    pred: Sequence[Sequence[Mapping[str, Any]]]


@dataclass
class _Frame:
    ids: list[str]
    labels: list[int]
    xy: list[np.ndarray]
    scores: list[float]


def _frames(seq: SequenceResults, which: str, classes: dict[str, int], ranges: np.ndarray) -> list[_Frame]:
    """Boxes within range, in the world frame; track scores averaged (predictions), gaps interpolated."""
    frames = []
    for f, records in enumerate(seq.gt if which == "gt" else seq.pred):
        pose = np.asarray(seq.poses[f], np.float64)
        out = _Frame([], [], [], [])
        for r in records:
            label = classes.get(r["tracking_name"])
            t = np.asarray(r["translation"], np.float64)
            if label is None or not math.hypot(t[0], t[1]) < ranges[label]:
                continue
            out.ids.append(str(r["tracking_id"]))
            out.labels.append(label)
            out.xy.append((pose[:3, :3] @ t + pose[:3, 3])[:2])
            out.scores.append(float(r.get("tracking_score", -1.0)) if which == "pred" else -1.0)
        frames.append(out)
    if which == "pred":
        per_id: dict[str, list[float]] = {}
        for fr in frames:
            for i, s in zip(fr.ids, fr.scores):
                per_id.setdefault(i, []).append(s)
        mean = {i: float(np.mean(s)) for i, s in per_id.items()}
        for fr in frames:
            fr.scores = [mean[i] for i in fr.ids]
    return _interpolate(frames, [round(float(s) * 1e6) for s in seq.stamps])  # microseconds, as nuScenes stamps


def _interpolate(frames: list[_Frame], stamps: list[int]) -> list[_Frame]:
    """The devkit's ``interpolate_tracks``: a box for every frame inside a track's span that lacks one."""
    boxes: dict[str, list[tuple[int, int]]] = {}  # id -> (frame, index) in time order
    for f, fr in enumerate(frames):
        for k, i in enumerate(fr.ids):
            boxes.setdefault(i, []).append((f, k))
    for f in range(len(frames)):
        for i, track in boxes.items():
            times = [stamps[g] for g, _ in track]
            if not times[0] <= stamps[f] <= times[-1] or any(g == f for g, _ in track):
                continue
            right = bisect(times, stamps[f])
            (fl, kl), (fr_, kr) = track[right - 1], track[right]
            ratio = (stamps[fr_] - stamps[f]) / (stamps[fr_] - stamps[fl])  # the devkit's weight of the right box
            left_box, right_box = frames[fl], frames[fr_]
            frames[f].ids.append(i)
            frames[f].labels.append(right_box.labels[kr])
            frames[f].xy.append((1 - ratio) * left_box.xy[kl] + ratio * right_box.xy[kr])
            frames[f].scores.append((1 - ratio) * left_box.scores[kl] + ratio * right_box.scores[kr])
    return frames


def _accumulate(
    gt: list[list[_Frame]], pred: list[list[_Frame]], label: int, threshold: float | None, dist_th: float
) -> tuple[list[MotAccumulator], list[float]]:
    """One accumulator per sequence at a score threshold (None: every box), and the scores of the matches."""
    accs, scores = [], []
    for gt_frames, pred_frames in zip(gt, pred):
        acc = MotAccumulator()
        for g, p in zip(gt_frames, pred_frames):
            gi = [k for k, lab in enumerate(g.labels) if lab == label]
            pi = [
                k for k, lab in enumerate(p.labels) if lab == label and (threshold is None or p.scores[k] >= threshold)
            ]
            if not gi and not pi:
                continue
            if gi and pi:
                a, b = np.array([g.xy[k] for k in gi]), np.array([p.xy[k] for k in pi])
                d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
                d[d >= dist_th] = np.nan
            else:
                d = np.zeros((len(gi), len(pi)))
            hids = [p.ids[k] for k in pi]
            matched = acc.update([g.ids[k] for k in gi], hids, d)
            if threshold is None:
                ids = {hids[j] for j in matched}
                scores += [p.scores[k] for k in pi if p.ids[k] in ids]
        accs.append(acc)
    return accs, scores


def _thresholds(scores: list[float], gt_count: int) -> np.ndarray:
    """The devkit's ``compute_thresholds``: score thresholds at recalls 1 down to 0.1, NaN where unreached."""
    if not scores:
        return np.full(NUM_THRESHOLDS, np.nan)
    s = np.sort(np.array(scores))[::-1]
    rec = np.arange(1, len(s) + 1) / gt_count
    rec_interp = np.linspace(MIN_RECALL, 1, NUM_THRESHOLDS).round(12)
    th = np.interp(rec_interp, rec, s, right=0)
    th[rec_interp > rec.max()] = np.nan
    return th[::-1]


def _class_metrics(gt: list[list[_Frame]], pred: list[list[_Frame]], label: int, dist_th: float) -> dict[str, float]:
    gt_count = sum(lab == label for frames in gt for fr in frames for lab in fr.labels)
    if gt_count == 0:
        return {m: math.nan for m in TRACKING_METRICS}
    thresholds = _thresholds(_accumulate(gt, pred, label, None, dist_th)[1], gt_count)
    valid = thresholds[~np.isnan(thresholds)]
    per: dict[float, MotSummary] = {}
    for th in valid:
        if float(th) not in per:
            per[float(th)] = summarize(_accumulate(gt, pred, label, float(th), dist_th)[0])
    rows: list[dict[str, float] | None] = [None] * int(np.isnan(thresholds).sum())
    rows += [{k: float(v) for k, v in asdict(per[float(th)]).items()} for th in valid]
    if not per:
        gt_ids = {i for frames in gt for fr in frames for i, lab in zip(fr.ids, fr.labels) if lab == label}
        worst = {**_WORST, "ml": float(len(gt_ids)), "gt": float(gt_count), "fn": float(gt_count)}
        rows = [{k: worst.get(k, math.nan) for k in TRACKING_METRICS if k not in ("amota", "amotp")}] * NUM_THRESHOLDS
    series = {k: np.array([math.nan if r is None else r[k] for r in rows]) for k in ("mota", "motar", "motp")}
    out: dict[str, float] = {}
    if not np.all(np.isnan(series["mota"])):
        best = rows[int(np.nanargmax(series["mota"]))]
        assert best is not None
        out = {k: best[k] for k in TRACKING_METRICS if k not in ("amota", "amotp")}
    for name, key in (("amota", "motar"), ("amotp", "motp")):
        values = series[key]
        out[name] = (
            math.nan if np.all(np.isnan(values)) else float(np.mean(np.where(np.isnan(values), _WORST[name], values)))
        )
    return {m: out.get(m, math.nan) for m in TRACKING_METRICS}


@dataclass(frozen=True)
class TrackingReport:
    """Tracking metrics per reference range: per class and overall.

    The metrics are ``amota``, ``amotp``, ``mota``, ``motp``, ``motar``, ``recall``, ``ids``, ``frag``, ``tp``,
    ``fp``, ``fn``, ``gt``, ``mt``, ``ml`` and ``faf``; NaN where a class has no ground truth. Overall values
    average the classes (rates) or add them (counts).

    Attributes:
        classes (dict[float, dict[str, dict[str, float]]]): Reference range (m) -> class name -> metric -> value.
        overall (dict[float, dict[str, float]]): Reference range (m) -> metric -> value.
        hota (dict[float, dict[str, dict[str, float]]]): Reference range (m) -> class name or ``overall`` ->
            ``hota``, ``deta``, ``assa``, ``loca`` ([`evaluate_hota`][fisheye_infer.eval.hota.evaluate_hota]);
            empty unless asked for.
    """

    classes: dict[float, dict[str, dict[str, float]]]
    overall: dict[float, dict[str, float]]
    hota: dict[float, dict[str, dict[str, float]]] = field(default_factory=dict)

    def to_json(self, **kwargs: Any) -> str:
        """The report as a JSON document keyed ``"0-30m"``, ``"0-48m"``..., NaN written as null.

        Args:
            **kwargs: Passed to `json.dumps` (e.g. ``indent=2``).

        Returns:
            str: The document.
        """

        def clean(v: float) -> float | None:
            return None if math.isnan(v) else v

        doc: dict[str, dict[str, Any]] = {
            f"0-{r:g}m": {
                "overall": {k: clean(v) for k, v in self.overall[r].items()},
                "classes": {c: {k: clean(v) for k, v in m.items()} for c, m in self.classes[r].items()},
            }
            for r in self.overall
        }
        for r, scores in self.hota.items():
            doc[f"0-{r:g}m"]["hota"] = {c: {k: clean(v) for k, v in m.items()} for c, m in scores.items()}
        return json.dumps(doc, **kwargs)

    def to_markdown(self) -> str:
        """One Markdown table per reference range: AMOTA, AMOTP, MOTA, MOTP, recall, IDS, FRAG and GT per class.

        Returns:
            str: The tables.
        """
        cols = ("amota", "amotp", "mota", "motp", "recall", "ids", "frag", "gt")
        lines = []
        for r, per_class in self.classes.items():
            lines += [f"## Tracking, 0-{r:g} m", "", "| class | " + " | ".join(c.upper() for c in cols) + " |"]
            lines.append("|---" * (len(cols) + 1) + "|")
            for name, m in [*per_class.items(), ("overall", self.overall[r])]:
                cells = [("-" if math.isnan(m[c]) else f"{m[c]:.0f}" if c in _COUNTS else f"{m[c]:.3f}") for c in cols]
                lines.append(f"| {name} | " + " | ".join(cells) + " |")
            lines.append("")
            if r in self.hota:
                h = self.hota[r]["overall"]
                parts = ", ".join(f"{k} {h[k.lower()]:.3f}" for k in ("DetA", "AssA", "LocA"))
                lines += [f"HOTA {h['hota']:.3f} ({parts})", ""]
        return "\n".join(lines)


def evaluate_tracking(
    sequences: Sequence[SequenceResults],
    config: EvalConfig | None = None,
    ref_ranges: Sequence[float] | None = None,
    hota: bool = False,
) -> TrackingReport:
    """nuScenes tracking metrics of ``sequences`` at each reference range.

    The steps are the nuScenes devkit's tracking evaluation: boxes beyond their class's range are dropped, a
    track's score becomes its mean over the sequence, gaps are interpolated, and at 40 score thresholds the
    CLEAR-MOT events of centre distances below ``dist_th_tp`` (in the world frame) give MOTAR, MOTP and the
    counts; AMOTA and AMOTP average them over the thresholds.

    Args:
        sequences (Sequence[SequenceResults]): Ground truth and tracks per frame.
        config (EvalConfig | None): Classes, class ranges and the match distance (``dist_th_tp``, 2 m).
        ref_ranges (Sequence[float] | None): Reference ranges (default: ``config.distance_breakdown``, 30 and 48 m).
        hota (bool): Also HOTA, DetA, AssA and LocA at each range, by TrackEval
            ([`evaluate_hota`][fisheye_infer.eval.hota.evaluate_hota]).

    Returns:
        TrackingReport: Per range, per class and overall.

    Raises:
        OptionError: ``hota`` without TrackEval installed.
    """
    config = config or EvalConfig()
    classes = {name: k for k, name in enumerate(config.class_names)}
    per_class: dict[float, dict[str, dict[str, float]]] = {}
    overall: dict[float, dict[str, float]] = {}
    for ref in ref_ranges or config.distance_breakdown:
        ranges = config.class_ranges(ref)
        gt = [_frames(s, "gt", classes, ranges) for s in sequences]
        pred = [_frames(s, "pred", classes, ranges) for s in sequences]
        per_class[ref] = {name: _class_metrics(gt, pred, k, config.dist_th_tp) for name, k in classes.items()}
        overall[ref] = {}
        for m in TRACKING_METRICS:
            values = np.array([per_class[ref][c][m] for c in classes])
            overall[ref][m] = (
                math.nan
                if np.all(np.isnan(values))
                else float(np.nansum(values) if m in _COUNTS else np.nanmean(values))
            )
    scores: dict[float, dict[str, dict[str, float]]] = {}
    if hota:
        from fisheye_infer.eval.hota import evaluate_hota

        scores = {ref: evaluate_hota(sequences, config, ref) for ref in per_class}
    return TrackingReport(per_class, overall, scores)
