"""FDS, mAP and the TP errors on small named situations, including the specification's worked example."""

from __future__ import annotations

import math

import numpy as np
import pytest
from eval_cases import one_of_each, record

from fisheye_infer.errors import ConfigError, FrameError
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import evaluate, evaluate_results
from fisheye_infer.eval.metrics import EvalConfig, MetricsReport
from fisheye_infer.runtime.records import CLASSES, boxes_to_records


def test_toy_example_of_the_specification() -> None:
    """§4.10: one Car, 0.75 m off and 0.2 rad turned; the five other classes have no ground truth."""
    gt = {"s": [record(10, 0, size=(4, 2, 1.5))]}
    pred = {"s": [record(10.45, 0.6, yaw=0.2, score=0.9, size=(4, 2, 1.5))]}
    report = evaluate_results(gt, pred)
    car = report.main.classes["Car"]
    assert car.ap_by_threshold == pytest.approx({"0.5": 0.0, "1.0": 1.0, "2.0": 1.0, "4.0": 1.0})
    assert car.ap == pytest.approx(0.75)
    assert (car.trans_err, car.scale_err, car.orient_err) == pytest.approx((0.75, 0.0, 0.2))
    for name in CLASSES[1:]:
        c = report.main.classes[name]
        assert (c.ap, c.trans_err, c.scale_err, c.orient_err) == (0.0, 1.0, 1.0, 1.0)
    assert report.mAP == pytest.approx(0.125)
    assert (report.main.mATE, report.main.mASE, report.main.mAOE) == pytest.approx((5.75 / 6, 5 / 6, 5.2 / 6))
    assert pytest.approx(0.119444, abs=1e-6) == report.FDS
    assert report.details()["NDS"] == report.FDS


def test_perfect_gives_map_1() -> None:
    gt = {"a": one_of_each(), "b": one_of_each(shift=3.0)}
    pred = {"a": one_of_each(score=0.9), "b": one_of_each(score=0.8, shift=3.0)}
    report = evaluate_results(gt, pred)
    assert report.mAP == pytest.approx(1.0)
    assert (report.main.mATE, report.main.mASE, report.main.mAOE) == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert pytest.approx(1.0) == report.FDS


@pytest.mark.parametrize(
    ("shift", "ate", "ap"),
    [
        (0.3, 0.3, 1.0),  # inside every threshold
        (0.7, 0.7, 0.75),  # misses 0.5 m only
        (1.5, 1.5, 0.5),  # matched at 2 and 4 m
        (3.0, 1.0, 0.25),  # only 4 m matches; no match at 2 m, so ATE is 1
    ],
)
def test_shifted_box_gives_its_shift_as_ate(shift: float, ate: float, ap: float) -> None:
    report = evaluate_results({"s": one_of_each()}, {"s": one_of_each(score=0.7, shift=shift)})
    for c in report.main.classes.values():
        assert c.trans_err == pytest.approx(ate)
        assert c.ap == pytest.approx(ap)


def test_flipped_yaw_gives_aoe_pi() -> None:
    report = evaluate_results({"s": one_of_each(yaw=0.4)}, {"s": one_of_each(score=0.7, yaw=0.4 + math.pi)})
    assert report.main.mAOE == pytest.approx(math.pi)
    assert report.mAP == pytest.approx(1.0)  # orientation does not affect matching
    assert pytest.approx((3 + 1 + 1 + 0) / 6) == report.FDS


def test_size_error_gives_ase() -> None:
    gt = {"s": [record(10, 0, size=(4, 2, 1))]}
    pred = {"s": [record(10, 0, size=(4, 2, 2), score=0.9)]}
    assert evaluate_results(gt, pred).main.classes["Car"].scale_err == pytest.approx(0.5)


def test_empty_predictions() -> None:
    report = evaluate_results({"a": one_of_each(), "b": []}, {"a": [], "b": []})
    assert report.mAP == 0.0 and report.FDS == 0.0
    assert (report.main.mATE, report.main.mASE, report.main.mAOE) == (1.0, 1.0, 1.0)


def test_no_boxes_anywhere() -> None:
    report = evaluate_results({"a": []}, {"a": []})
    assert report.mAP == 0.0 and report.FDS == 0.0 and report.main.num_gt == 0


