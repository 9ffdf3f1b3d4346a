"""The shared record format: layout, round trip, and errors that name the record and field."""

from __future__ import annotations

import math
import re
from contextlib import nullcontext as does_not_raise

import numpy as np
import pytest

from fisheye_infer.errors import FrameError
from fisheye_infer.eval.evaluate import load_results
from fisheye_infer.runtime.records import (
    CLASSES,
    GT_SCORE,
    bottom_to_gravity,
    boxes_to_records,
    gravity_to_bottom,
    quaternion_to_yaw,
    records_to_arrays,
)


def test_record_layout_is_gravity_centre_wlh_and_z_quaternion() -> None:
    (rec,) = boxes_to_records(
        np.array([[10.0, -2.0, -1.8, 4.5, 1.9, 1.6, math.pi / 2]]), np.array([0.8]), np.array([3])
    )
    assert rec["translation"] == pytest.approx([10.0, -2.0, -1.0])  # z_bottom + h / 2
    assert rec["size"] == [1.9, 4.5, 1.6]  # w, l, h
    assert rec["rotation"] == pytest.approx([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    assert rec["detection_name"] == "Bus" and rec["detection_score"] == 0.8


def test_ground_truth_records_carry_score_minus_one() -> None:
    recs = boxes_to_records(np.zeros((2, 7)) + [0, 0, 0, 1, 1, 1, 0], None, np.array([0, 5]))
    assert [r["detection_score"] for r in recs] == [GT_SCORE, GT_SCORE]
    assert [r["detection_name"] for r in recs] == ["Car", "Cyclist"]


@pytest.mark.parametrize(
    "yaw",
    [0.0, 0.3, -0.3, math.pi / 2, -math.pi / 2, 3.1, -3.1],  # every quadrant, near the +-pi seam
)
def test_round_trip_keeps_boxes(yaw: float) -> None:
    rng = np.random.default_rng(0)
    boxes = np.column_stack([rng.uniform(-40, 40, (6, 3)), rng.uniform(0.5, 10, (6, 3)), np.full(6, yaw)])
    scores, labels = rng.random(6), np.arange(6)
    back, back_scores, back_labels = records_to_arrays(boxes_to_records(boxes, scores, labels))
    np.testing.assert_allclose(back, boxes, atol=1e-12)
    np.testing.assert_array_equal(back_scores, scores)
    np.testing.assert_array_equal(back_labels, labels)


def test_gravity_and_bottom_are_inverse() -> None:
    boxes = np.array([[1.0, 2.0, -1.6, 4.8, 2.1, 1.5, 0.02]])
    np.testing.assert_allclose(gravity_to_bottom(boxes)[:, 2], [-2.35])
    np.testing.assert_allclose(bottom_to_gravity(gravity_to_bottom(boxes)), boxes)


def test_yaw_of_a_tilted_quaternion_is_the_heading_of_its_x_axis() -> None:
    # 90 degrees about z, then a small roll about x: the x axis still points along +y.
    qz = np.array([math.cos(math.pi / 4), 0, 0, math.sin(math.pi / 4)])
    qx = np.array([math.cos(0.1), math.sin(0.1), 0, 0])
    w1, x1, y1, z1 = qz
    w2, x2, y2, z2 = qx
    q = np.array(
        [
            [
                w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            ]
        ]
    )
    assert quaternion_to_yaw(2.0 * q)[0] == pytest.approx(math.pi / 2)  # scale does not matter


def _good() -> dict:
    return {
        "translation": [1.0, 2.0, 0.5],
        "size": [2.0, 4.0, 1.5],
        "rotation": [1.0, 0.0, 0.0, 0.0],
        "detection_name": "Car",
        "detection_score": 0.5,
    }


def _with(**changes: object) -> dict:
    rec = _good()
    for key, value in changes.items():
        if value is None:
            del rec[key]
        else:
            rec[key] = value
    return rec


@pytest.mark.parametrize(
    ("bad", "expectation"),
    [
        (_good(), does_not_raise()),  # well formed
        ({**_good(), "velocity": [0, 0], "sample_token": "x"}, does_not_raise()),  # nuScenes extras are ignored
        ({**_good(), "detection_score": 1}, does_not_raise()),  # an integer score is a number
        ("Car", pytest.raises(FrameError, match=r"record 1: expected an object")),
        (_with(size=None), pytest.raises(FrameError, match=r"record 1: missing field 'size'")),
        (
            _with(translation=[1.0, 2.0]),
            pytest.raises(FrameError, match=r"record 1: 'translation' must be 3 finite numbers"),
        ),
        (
            _with(translation=[1.0, float("nan"), 0.0]),
            pytest.raises(FrameError, match=r"record 1: 'translation' must be 3 finite"),
        ),
        (_with(size=[2.0, -4.0, 1.5]), pytest.raises(FrameError, match=r"record 1: 'size' must be positive")),
        (_with(rotation=[0, 0, 0, 0]), pytest.raises(FrameError, match=r"record 1: 'rotation' is the zero quaternion")),
        (_with(rotation=[1, 0, 0]), pytest.raises(FrameError, match=r"record 1: 'rotation' must be 4 finite numbers")),
        (
            _with(detection_name="car"),
            pytest.raises(FrameError, match=r"record 1: 'detection_name' 'car' is not one of Car"),
        ),
        (
            _with(detection_score="0.5"),
            pytest.raises(FrameError, match=r"record 1: 'detection_score' must be a finite number"),
        ),
        (
            _with(detection_score=True),
            pytest.raises(FrameError, match=r"record 1: 'detection_score' must be a finite number"),
        ),
    ],
)
def test_malformed_record_is_named(bad: object, expectation) -> None:
    with expectation:
        boxes, _, _ = records_to_arrays([_good(), bad], source="sample s0")
        assert boxes.shape == (2, 7)


def test_error_names_the_source() -> None:
    with pytest.raises(FrameError, match=re.escape("sample abc, record 0")):
        records_to_arrays([_with(detection_name="Tram")], source="sample abc")
    with pytest.raises(FrameError, match="expected a list of records"):
        records_to_arrays({"translation": [0, 0, 0]})  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("boxes", "scores", "labels", "message"),
    [
        (np.zeros((2, 6)), None, np.zeros(2, int), r"boxes: expected shape \(K, 7\)"),
        (np.ones((2, 7)), np.ones(3), np.zeros(2, int), r"scores: expected shape \(2,\)"),
        (np.ones((2, 7)), None, np.array([0, 6]), r"labels: expected integers in \[0, 6\)"),
        (np.ones((1, 7)), None, np.array([0.0]), r"labels: expected integers"),
        (np.full((1, 7), np.nan), None, np.array([0]), r"NaN"),
    ],
)
def test_boxes_to_records_refuses_bad_arrays(
    boxes: np.ndarray, scores: np.ndarray | None, labels: np.ndarray, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        boxes_to_records(boxes, scores, labels, CLASSES)


def test_empty_round_trip() -> None:
    assert boxes_to_records(np.zeros((0, 7)), np.zeros(0), np.zeros(0, int)) == []
    boxes, scores, labels = records_to_arrays([])
    assert boxes.shape == (0, 7) and scores.shape == (0,) and labels.dtype == np.int64


@pytest.mark.parametrize(
    "data, words",
    [
        (b"\xff\xfe\x00binary", "not valid JSON: 'utf-8' codec can't decode"),
        (b"[" * 100_000 + b"]" * 100_000, "not valid JSON"),
        (b'{"results": ' + b"7" * 5000 + b"}", "not valid JSON: Exceeds the limit (4300 digits)"),
        (b'{"results": [}', "not valid JSON: Expecting value"),
    ],
)
def test_a_results_file_that_is_not_json_is_named(tmp_path, data: bytes, words: str) -> None:
    """A binary file, JSON nested 100,000 deep and a 5000-digit number were tracebacks."""
    path = tmp_path / "results.json"
    path.write_bytes(data)
    with pytest.raises(FrameError, match=re.escape(f"results file {path}: {words}")):
        load_results(path)
