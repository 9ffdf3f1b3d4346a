"""The paired bootstrap over frames: resamples score as the metric scores the same frames, and pairing two models on
the same resamples resolves a difference that their separate intervals do not."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from eval_cases import one_of_each

from fisheye_infer.eval.bootstrap import frame_draws, interval, resampled_fds, resolved
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import evaluate_results, summarise
from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.eval.random_boxes import synthetic_boxes


def _records(shifts: dict[str, float]) -> tuple[dict, dict]:
    gt = {token: one_of_each() for token in shifts}
    pred = {token: one_of_each(score=0.9 - 0.1 * i, shift=s) for i, (token, s) in enumerate(shifts.items())}
    return gt, pred


def test_the_identity_draw_scores_as_the_frames_themselves() -> None:
    gt, pred = synthetic_boxes(40, 8, 30, seed=3)
    config = EvalConfig()
    everything = np.arange(40)
    assert summarise(gt.take(everything), pred.take(everything), config) == summarise(gt, pred, config)


def test_a_frame_drawn_twice_counts_as_two_frames() -> None:
    gt, pred = _records({"a": 0.0, "b": 1.2, "c": 3.0})
    names, tokens = EvalConfig().class_names, sorted(gt)
    gt_boxes = EvalBoxes.from_records(gt, names, tokens, ground_truth=True)
    pred_boxes = EvalBoxes.from_records(pred, names, tokens)
    drawn = [1, 1, 2, 0, 1]
    taken_gt, taken_pred = gt_boxes.take(drawn), pred_boxes.take(drawn)
    assert taken_gt.tokens == ("b#0", "b#1", "c#2", "a#3", "b#4")
    assert taken_pred.counts().tolist() == [6, 6, 6, 6, 6]
    # the same frames written out as five samples of their own, evaluated from records
    copies = {f"{tokens[f]}#{i}": f for i, f in enumerate(drawn)}
    expected = evaluate_results(
        {t: gt[tokens[f]] for t, f in copies.items()}, {t: pred[tokens[f]] for t, f in copies.items()}
    )
    score = summarise(taken_gt, taken_pred, EvalConfig())
    assert (score.FDS, score.mAP) == pytest.approx((expected.FDS, expected.mAP), abs=1e-12)


def test_a_frame_without_boxes_is_drawn_as_an_empty_sample() -> None:
    gt, pred = synthetic_boxes(3, 4, 6, seed=1)
    pred = pred[pred.sample != 1]
    taken = pred.take([1, 0, 1])
    assert taken.counts()[[0, 2]].tolist() == [0, 0] and taken.counts()[1] == (pred.sample == 0).sum()
    np.testing.assert_array_equal(taken.score, pred.score[pred.sample == 0])


def test_out_of_range_frames_are_refused() -> None:
    gt, _ = synthetic_boxes(3, 2, 2)
    with pytest.raises(ValueError, match=r"frames: indices must lie in \[0, 3\)"):
        gt.take([0, 3])
    with pytest.raises(ValueError, match="frames and draws: expected at least 1 each, got 0 and 5"):
        frame_draws(0, 5)
    with pytest.raises(ValueError, match="level: expected a share in"):
        interval(np.zeros(3), level=1.0)


def test_draws_are_seeded() -> None:
    assert np.array_equal(frame_draws(30, 10, seed=4), frame_draws(30, 10, seed=4))
    assert not np.array_equal(frame_draws(30, 10, seed=4), frame_draws(30, 10, seed=5))


def test_pairing_resolves_what_separate_intervals_do_not() -> None:
    """B is A with every frame's true positives moved 0.4 m: a little worse on every frame. Scene to scene the FDS
    varies more than that, so the two intervals overlap; on the same resamples B is below A every time."""
    gt, a = synthetic_boxes(60, 10, 30, seed=2)
    moved = a.translation.copy()
    moved[a.score > 0.5, 0] += 0.4
    b = dataclasses.replace(a, translation=moved)
    draws = frame_draws(60, 100)
    fds_a, fds_b = resampled_fds(gt, a, draws), resampled_fds(gt, b, draws)
    (a_low, a_high), (b_low, b_high) = interval(fds_a), interval(fds_b)
    assert b_low < a_high and a_low < b_high  # the separate intervals overlap
    low, high = interval(fds_a - fds_b)
    assert resolved(low, high) and low > 0
    assert not resolved(-0.01, 0.02) and resolved(-0.03, -0.01)
