"""Measure accuracy: the Fisheye3DOD reader and the FDS/mAP metric, torch-free.

    from fisheye_infer.eval import Fisheye3DOD, evaluate_results, load_results
    report = evaluate_results(load_results("gt.json"), load_results("pred.json"))
    print(report.to_markdown())
    for frame in Fisheye3DOD("data/Fisheye3DODdataset", "val", limit=10):
        dets = detector.detect(frame.image_paths)   # frame.rig, frame.gt_boxes, frame.gt_records()

``algo`` holds the vectorised metric functions (nuScenes names), ``eval_boxes`` the boxes as
columns, ``metric_config`` and ``metric_report`` the config and report types (``metrics`` re-exports
both), ``evaluate`` the orchestration, ``dataset`` the reader (``dataset_files`` its split and label
files) and ``writer`` its inverse, ``random_boxes`` ground truth and predictions without images,
``top_match`` the share of a reference's top boxes a candidate finds again (how an int8 or fp16 file
is judged against its fp32 file), ``bootstrap`` how sure a difference between two models scored on
the same frames is (a paired bootstrap over the frames). For tracking: ``sequences`` reads a split as
sequences (stamps, ego poses, instance ids), ``track_run`` runs a detector and a tracker over them,
``tracking`` scores the tracks as nuScenes' tracking evaluation does, on ``mot``'s CLEAR-MOT events.
The commands are ``fisheye_infer.commands.eval``/``synth``.
"""

from fisheye_infer.eval.algo import accumulate, calc_ap, calc_tp, center_distance, scale_iou, yaw_diff
from fisheye_infer.eval.dataset import DatasetError, Fisheye3DOD, Frame
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import evaluate, evaluate_results, load_results, save_results
from fisheye_infer.eval.metric_config import EvalConfig
from fisheye_infer.eval.metric_report import MetricData, MetricsReport

__all__ = [
    "DatasetError",
    "EvalBoxes",
    "EvalConfig",
    "Fisheye3DOD",
    "Frame",
    "MetricData",
    "MetricsReport",
    "accumulate",
    "calc_ap",
    "calc_tp",
    "center_distance",
    "evaluate",
    "evaluate_results",
    "load_results",
    "save_results",
    "scale_iou",
    "yaw_diff",
]
