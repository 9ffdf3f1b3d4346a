"""Synthetic ground truth and predictions for the metric, without images (tests and ``benchmarks/metric_speed.py``).

    gt, pred = synthetic_boxes(frames=100, gt_per_frame=20, pred_per_frame=200)
    report = evaluate(gt, pred, EvalConfig())

Ground truth is drawn uniformly in a 50 m disc; predictions are noisy copies of most ground-truth
boxes (some with the wrong class) plus random false positives, up to ``pred_per_frame`` per frame,
as a detector that emits a fixed number of proposals does.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.runtime.records import CLASSES

__all__ = ["synthetic_boxes", "to_results"]

_SIZES = np.array(
    [[4.5, 1.9, 1.6], [5.0, 2.0, 2.1], [8.0, 2.5, 3.2], [11.0, 2.9, 3.4], [0.7, 0.7, 1.75], [1.8, 0.7, 1.7]]
)


def _random_boxes(rng: np.random.Generator, n: int, labels: np.ndarray) -> np.ndarray:
    r = 50 * np.sqrt(rng.random(n))
    phi = rng.uniform(-np.pi, np.pi, n)
    size = _SIZES[labels] * rng.uniform(0.85, 1.15, (n, 3))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), np.full(n, -1.8), size, rng.uniform(-np.pi, np.pi, n)])


def synthetic_boxes(frames: int, gt_per_frame: int, pred_per_frame: int, seed: int = 0) -> tuple[EvalBoxes, EvalBoxes]:
    """(ground truth, predictions) as ``EvalBoxes`` over ``frames`` samples."""
    rng = np.random.default_rng(seed)
    tokens = [f"bench.ego0.{i:08d}" for i in range(frames)]
    n_gt = frames * gt_per_frame
    gt_label = rng.choice(len(CLASSES), n_gt, p=[0.45, 0.15, 0.1, 0.05, 0.15, 0.1])
    gt_box = _random_boxes(rng, n_gt, gt_label)
    gt_sample = np.repeat(np.arange(frames), gt_per_frame)
    found = rng.random(n_gt) < 0.8
    tp_box = gt_box[found] + rng.normal(0, 1, (int(found.sum()), 7)) * [0.6, 0.6, 0.1, 0.2, 0.1, 0.1, 0.3]
    tp_box[:, 3:6] = np.abs(tp_box[:, 3:6]) + 0.05
    tp_label = np.where(rng.random(len(tp_box)) < 0.9, gt_label[found], rng.integers(0, len(CLASSES), len(tp_box)))
    tp_sample = gt_sample[found]
    fp_per_frame = max(pred_per_frame - int(round(0.8 * gt_per_frame)), 0)
    fp_label = rng.integers(0, len(CLASSES), frames * fp_per_frame)
    fp_box = _random_boxes(rng, len(fp_label), fp_label)
    fp_sample = np.repeat(np.arange(frames), fp_per_frame)
    sample = np.concatenate([tp_sample, fp_sample])
    order = np.argsort(sample, kind="stable")
    box = np.concatenate([tp_box, fp_box])[order]
    label = np.concatenate([tp_label, fp_label])[order]
    score = np.concatenate([rng.beta(5, 2, len(tp_box)), rng.beta(1.2, 6, len(fp_box))])[order]

    def as_eval(s: np.ndarray, b: np.ndarray, lab: np.ndarray, sc: np.ndarray) -> EvalBoxes:
        centre = b[:, :3].copy()
        centre[:, 2] += b[:, 5] / 2
        return EvalBoxes(tuple(tokens), s, lab, centre, b[:, [4, 3, 5]], b[:, 6], sc)

    return as_eval(gt_sample, gt_box, gt_label, np.full(n_gt, -1.0)), as_eval(sample[order], box, label, score)


def to_results(boxes: EvalBoxes) -> dict[str, list[dict]]:
    """``EvalBoxes`` back to ``{token: [record, ...]}``."""
    half = boxes.yaw / 2
    rows = zip(
        boxes.sample.tolist(),
        boxes.translation.tolist(),
        boxes.size.tolist(),
        np.cos(half).tolist(),
        np.sin(half).tolist(),
        boxes.label.tolist(),
        boxes.score.tolist(),
    )
    out: dict[str, list[dict]] = {t: [] for t in boxes.tokens}
    for s, t, size, w, z, lab, score in rows:
        out[boxes.tokens[s]].append(
            {
                "translation": t,
                "size": size,
                "rotation": [w, 0.0, 0.0, z],
                "detection_name": CLASSES[lab],
                "detection_score": score,
            }
        )
    return out