def test_class_without_ground_truth() -> None:
    # Buses predicted but none annotated: AP 0 and errors 1 for Bus, the Car result is unaffected.
    gt = {"s": [record(10, 0)]}
    pred = {"s": [record(10, 0, score=0.9), record(-10, 0, "Bus", score=0.95)]}
    report = evaluate_results(gt, pred)
    bus = report.main.classes["Bus"]
    assert (bus.ap, bus.trans_err, bus.scale_err, bus.orient_err) == (0.0, 1.0, 1.0, 1.0)
    assert report.main.classes["Car"].ap == pytest.approx(1.0)


def test_false_positive_ranked_first_is_interpolated_without_envelope() -> None:
    # PR points (recall 0, precision 0) then (1, 0.5): precision rises linearly, p_k = k / 200,
    # and only points above 0.1 count: sum over k = 21..100 of (k / 200 - 0.1) / 0.9, over 90 points.
    gt = {"s": [record(10, 0)]}
    pred = {"s": [record(10, 0, score=0.5), record(-10, 5, score=0.9)]}
    expected = sum(k / 200 - 0.1 for k in range(21, 101)) / 0.9 / 90
    assert evaluate_results(gt, pred).main.classes["Car"].ap == pytest.approx(expected)
    assert expected == pytest.approx(0.2)


@pytest.mark.parametrize(
    ("cls", "distance", "counted"),
    [
        ("Car", 47.9, True),
        ("Car", 48.0, False),  # the range test is strict
        ("Truck", 47.99, True),
        ("Pedestrian", 35.9, True),
        ("Pedestrian", 36.0, False),
        ("Cyclist", 41.9, True),
        ("Cyclist", 42.0, False),
    ],
)
def test_range_filter(cls: str, distance: float, counted: bool) -> None:
    angle = 0.7  # the range is an x-y circle, not a square
    x, y = distance * math.cos(angle), distance * math.sin(angle)
    report = evaluate_results({"s": [record(x, y, cls)]}, {"s": [record(x, y, cls, score=0.9)]})
    assert report.main.num_gt == report.main.num_pred == int(counted)
    assert report.main.classes[cls].ap == pytest.approx(1.0 if counted else 0.0)


def test_range_ignores_height() -> None:
    report = evaluate_results({"s": [record(47.0, 0, z=30.0)]}, {"s": [record(47.0, 0, z=30.0, score=0.5)]})
    assert report.main.num_gt == 1


def test_ref_range_scales_every_class_range() -> None:
    assert EvalConfig(ref_range=30).class_ranges().tolist() == [30, 30, 30, 30, 22.5, 26.25]
    assert EvalConfig().class_ranges(36).tolist() == [36, 36, 36, 36, 27, 31.5]


def test_distance_breakdown() -> None:
    # A Car at 10 m is found and one at 35 m is missed: perfect within 0-30 m, half recall within 0-48 m.
    gt = {"s": [record(10, 0), record(0, 35)]}
    pred = {"s": [record(10, 0, score=0.9)]}
    report = evaluate_results(gt, pred)
    near, full = report.distance["0-30 m"], report.distance["0-48 m"]
    assert near.classes["Car"].ap == pytest.approx(1.0) and near.num_gt == 1 and near.ref_range == 30
    assert full.classes["Car"].ap == pytest.approx(40 / 90) and full.num_gt == 2
    assert full.FDS == report.FDS
    assert "| 0-30 m |" in report.to_markdown()


def test_pedestrian_breakdown_uses_the_scaled_range() -> None:
    # 25 m is inside the 36 m Pedestrian range but outside its 0-30 m range (22.5 m).
    report = evaluate_results({"s": [record(25, 0, "Pedestrian")]}, {"s": [record(25, 0, "Pedestrian", score=0.9)]})
    assert report.distance["0-30 m"].num_gt == 0 and report.distance["0-48 m"].num_gt == 1


def test_max_boxes_cut_is_off_unless_asked() -> None:
    gt = {"s": [record(10, 0)]}
    pred = {"s": [record(-10, 5, score=0.9), record(-10, -5, score=0.8), record(10, 0, score=0.1)]}
    assert evaluate_results(gt, pred).main.classes["Car"].ap > 0
    cut = evaluate_results(gt, pred, EvalConfig(max_boxes_per_sample=2))
    assert cut.main.classes["Car"].ap == 0.0 and cut.main.num_pred == 2


