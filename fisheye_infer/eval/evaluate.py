"""Orchestration only: results -> ``EvalBoxes`` -> range filter -> per class and threshold -> report.

    gt = load_results("gt.json")                 # {"results": {sample_token: [record, ...]}}
    pred = load_results("pred.json")
    report = evaluate_results(gt, pred)          # MetricsReport
    print(report.to_markdown())

Sample order follows the predictions (as the official evaluator, which walks one results list
for both), so score ties break the same way. Every prediction token must have ground truth;
ground-truth samples without predictions are an error unless ``allow_missing`` counts them as
frames where nothing was detected.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import FrameError
from fisheye_infer.eval.algo import accumulate_thresholds, calc_ap, calc_tp
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.metric_config import EvalConfig
from fisheye_infer.eval.metric_report import TP_METRICS, ClassMetrics, MetricsReport, Summary
from fisheye_infer.tools.progress import Progress

if TYPE_CHECKING:
    from fisheye_infer.eval.dataset import Fisheye3DOD
    from fisheye_infer.runtime.detector import FrameDetector

__all__ = [
    "evaluate",
    "evaluate_results",
    "summarise",
    "detect_dataset",
    "load_results",
    "save_results",
    "breakdown_label",
]

Results = Mapping[str, Sequence[Mapping[str, Any]]]


def breakdown_label(ref_range: float) -> str:
    return f"0-{ref_range:g} m"


def summarise(gt: EvalBoxes, pred: EvalBoxes, config: EvalConfig, ref_range: float | None = None) -> Summary:
    """The metric for one set of class ranges (``ref_range``: rescale them; default as configured)."""
    names = config.class_names
    if config.max_boxes_per_sample is not None:
        pred = pred.top_per_sample(config.max_boxes_per_sample)
    ranges = config.class_ranges(ref_range)
    gt_by, pred_by = gt.by_class(len(names), ranges), pred.by_class(len(names), ranges)
    classes = {}
    for c, name in enumerate(names):
        mds = accumulate_thresholds(gt_by[c], pred_by[c], config.dist_ths, period=config.period(name))
        aps = {
            str(float(th)): calc_ap(md, config.min_recall, config.min_precision) for th, md in zip(config.dist_ths, mds)
        }
        tp_md = mds[list(config.dist_ths).index(config.dist_th_tp)]
        errs = {m: calc_tp(tp_md, config.min_recall, m) for m in TP_METRICS}
        classes[name] = ClassMetrics(ap=float(np.mean(list(aps.values()))), ap_by_threshold=aps, **errs)
    mean_ap = float(np.mean([c.ap for c in classes.values()]))
    mtp = {m: float(np.nanmean([getattr(c, m) for c in classes.values()])) for m in TP_METRICS}
    scores = [max(0.0, 1.0 - mtp[m]) for m in TP_METRICS]
    fds = (config.mean_ap_weight * mean_ap + sum(scores)) / (config.mean_ap_weight + len(TP_METRICS))
    return Summary(
        ref_range=ref_range if ref_range is not None else config.ref_range,
        FDS=fds,
        mAP=mean_ap,
        mATE=mtp["trans_err"],
        mASE=mtp["scale_err"],
        mAOE=mtp["orient_err"],
        classes=classes,
        num_gt=sum(len(b) for b in gt_by),
        num_pred=sum(len(b) for b in pred_by),
    )


def evaluate(gt: EvalBoxes, pred: EvalBoxes, config: EvalConfig | None = None) -> MetricsReport:
    """The full report on boxes already in columns: the configured metric, then the distance breakdown.

    Args:
        gt (EvalBoxes): Ground-truth boxes (``EvalBoxes.from_records(..., ground_truth=True)``).
        pred (EvalBoxes): Predicted boxes, on the same sample tokens in the same order.
        config (EvalConfig | None): The metric's settings (default: ``EvalConfig()``, the official metric).

    Returns:
        MetricsReport: The main summary and one summary per ``config.distance_breakdown`` range.

    Raises:
        ValueError: ``gt`` and ``pred`` do not share their sample tokens in the same order.
    """
    config = config or EvalConfig()
    if gt.tokens != pred.tokens:
        raise ValueError(
            "gt/pred: the two box sets must share their sample tokens, in the same order (see evaluate_results)"
        )
    t0 = time.perf_counter()
    main = summarise(gt, pred, config)
    distance = {}
    for r in config.distance_breakdown:
        same = np.array_equal(config.class_ranges(r), config.class_ranges())
        distance[breakdown_label(r)] = (
            main.model_copy(update={"ref_range": r}) if same else summarise(gt, pred, config, r)
        )
    return MetricsReport(
        main=main, distance=distance, num_samples=len(gt.tokens), config=config, eval_seconds=time.perf_counter() - t0
    )


def _sample_order(gt: Results, pred: Results, allow_missing: bool) -> list[str]:
    unknown = [t for t in pred if t not in gt]
    if unknown:
        raise FrameError(
            f"predictions: {len(unknown)} sample token(s) have no ground truth, e.g. {', '.join(unknown[:3])}"
        )
    missing = [t for t in gt if t not in pred]
    if missing and not allow_missing:
        raise FrameError(
            f"predictions: {len(missing)} of {len(gt)} ground-truth samples have no entry, "
            f"e.g. {', '.join(missing[:3])} "
            "(give an empty list for frames without detections, or allow missing samples)"
        )
    return list(pred) + missing


def evaluate_results(
    gt: Results, pred: Results, config: EvalConfig | None = None, allow_missing: bool = False
) -> MetricsReport:
    """Score predictions against ground truth, both as ``{sample_token: [record, ...]}``.

    Records are nuScenes-style (``translation``, ``size``, ``rotation``, ``detection_name``,
    ``detection_score``), as [`Detections.to_nuscenes`][fisheye_infer.runtime.detections.Detections.to_nuscenes]
    and [`Frame.gt_records`][fisheye_infer.eval.dataset.Frame.gt_records] write them. Ground-truth records need
    no ``detection_score``; whatever they carry is ignored.

    Args:
        gt (Results): Ground truth per sample token.
        pred (Results): Predictions per sample token; every token must have ground truth (an empty list for a
            frame without detections).
        config (EvalConfig | None): The metric's settings (default: ``EvalConfig()``, the official metric).
        allow_missing (bool): Score ground-truth samples that have no predictions entry as frames without
            detections, instead of refusing them.

    Returns:
        MetricsReport: FDS, mAP, the TP errors, per-class results and the distance breakdown.

    Raises:
        FrameError: An argument is not a mapping, a predicted token has no ground truth, a ground-truth token has
            no predictions (unless ``allow_missing``), or a record is malformed.

    Examples:
        ```python
        from fisheye_infer.eval import EvalConfig, evaluate_results, load_results

        report = evaluate_results(load_results("gt.json"), load_results("pred.json"), EvalConfig(ref_range=30.0))
        print(report.FDS, report.mAP, report.main.classes["Car"].ap)
        print(report.to_markdown())
        ```
    """
    config = config or EvalConfig()
    for name, results in (("ground truth", gt), ("predictions", pred)):
        if not isinstance(results, Mapping):
            raise FrameError(
                f"{name}: expected an object mapping sample tokens to lists of records, got {type(results).__name__}"
            )
    tokens = _sample_order(gt, pred, allow_missing)
    gt_boxes = EvalBoxes.from_records(gt, config.class_names, tokens, ground_truth=True)
    pred_boxes = EvalBoxes.from_records(pred, config.class_names, tokens)
    return evaluate(gt_boxes, pred_boxes, config)


def detect_dataset(
    detector: FrameDetector, dataset: Fisheye3DOD, progress: bool = True
) -> tuple[dict[str, list[dict[str, Any]]], dict[str, list[dict[str, Any]]]]:
    """Run ``detector`` on every frame of ``dataset``: (ground truth, predictions) by sample token.

    Predictions are the detector's unthresholded output, as the official numbers are computed;
    cameras the dataset leaves out reach the detector as missing (its degraded mode). Any
    ``FrameDetector`` serves (ONNX Runtime, Triton, the PyTorch model), so their metrics compare.
    """
    gt, pred = {}, {}
    bar = Progress(len(dataset)) if progress else None
    for i, frame in enumerate(dataset, start=1):
        if i == 1:
            _warn_if_rigs_differ(frame.rig, detector.info.rig)
        pred[frame.token] = detector.detect(dict(frame.image_paths)).to_nuscenes()
        gt[frame.token] = frame.gt_records()
        if bar is not None:
            bar.update(i)
    return gt, pred


def _warn_if_rigs_differ(data_rig: Rig, model_rig: Rig, tolerance: float = 0.01) -> None:
    """The model's geometry is baked for its own rig; say so when the data were recorded with another one."""
    worst = 0.0
    lenses = []
    for cam in data_rig.cameras:
        if cam.name in model_rig.names:
            baked = model_rig.camera(cam.name)
            worst = max(worst, float(np.abs(cam.matrix - baked.matrix).max()))
            if cam.model != baked.model:
                lenses.append(cam.name)
    mismatches = [f"cam2lidar differs by up to {worst:.3f}"] if worst > tolerance else []
    mismatches += [f"the lens model of camera '{name}' differs" for name in lenses]
    if mismatches:
        print(
            f"warning: the data's rig differs from the rig baked into the model ({'; '.join(mismatches)}); "
            "results reflect that mismatch (re-bake the model for this rig with `fisheye-infer rebake`)",
            file=sys.stderr,
        )


