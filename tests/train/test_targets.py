"""The Gaussian heatmap target and the box code, on hand-made boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer.models.training.targets import (
    HeadGrid,
    draw_gaussian,
    encode_boxes,
    gaussian_2d,
    gaussian_radius,
    heatmap_target,
)

#: 20 x 20 cells of 1 m from (-10, -10): cell (i, j) covers x in [i - 10, i - 9), y in [j - 10, j - 9).
GRID = HeadGrid(bev_size=(20, 20), cell=(1.0, 1.0), pc_range=(-10.0, -10.0))


def test_radius_of_a_square_is_the_smallest_of_the_three_cases() -> None:
    # for a 4 x 4 cell box at overlap 0.1 the third case (both corners inside) decides
    b3, c3 = -2 * 0.1 * 8, (0.1 - 1) * 16
    expected = (b3 + math.sqrt(b3**2 - 4 * 0.4 * c3)) / 2
    assert gaussian_radius((4.0, 4.0), 0.1) == pytest.approx(expected)
    assert gaussian_radius((4.0, 4.0), 0.7) < gaussian_radius((4.0, 4.0), 0.1)  # more overlap, tighter peak


def test_gaussian_kernel_peaks_at_one_in_its_centre() -> None:
    g = gaussian_2d(2)
    assert g.shape == (5, 5) and g[2, 2] == 1.0 and g.argmax() == 12
    assert g[2, 4] == pytest.approx(math.exp(-4 / (2 * (5 / 6) ** 2)))  # sigma = diameter / 6
    np.testing.assert_array_equal(g, g.T)


def test_box_draws_a_peak_of_one_at_its_centre_cell_in_its_class_map() -> None:
    # centre (0.5, -3.2) -> cell (10, 6); rows are x, columns y
    heat = heatmap_target(np.array([[0.5, -3.2, -1.0, 4.0, 2.0, 1.5, 0.3]]), np.array([2]), GRID, num_classes=6)
    assert heat.shape == (6, 20, 20) and heat.dtype == np.float32
    assert np.argwhere(heat == 1).tolist() == [[2, 10, 6]]
    assert heat[[0, 1, 3, 4, 5]].max() == 0
    radius = 2  # min_radius wins over the computed radius of a 4 x 2 cell box
    assert heat[2, 10, 6 + radius] > 0 and heat[2, 10, 6 + radius + 1] == 0


def test_overlapping_gaussians_keep_the_maximum() -> None:
    boxes = np.array([[0.5, 0.5, 0, 3, 3, 1, 0], [2.5, 0.5, 0, 3, 3, 1, 0]])
    heat = heatmap_target(boxes, np.array([0, 0]), GRID, num_classes=1)
    single = heatmap_target(boxes[:1], np.array([0]), GRID, num_classes=1)
    assert heat[0, 10, 10] == 1 and heat[0, 12, 10] == 1
    assert heat[0, 11, 10] == max(single[0, 11, 10], heatmap_target(boxes[1:], np.array([0]), GRID, 1)[0, 11, 10])


def test_gaussian_is_clipped_at_the_border_and_centres_outside_draw_nothing() -> None:
    heat = np.zeros((5, 5), np.float32)
    draw_gaussian(heat, 0, 4, 2)
    assert heat[0, 4] == 1 and heat[2, 2] > 0
    outside = heatmap_target(np.array([[30.0, 0, 0, 4, 2, 1.5, 0]]), np.array([0]), GRID, num_classes=1)
    assert outside.max() == 0


def test_bad_labels_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="labels"):
        heatmap_target(np.zeros((1, 7)), np.array([7]), GRID, num_classes=6)
    with pytest.raises(ValueError, match="1 boxes but 2 labels"):
        heatmap_target(np.zeros((1, 7)), np.array([0, 1]), GRID, num_classes=6)


def test_box_code_decodes_back_through_the_head() -> None:
    """encode -> the head's own decode gives the box again (the conventions of the two agree)."""
    torch = pytest.importorskip("torch")
    from fisheye_infer.models.transfusion import TransFusionHead

    head = TransFusionHead(
        in_channels=8,
        hidden_channel=8,
        num_classes=2,
        num_proposals=2,
        num_heads=2,
        ffn_channels=8,
        head_conv=4,
        bev_size=(20, 20),
        out_size_factor=1,
        voxel_size=(1.0, 1.0),
        pc_range=(-10.0, -10.0),
    )
    boxes = np.array([[0.5, -3.2, -1.9, 4.0, 2.0, 1.5, 0.3], [-7.25, 8.0, -2.0, 0.7, 0.6, 1.8, -2.8]])
    code = torch.from_numpy(encode_boxes(boxes, GRID)).T[None]  # 1 x 8 x 2
    res = {
        "center": code[:, 0:2],
        "height": code[:, 2:3],
        "dim": code[:, 3:6],
        "rot": code[:, 6:8],
        "heatmap": torch.zeros(1, 2, 2),
    }
    out = head.decode(res, torch.ones(1, 2, 2), torch.zeros(1, 2, dtype=torch.int64))
    np.testing.assert_allclose(out["boxes"][0].numpy(), boxes, atol=1e-5)