@pytest.mark.parametrize(
    ("gt", "pred", "allow", "message"),
    [
        ({"a": []}, {"a": [], "b": []}, False, r"1 sample token\(s\) have no ground truth, e.g. b"),
        ({"a": [], "b": []}, {"a": []}, False, r"1 of 2 ground-truth samples have no entry, e.g. b"),
        (
            {"a": [record(1, 1)]},
            {"a": [{"translation": [0, 0, 0]}]},
            False,
            r"sample a, record 0: missing field 'size'",
        ),
        ({"a": [record(1, 1)]}, [], False, r"predictions: expected an object"),
    ],
)
def test_results_are_checked(gt: dict, pred: dict, allow: bool, message: str) -> None:
    with pytest.raises(FrameError, match=message):
        evaluate_results(gt, pred, allow_missing=allow)


def test_ground_truth_score_is_ignored_and_may_be_absent() -> None:
    pred = {"s": one_of_each(score=0.9, shift=0.7)}
    reference = evaluate_results({"s": one_of_each()}, pred).details()
    unscored = [{k: v for k, v in r.items() if k != "detection_score"} for r in one_of_each()]
    assert evaluate_results({"s": unscored}, pred).details() == reference
    assert evaluate_results({"s": one_of_each(score=0.5)}, pred).details() == reference
    with pytest.raises(FrameError, match=r"sample s, record 0: missing field 'detection_score'"):
        evaluate_results({"s": one_of_each()}, {"s": unscored})


def test_missing_samples_can_count_as_empty() -> None:
    report = evaluate_results(
        {"a": [record(10, 0)], "b": [record(10, 0)]}, {"a": [record(10, 0, score=0.9)]}, allow_missing=True
    )
    assert report.num_samples == 2 and report.main.classes["Car"].ap == pytest.approx(40 / 90)


def test_config_round_trips_through_json() -> None:
    config = EvalConfig(ref_range=30, orientation_period={"Pedestrian": math.pi}, max_boxes_per_sample=300)
    assert EvalConfig.from_json(config.to_json()) == config
    assert EvalConfig.deserialize(EvalConfig().serialize()) == EvalConfig()


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"class_range": {"Car": 48.0}}, r"class_range: must name exactly the classes; missing \['Van'"),
        ({"dist_th_tp": 3.0}, r"dist_th_tp=3.0"),
        ({"min_precision": 1.0}, r"min_precision: "),
        ({"ref_range": -1}, r"ref_range: "),
        ({"orientation_period": {"Tram": 3.14}}, r"orientation_period"),
        ({"typo": 1}, r"typo: Extra inputs"),
    ],
)
def test_bad_config_names_the_field(data: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        EvalConfig.from_dict(data)


def test_report_round_trips_and_renders() -> None:
    report = evaluate_results({"s": one_of_each()}, {"s": one_of_each(score=0.6, shift=0.7)})
    again = MetricsReport.from_json(report.to_json())
    assert again == report
    text = report.to_markdown()
    assert "| FDS | mAP | mATE | mASE | mAOE |" in text and "| Pedestrian |" in text
    assert set(report.details()) >= {"mAP", "NDS", "Car_AP@0.5", "Cyclist_AOE"}


def test_arrays_and_records_evaluate_identically() -> None:
    rng = np.random.default_rng(5)
    boxes = np.column_stack(
        [rng.uniform(-30, 30, (40, 2)), np.full(40, -1.8), rng.uniform(0.5, 5, (40, 3)), rng.uniform(-3, 3, 40)]
    )
    labels, scores = rng.integers(0, 6, 40), rng.random(40)
    jitter = boxes + rng.normal(0, 0.3, boxes.shape) * [1, 1, 0, 0, 0, 0, 1]
    tokens = ["a", "b"]
    gt = EvalBoxes.from_arrays(tokens, [boxes[:20], boxes[20:]], [None, None], [labels[:20], labels[20:]])
    pred = EvalBoxes.from_arrays(
        tokens, [jitter[:20], jitter[20:]], [scores[:20], scores[20:]], [labels[:20], labels[20:]]
    )
    by_records = evaluate_results(
        {"a": boxes_to_records(boxes[:20], None, labels[:20]), "b": boxes_to_records(boxes[20:], None, labels[20:])},
        {
            "a": boxes_to_records(jitter[:20], scores[:20], labels[:20]),
            "b": boxes_to_records(jitter[20:], scores[20:], labels[20:]),
        },
    )
    assert evaluate(gt, pred).details() == pytest.approx(by_records.details(), abs=1e-12)
