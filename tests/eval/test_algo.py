"""The metric's building blocks: error measures, greedy matching against its plain-loop reference, AP and TP means."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from eval_cases import record

from fisheye_infer.eval.algo import (
    accumulate,
    angle_diff,
    calc_ap,
    calc_tp,
    center_distance,
    cummean,
    match,
    match_reference,
    scale_iou,
    yaw_diff,
)
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.metrics import MetricData
from fisheye_infer.eval.random_boxes import synthetic_boxes


@pytest.mark.parametrize(
    ("gt", "pred", "period", "expected"),
    [
        (0.0, 0.2, 2 * math.pi, 0.2),  # plain difference
        (0.0, math.pi, 2 * math.pi, math.pi),  # turned round: the full error, no symmetry
        (3.1, -3.1, 2 * math.pi, 2 * math.pi - 6.2),  # across the +-pi seam
        (0.0, math.pi, math.pi, 0.0),  # a pi period forgives turning round (nuScenes barriers)
        (0.5, 0.5 + 4 * math.pi, 2 * math.pi, 0.0),  # whole turns do not count
    ],
)
def test_yaw_diff(gt: float, pred: float, period: float, expected: float) -> None:
    assert yaw_diff(np.array([gt]), np.array([pred]), period)[0] == pytest.approx(expected, abs=1e-12)


def test_angle_diff_is_signed_from_y_to_x() -> None:
    assert angle_diff(np.array([0.1]), np.array([-0.1]), 2 * math.pi)[0] == pytest.approx(0.2)
    assert angle_diff(np.array([-0.1]), np.array([0.1]), 2 * math.pi)[0] == pytest.approx(-0.2)


@pytest.mark.parametrize(
    ("gt", "pred", "expected"),
    [
        ((2, 4, 1.5), (2, 4, 1.5), 1.0),  # identical
        ((2, 4, 1.5), (4, 8, 3.0), 1 / 8),  # twice as large in every direction
        ((1, 1, 1), (1, 1, 2), 0.5),  # twice as tall
        ((2, 1, 1), (1, 2, 1), 1 / 3),  # swapped width and length
    ],
)
def test_scale_iou(gt: tuple, pred: tuple, expected: float) -> None:
    assert scale_iou(np.array([gt], float), np.array([pred], float))[0] == pytest.approx(expected)


def test_scale_iou_refuses_non_positive_sizes() -> None:
    with pytest.raises(ValueError, match="every size must be positive"):
        scale_iou(np.array([[1.0, 0.0, 1.0]]), np.array([[1.0, 1.0, 1.0]]))


def test_center_distance_ignores_height() -> None:
    assert center_distance(np.array([[10.0, 0.0, 0.75]]), np.array([[10.45, 0.6, 5.0]]))[0] == pytest.approx(0.75)


def test_cummean_skips_nans_and_all_nan_is_one() -> None:
    np.testing.assert_allclose(cummean(np.array([1.0, np.nan, 3.0])), [1.0, 1.0, 2.0])
    np.testing.assert_array_equal(cummean(np.array([np.nan, np.nan])), [1.0, 1.0])


def _boxes(gt: list[dict], pred: list[dict]) -> tuple[EvalBoxes, EvalBoxes]:
    results_gt, results_pred = {"s": gt}, {"s": pred}
    return EvalBoxes.from_records(results_gt), EvalBoxes.from_records(results_pred)


def test_nearest_free_ground_truth_is_taken() -> None:
    # The best prediction takes the nearer box; the second one falls back to the other box.
    gt, pred = _boxes([record(10, 0), record(11.5, 0)], [record(11.2, 0, score=0.9), record(11.0, 0, score=0.8)])
    order, tp, gt_row = match(gt, pred, (2.0,))
    assert order.tolist() == [0, 1] and tp[0].tolist() == [True, True] and gt_row[0].tolist() == [1, 0]


def test_equal_distance_keeps_the_first_ground_truth() -> None:
    gt, pred = _boxes([record(10, 1), record(10, -1)], [record(10, 0, score=0.5)])
    _, tp, gt_row = match(gt, pred, (2.0,))
    assert tp[0, 0] and gt_row[0, 0] == 0


def test_equal_scores_visit_the_later_prediction_first() -> None:
    gt, pred = _boxes([record(10, 0)], [record(10.2, 0, score=0.5), record(10.1, 0, score=0.5)])
    order, tp, _ = match(gt, pred, (1.0,))
    assert order.tolist() == [1, 0] and tp[0].tolist() == [True, False]


def test_distance_must_be_strictly_below_the_threshold() -> None:
    gt, pred = _boxes([record(10, 0)], [record(11, 0, score=0.5)])
    _, tp, _ = match(gt, pred, (1.0, 1.0 + 1e-9))
    assert tp[:, 0].tolist() == [False, True]


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("class_id", range(6))
def test_rounds_match_the_sequential_loop(seed: int, class_id: int) -> None:
    gt, pred = synthetic_boxes(120, 10, 40, seed=seed)
    gt, pred = gt[gt.label == class_id], pred[pred.label == class_id]
    pred = dataclasses.replace(pred, score=np.round(pred.score, 1))  # many score ties
    ths = (0.5, 1.0, 2.0, 4.0)
    order, tp, gt_row = match(gt, pred, ths)
    for t, th in enumerate(ths):
        ref_order, ref_tp, ref_row = match_reference(gt, pred, th)
        np.testing.assert_array_equal(order, ref_order)
        np.testing.assert_array_equal(tp[t], ref_tp)
        np.testing.assert_array_equal(gt_row[t], ref_row)


def test_no_predictions_gives_zero_ap_and_unit_errors() -> None:
    md = MetricData.no_predictions()
    assert calc_ap(md, 0.1, 0.1) == 0.0
    assert all(calc_tp(md, 0.1, m) == 1.0 for m in ("trans_err", "scale_err", "orient_err"))


def test_accumulate_selects_the_class() -> None:
    gt, pred = _boxes(
        [record(10, 0), record(0, 10, "Pedestrian")],
        [record(10, 0, score=0.9), record(20, 20, "Pedestrian", score=0.9)],
    )
    assert calc_ap(accumulate(gt, pred, 1.0, class_id=0), 0.1, 0.1) == pytest.approx(1.0)
    assert calc_ap(accumulate(gt, pred, 1.0, class_id=4), 0.1, 0.1) == 0.0


def test_half_recall_gives_ap_below_one_and_tp_errors_up_to_max_recall() -> None:
    gt, pred = _boxes([record(10, 0), record(-10, 0)], [record(10.5, 0, score=0.9)])
    md = accumulate(gt, pred, 2.0)
    assert md.max_recall_ind == 50
    assert calc_ap(md, 0.1, 0.1) == pytest.approx(40 / 90)  # recall points 11..50 at precision 1, the rest 0
    assert calc_tp(md, 0.1, "trans_err") == pytest.approx(0.5)


def test_tp_error_is_the_cumulative_mean_read_at_each_recall_points_confidence() -> None:
    """Two matches, errors 0.2 (score 0.9) then 0.6 (score 0.8): cumulative means 0.2, 0.4.

    Recall points 11..50 sit at confidence 0.9 (error 0.2); points 51..100 interpolate the
    confidence from 0.9 to 0.8 and so the error from 0.2 to 0.4: mean 0.302. Over the 90 points
    (40 * 0.2 + 50 * 0.302) / 90, not the plain mean 0.4 of the matches.
    """
    gt, pred = _boxes([record(10, 0), record(-10, 0)], [record(10.2, 0, score=0.9), record(-10.6, 0, score=0.8)])
    md = accumulate(gt, pred, 2.0)
    assert md.max_recall_ind == 100
    assert calc_tp(md, 0.1, "trans_err") == pytest.approx((40 * 0.2 + 50 * 0.302) / 90)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ((0.1, 1.0), "min_precision"),
        ((1.5, 0.1), "min_recall"),
    ],
)
def test_calc_ap_refuses_bad_limits(args: tuple[float, float], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        calc_ap(MetricData.no_predictions(), *args)


def test_calc_tp_refuses_unknown_metric() -> None:
    with pytest.raises(ValueError, match="metric_name"):
        calc_tp(MetricData.no_predictions(), 0.1, "vel_err")
