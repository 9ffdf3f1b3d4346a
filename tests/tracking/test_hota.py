"""HOTA through TrackEval against values worked out by hand (skipped where TrackEval is not installed:
``pip install --no-deps --target DIR trackeval``, ``PYTHONPATH=DIR``)."""

from __future__ import annotations

import json
import math

import pytest

from fisheye_infer.eval.hota import evaluate_hota
from fisheye_infer.eval.tracking import evaluate_tracking

pytest.importorskip("trackeval.metrics")
from test_tracking_metrics import rec, sequence  # noqa: E402


def test_perfect_tracks_score_one_and_classes_without_ground_truth_are_left_out() -> None:
    gt = [[rec(10 + k, 0, "1"), rec(-5, 3, "2", "Pedestrian")] for k in range(6)]
    pred = [[rec(10 + k, 0, "7", score=0.9), rec(-5, 3, "8", "Pedestrian", 0.6)] for k in range(6)]
    scores = evaluate_hota([sequence(gt, pred)])
    assert scores["overall"] == pytest.approx({"hota": 1.0, "deta": 1.0, "assa": 1.0, "loca": 1.0})
    assert math.isnan(scores["Bus"]["hota"])


def test_a_switch_halves_association() -> None:
    # one object seen exactly by track a for two frames, then by track b: every detection right (DetA 1), each
    # pair of ids shares 2 of the object's 4 frames (AssA 1/2)
    gt = [[rec(10, 0, "1")] for _ in range(4)]
    pred = [[rec(10, 0, "a" if k < 2 else "b", score=0.8)] for k in range(4)]
    car = evaluate_hota([sequence(gt, pred)])["Car"]
    assert (car["deta"], car["assa"]) == pytest.approx((1.0, 0.5))
    assert car["hota"] == pytest.approx(math.sqrt(0.5))


def test_a_metre_off_counts_at_the_lower_half_of_the_thresholds() -> None:
    # similarity 1 - 1 m / 2 m = 0.5: a match at the 10 thresholds 0.05 to 0.5 of 19, none above
    gt = [[rec(10, 0, "1")] for _ in range(5)]
    pred = [[rec(11, 0, "a", score=0.8)] for _ in range(5)]
    car = evaluate_hota([sequence(gt, pred)])["Car"]
    assert (car["hota"], car["deta"], car["assa"]) == pytest.approx((10 / 19, 10 / 19, 10 / 19))


def test_the_tracking_report_carries_hota_per_range() -> None:
    gt = [[rec(10, 0, "1"), rec(40, 0, "2")] for _ in range(4)]  # the second car only within 0-48 m
    pred = [[rec(10, 0, "a" if k < 2 else "b", score=0.8), rec(40, 0, "c", score=0.7)] for k in range(4)]
    seqs = [sequence(gt, pred)]
    report = evaluate_tracking(seqs, hota=True)
    assert set(report.hota) == set(report.overall) == {30.0, 48.0}
    for ref in (30.0, 48.0):
        assert report.hota[ref]["overall"] == pytest.approx(evaluate_hota(seqs, ref_range=ref)["overall"])
    assert report.hota[30.0]["Car"]["assa"] == pytest.approx(0.5)  # the switching track alone
    assert report.hota[48.0]["Car"]["assa"] > 0.5  # with the car tracked throughout
    doc = json.loads(report.to_json())
    assert doc["0-48m"]["hota"]["overall"]["hota"] == pytest.approx(report.hota[48.0]["overall"]["hota"])
    assert "HOTA " in report.to_markdown()
    assert evaluate_tracking(seqs).hota == {} and "hota" not in json.loads(evaluate_tracking(seqs).to_json())["0-48m"]
