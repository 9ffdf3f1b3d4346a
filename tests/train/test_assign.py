"""3D IoU, assignment costs and the Hungarian matching, on hand-made boxes."""

from __future__ import annotations

import numpy as np
import pytest

from fisheye_infer.models.training.assign import AssignerConfig, bev_l1_cost, focal_cost, hungarian_assign, iou_3d

CUBE = np.array([0.0, 0.0, 0.0, 2.0, 2.0, 2.0, 0.0])  # x, y, z_bottom, l, w, h, yaw


@pytest.mark.parametrize(
    ("other", "expected"),
    [
        (CUBE, 1.0),  # identical
        (CUBE + [1.0, 0, 0, 0, 0, 0, 0], 4 / 12),  # half overlap along x: 4 / (8 + 8 - 4)
        (CUBE + [0, 0, 1.0, 0, 0, 0, 0], 4 / 12),  # half overlap in height
        (CUBE + [0, 0, 0, 0, 0, 0, np.pi / 2], 1.0),  # a square turned by 90 degrees is the same box
        (CUBE + [3.0, 0, 0, 0, 0, 0, 0], 0.0),  # apart
        (CUBE + [0, 0, 0, 0, 0, 0, np.pi / 4], 8 * (np.sqrt(2) - 1) * 2 / (16 - 8 * (np.sqrt(2) - 1) * 2)),  # octagon
    ],
)
def test_iou_3d(other: np.ndarray, expected: float) -> None:
    assert iou_3d(CUBE[None], np.asarray(other)[None])[0, 0] == pytest.approx(expected, abs=1e-6)


def test_focal_cost_is_lower_for_the_predicted_class() -> None:
    logits = np.array([[4.0, -4.0], [-4.0, 4.0]])
    cost = focal_cost(logits, np.array([0, 1]))
    assert cost[0, 0] < cost[0, 1] and cost[1, 1] < cost[1, 0]


def test_bev_l1_cost_is_normalised_by_the_range() -> None:
    cost = bev_l1_cost(np.array([[0.0, 0.0]]), np.array([[48.0, -24.0]]), (-48.0, -48.0), (96.0, 96.0))
    assert cost[0, 0] == pytest.approx(0.5 + 0.25)


def test_each_box_gets_the_proposal_that_sits_on_it() -> None:
    gt = np.array([[10.0, 0, -2, 4.5, 1.9, 1.6, 0], [0, -10.0, -2, 0.7, 0.7, 1.7, 0]])
    preds = np.array(
        [
            [30.0, 30, -2, 4, 2, 1.5, 0],
            [0.3, -10.1, -2, 0.7, 0.7, 1.7, 0.1],
            [9.8, 0.2, -2, 4.4, 1.9, 1.6, 0.05],
            [-20, 5, -2, 4, 2, 1.5, 0],
        ]
    )
    logits = np.zeros((4, 6))
    match = hungarian_assign(preds, logits, gt, np.array([0, 4]), (-48.0, -48.0), (96.0, 96.0))
    assert match.gt_index.tolist() == [-1, 1, 0, -1]
    assert match.positive.tolist() == [1, 2]
    assert match.iou[2] == pytest.approx(iou_3d(preds[2:3], gt[:1])[0, 0]) and match.iou[0] == 0


def test_class_cost_decides_between_equally_placed_proposals() -> None:
    gt = np.array([[5.0, 5, -2, 4.5, 1.9, 1.6, 0]])
    preds = np.repeat(gt, 2, axis=0)
    logits = np.array([[-5.0, 5.0], [5.0, -5.0]])  # proposal 1 says class 0
    match = hungarian_assign(preds, logits, gt, np.array([0]), (-48.0, -48.0), (96.0, 96.0), AssignerConfig())
    assert match.gt_index.tolist() == [-1, 0]


def test_no_ground_truth_makes_every_proposal_background() -> None:
    match = hungarian_assign(
        np.zeros((3, 7)), np.zeros((3, 6)), np.zeros((0, 7)), np.zeros(0), (-48.0, -48.0), (96.0, 96.0)
    )
    assert match.gt_index.tolist() == [-1, -1, -1] and match.positive.size == 0


def test_bad_inputs_are_named() -> None:
    with pytest.raises(ValueError, match="pred_logits"):
        hungarian_assign(np.zeros((3, 7)), np.zeros((2, 6)), CUBE[None], np.array([0]), (-48.0, -48.0), (96.0, 96.0))
    with pytest.raises(ValueError, match="gt_labels"):
        hungarian_assign(np.zeros((3, 7)), np.zeros((3, 6)), CUBE[None], np.array([9]), (-48.0, -48.0), (96.0, 96.0))