def load_results(path: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Read a results file ``{"results": {sample_token: [record, ...]}, "meta": {...}}``.

    Args:
        path (str | Path): The JSON file (as [`save_results`][fisheye_infer.eval.evaluate.save_results] or the
            nuScenes tools write it).

    Returns:
        dict[str, list[dict[str, Any]]]: The ``results`` mapping, sample token -> records.

    Raises:
        FrameError: The file cannot be read, is not JSON, or has no ``results`` object.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as exc:
        raise FrameError(f"results file {path}: cannot be read ({exc.strerror})") from exc
    except (ValueError, RecursionError) as exc:  # also not UTF-8, a number of 4300+ digits, nested too deep
        reason = str(exc)[:200] or "nested too deep"
        raise FrameError(f"results file {path}: not valid JSON: {reason}") from None
    results = doc.get("results") if isinstance(doc, dict) else None
    if not isinstance(results, dict):
        raise FrameError(f'results file {path}: expected {{"results": {{sample_token: [record, ...]}}}}')
    return results


def save_results(
    path: str | Path, results: Mapping[str, Sequence[Mapping[str, Any]]], meta: Mapping[str, Any] | None = None
) -> Path:
    """Write a results file ``{"meta": ..., "results": ...}``, the format ``load_results`` and nuScenes tools read.

    Args:
        path (str | Path): The JSON file to write; missing folders are created.
        results (Mapping[str, Sequence[Mapping[str, Any]]]): Sample token -> records.
        meta (Mapping[str, Any] | None): Anything to keep beside the results (e.g. the model id).

    Returns:
        Path: The file written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"meta": dict(meta or {}), "results": {k: list(v) for k, v in results.items()}}))
    return path
