"""The metric's settings and results under one import: ``EvalConfig`` (``metric_config``: the official evaluator's
defaults) and ``MetricData``, ``MetricsReport`` (``metric_report``: the curves and the report).
"""

from __future__ import annotations

from fisheye_infer.eval.metric_config import REFERENCE_RANGE, EvalConfig
from fisheye_infer.eval.metric_report import TP_METRICS, ClassMetrics, MetricData, MetricsReport, Summary

__all__ = ["EvalConfig", "MetricData", "ClassMetrics", "Summary", "MetricsReport", "TP_METRICS", "REFERENCE_RANGE"]
