"""The tracking metric against values worked out by hand from nuScenes' definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.eval.mot import FP, MATCH, MISS, SWITCH, MotAccumulator, summarize
from fisheye_infer.eval.tracking import SequenceResults, evaluate_tracking


def rec(x: float, y: float, track: str, name: str = "Car", score: float | None = None) -> dict[str, object]:
    r: dict[str, object] = {"translation": [x, y, -1.0], "tracking_id": track, "tracking_name": name}
    if score is not None:
        r["tracking_score"] = score
    return r


def sequence(gt: list[list[dict]], pred: list[list[dict]], poses: np.ndarray | None = None) -> SequenceResults:  # type: ignore[type-arg]
    n = len(gt)
    return SequenceResults(
        "s", [0.1 * k for k in range(n)], np.stack([np.eye(4)] * n) if poses is None else poses, gt, pred
    )


def test_accumulator_match_switch_miss_and_fragmentation() -> None:
    acc = MotAccumulator()
    acc.update(["o"], ["a"], np.array([[0.2]]))
    acc.update(["o"], ["b"], np.array([[0.4]]))  # another track takes the object: a switch
    acc.update(["o"], [], np.zeros((1, 0)))  # missed
    acc.update(["o"], ["b", "c"], np.array([[0.6, np.nan]]))  # back with b (a match), c is a false positive
    assert [e[1] for e in acc.events] == [MATCH, SWITCH, MISS, MATCH, FP]
    s = summarize([acc])
    assert (s.gt, s.tp, s.ids, s.fn, s.fp, s.frag, s.frames) == (4, 2, 1, 1, 1, 1, 4)
    assert s.mota == pytest.approx(1 - 3 / 4)
    assert s.motp == pytest.approx((0.2 + 0.4 + 0.6) / 3)
    assert s.recall == pytest.approx(3 / 4)
    assert s.motar == pytest.approx(1 - (3 - (1 - 2 / 4) * 4) / 2)  # recall from the matches alone


def test_accumulator_keeps_an_established_pair_over_a_closer_newcomer() -> None:
    acc = MotAccumulator()
    acc.update(["o"], ["a"], np.array([[0.5]]))
    acc.update(["o"], ["a", "b"], np.array([[1.5, 0.1]]))  # b is closer, but a still reaches
    assert acc.events[1][1:4] == (MATCH, "o", "a") and acc.events[2][1] == FP


def test_perfect_tracks_score_amota_one() -> None:
    gt = [[rec(10 + k, 0, "1"), rec(-5, 3, "2", "Pedestrian")] for k in range(10)]
    pred = [[rec(10 + k, 0, "7", score=0.9), rec(-5, 3, "8", "Pedestrian", 0.6)] for k in range(10)]
    report = evaluate_tracking([sequence(gt, pred)])
    for ref in (30.0, 48.0):
        assert report.overall[ref]["amota"] == pytest.approx(1.0) and report.overall[ref]["amotp"] == pytest.approx(0.0)
        assert report.overall[ref]["ids"] == 0 and report.overall[ref]["gt"] == 20
    assert math.isnan(report.classes[48.0]["Bus"]["amota"])  # no ground truth: left out of the average


def test_half_found_track_by_hand() -> None:
    # one car over 10 frames, tracked in the first 5 at 0.5 m: recall 0.5 reaches 18 of the 40 recall steps
    gt = [[rec(10, 0, "1")] for _ in range(10)]
    pred = [[rec(10.5, 0, "t", score=0.5)] if k < 5 else [] for k in range(10)]
    m = evaluate_tracking([sequence(gt, pred)]).classes[48.0]["Car"]
    reached = int(np.sum(np.linspace(0.1, 1, 40).round(12) <= 0.5))
    assert reached == 18
    assert m["amota"] == pytest.approx(reached / 40)  # MOTAR 1 where reached, 0 elsewhere
    assert m["amotp"] == pytest.approx((reached * 0.5 + (40 - reached) * 2.0) / 40)
    assert (m["mota"], m["recall"], m["motp"], m["frag"], m["fn"]) == pytest.approx((0.5, 0.5, 0.5, 0, 5))


def test_gaps_are_interpolated_and_ranges_applied() -> None:
    gt = [[rec(10 + k, 0, "1"), rec(40, 0, "2")] for k in range(5)]  # the second is beyond 30 m
    pred = [[rec(10 + k, 0, "t", score=0.8)] if k != 2 else [] for k in range(5)]
    report = evaluate_tracking([sequence(gt, pred)])
    near = report.classes[30.0]["Car"]
    assert (near["gt"], near["tp"], near["frag"], near["amota"]) == (5, 5, 0, pytest.approx(1.0))
    assert report.classes[48.0]["Car"]["gt"] == 10


def test_a_swap_counts_as_identity_switches() -> None:
    gt = [[rec(0, 0, "1"), rec(0, 5, "2")] for _ in range(6)]
    pred = [
        [rec(0, 0, "a" if k < 3 else "b", score=0.9), rec(0, 5, "b" if k < 3 else "a", score=0.9)] for k in range(6)
    ]
    m = evaluate_tracking([sequence(gt, pred)]).classes[48.0]["Car"]
    assert m["ids"] == 2 and m["mota"] == pytest.approx(1 - 2 / 12)


def test_matching_is_done_in_the_world_frame() -> None:
    # a parked car at world (20, 0); the ego drives 5 m per frame and turns; the track misses frame 2
    poses, gt, pred = [], [], []
    for k in range(5):
        yaw, pose = 0.2 * k, np.eye(4)
        pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        pose[:2, 3] = [5.0 * k, 0.0]
        local = np.linalg.inv(pose) @ [20.0, 0.0, -1.0, 1.0]
        poses.append(pose)
        gt.append([rec(local[0], local[1], "1")])
        pred.append([rec(local[0], local[1], "t", score=0.7)] if k != 2 else [])
    m = evaluate_tracking([sequence(gt, pred, np.stack(poses))]).classes[48.0]["Car"]
    assert m["tp"] == 5 and m["motp"] == pytest.approx(0.0, abs=1e-9)


def test_custom_ranges() -> None:
    gt = [[rec(20, 0, "1")] for _ in range(3)]
    report = evaluate_tracking([sequence(gt, [[] for _ in range(3)])], EvalConfig(), ref_ranges=[10.0])
    assert list(report.overall) == [10.0] and math.isnan(report.overall[10.0]["amota"])
