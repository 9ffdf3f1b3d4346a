"""HOTA (Luiten et al., IJCV 2021) of tracking results, computed by TrackEval's own implementation.

    scores = evaluate_hota(sequences)              # the SequenceResults that evaluate_tracking reads
    scores["overall"]["hota"], scores["Car"]["assa"]

TrackEval is not a dependency: ``pip install --no-deps trackeval`` (1.3, which runs on numpy 2; its HOTA
needs only numpy and scipy, and its declared dependencies would add the GUI build of OpenCV beside the
headless one the project uses). The boxes are those ``evaluate_tracking`` scores at the reference range:
within their class's range, in the world frame, each track's gaps filled; every reported track counts
(HOTA has no score threshold). The similarity of a track and an object is ``1 - d / dist_th_tp`` of their
centre distance ``d`` (0 beyond 2 m), so HOTA's localisation thresholds 0.05 to 0.95 are distances of
1.9 m down to 0.1 m. Per class HOTA, DetA, AssA and LocA are averaged over those thresholds and combined
over sequences as TrackEval combines them; ``overall`` averages the classes that have ground truth.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Sequence
from typing import Any

import numpy as np

from fisheye_infer.errors import OptionError
from fisheye_infer.eval.metric_config import EvalConfig
from fisheye_infer.eval.tracking import SequenceResults, _Frame, _frames

__all__ = ["HOTA_METRICS", "evaluate_hota", "hota_metric"]

#: Values per class and overall: TrackEval's HOTA, DetA, AssA and LocA, each averaged over its thresholds.
HOTA_METRICS = ("hota", "deta", "assa", "loca")


def _sequence_data(gt: list[_Frame], pred: list[_Frame], label: int, dist_th: float) -> dict[str, Any]:
    """One class of one sequence in the layout of TrackEval's ``HOTA.eval_sequence``."""
    gt_index: dict[str, int] = {}
    pred_index: dict[str, int] = {}
    data: dict[str, Any] = {"gt_ids": [], "tracker_ids": [], "similarity_scores": []}
    for g, p in zip(gt, pred):
        gk = [k for k, lab in enumerate(g.labels) if lab == label]
        pk = [k for k, lab in enumerate(p.labels) if lab == label]
        data["gt_ids"].append(np.array([gt_index.setdefault(g.ids[k], len(gt_index)) for k in gk], int))
        data["tracker_ids"].append(np.array([pred_index.setdefault(p.ids[k], len(pred_index)) for k in pk], int))
        a = np.array([g.xy[k] for k in gk]).reshape(-1, 2)
        b = np.array([p.xy[k] for k in pk]).reshape(-1, 2)
        d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
        data["similarity_scores"].append(np.clip(1.0 - d / dist_th, 0.0, 1.0))
    data["num_gt_ids"], data["num_tracker_ids"] = len(gt_index), len(pred_index)
    data["num_gt_dets"] = sum(len(i) for i in data["gt_ids"])
    data["num_tracker_dets"] = sum(len(i) for i in data["tracker_ids"])
    return data


def hota_metric() -> Any:
    """TrackEval's ``HOTA`` metric class.

    Returns:
        Any: ``trackeval.metrics.HOTA``.

    Raises:
        OptionError: TrackEval is not installed.
    """
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # its package prints which optional datasets it lacks
            from trackeval.metrics import HOTA
    except ImportError as err:
        raise OptionError("HOTA needs TrackEval: pip install --no-deps trackeval") from err
    return HOTA


def evaluate_hota(
    sequences: Sequence[SequenceResults], config: EvalConfig | None = None, ref_range: float = 48.0
) -> dict[str, dict[str, float]]:
    """HOTA, DetA, AssA and LocA per class and overall, by TrackEval's ``HOTA`` metric.

    Args:
        sequences (Sequence[SequenceResults]): Ground truth and tracks per frame, as
            [`evaluate_tracking`][fisheye_infer.eval.tracking.evaluate_tracking] reads them.
        config (EvalConfig | None): Classes, class ranges and the distance at which similarity reaches 0
            (``dist_th_tp``, 2 m).
        ref_range (float): Reference range the class ranges are scaled to, metres.

    Returns:
        dict[str, dict[str, float]]: Class name (and ``overall``) -> ``HOTA_METRICS`` -> value in [0, 1]; NaN for a
            class without ground truth.

    Raises:
        OptionError: TrackEval is not installed.
    """
    metric = hota_metric()()
    config = config or EvalConfig()
    classes = {name: k for k, name in enumerate(config.class_names)}
    ranges = config.class_ranges(ref_range)
    gt = [_frames(s, "gt", classes, ranges) for s in sequences]
    pred = [_frames(s, "pred", classes, ranges) for s in sequences]
    out: dict[str, dict[str, float]] = {}
    for name, label in classes.items():
        per_sequence = {
            str(i): metric.eval_sequence(_sequence_data(g, p, label, config.dist_th_tp))
            for i, (g, p) in enumerate(zip(gt, pred))
        }
        combined = metric.combine_sequences(per_sequence)
        has_gt = combined["HOTA_TP"].sum() + combined["HOTA_FN"].sum() > 0
        out[name] = {
            m: float(np.mean(combined[key])) if has_gt else float("nan")
            for m, key in zip(HOTA_METRICS, ("HOTA", "DetA", "AssA", "LocA"))
        }
    out["overall"] = {m: float(np.nanmean([out[c][m] for c in classes])) for m in HOTA_METRICS}
    return out
