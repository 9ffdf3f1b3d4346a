"""What the metric is configured with and what it produces: ``EvalConfig``, ``MetricData``, ``MetricsReport``.

The defaults are the official Fisheye3DOD evaluator's (a nuScenes ``DetectionEval`` with its own
classes, ranges and weights): classes Car, Van, Truck, Bus, Pedestrian, Cyclist; x-y ranges
48/48/48/48/36/42 m (scaled by ``ref_range / 48`` when a reference range is given); centre
distance thresholds 0.5/1/2/4 m; TP errors at 2 m; min recall and min precision 0.1;
FDS = (3 mAP + sum over ATE, ASE, AOE of (1 - min(1, mTP))) / 6. Orientation errors use a 2 pi
period for every class, and no per-sample box cap is applied, as in the official code.

    config = EvalConfig()                               # the official settings
    config = EvalConfig.load("eval.json")               # or a JSON file with any subset of fields
    EvalConfig.deserialize(config.serialize()) == config

The definitions live in ``metric_config`` (``EvalConfig``) and ``metric_report`` (the curves and the
report); this module re-exports them under their original import path.
"""

from __future__ import annotations

from fisheye_infer.eval.metric_config import REFERENCE_RANGE, EvalConfig
from fisheye_infer.eval.metric_report import TP_METRICS, ClassMetrics, MetricData, MetricsReport, Summary

__all__ = ["EvalConfig", "MetricData", "ClassMetrics", "Summary", "MetricsReport", "TP_METRICS", "REFERENCE_RANGE"]
