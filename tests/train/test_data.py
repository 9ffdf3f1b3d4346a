"""Seeded synthetic training and validation frames."""

from __future__ import annotations

import numpy as np
import pytest

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.runtime.records import GT_SCORE, records_to_arrays
from fisheye_infer.scenes.render import resized_rig
from fisheye_infer.scenes.streams import SyntheticFrames

RIG = resized_rig(default_rig(), 0.1)  # 80 x 80 pictures: the content matters here, not the detail


def test_a_frame_is_a_pure_function_of_split_seed_and_index() -> None:
    a, b = SyntheticFrames(RIG, "train")[3], SyntheticFrames(RIG, "train")[3]
    assert a.images.shape == (4, 80, 80, 3) and a.images.dtype == np.uint8
    np.testing.assert_array_equal(a.images, b.images)
    assert a.records == b.records


def test_validation_frames_differ_from_training_frames() -> None:
    train, val = SyntheticFrames(RIG, "train"), SyntheticFrames(RIG, "val")
    train_boxes = [train[i].boxes for i in range(4)]
    for i in range(4):
        assert not any(len(val[i].boxes) == len(t) and np.allclose(val[i].boxes, t) for t in train_boxes)


def test_looks_are_randomised_per_frame() -> None:
    frames = SyntheticFrames(RIG, "train")
    means = [
        frames[i].images[0, 60:, :, :].reshape(-1, 3).mean(axis=0) for i in range(4)
    ]  # ground below the front camera
    assert np.ptp(np.array(means), axis=0).max() > 10


def test_labels_are_ground_truth_records_inside_the_bev_range() -> None:
    sample = SyntheticFrames(RIG, "train", bev_range=(-20.0, -20.0, 20.0, 20.0), num_objects=(12, 12))[0]
    assert all(r["detection_score"] == GT_SCORE for r in sample.records)
    boxes, _, labels = records_to_arrays(list(sample.records))
    np.testing.assert_array_equal(boxes, sample.boxes)
    np.testing.assert_array_equal(labels, sample.labels)
    assert (np.abs(sample.boxes[:, :2]) < 20).all() and len(sample.boxes) < 12  # objects up to 40 m away were dropped


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"split": "test"}, "split: expected one of train, val"),
        ({"bev_range": (0.0, 0.0, -1.0, 1.0)}, "bev_range"),
    ],
)
def test_bad_options_are_named(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SyntheticFrames(RIG, **kwargs)
