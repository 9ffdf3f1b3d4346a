"""Depth targets from the renderer and BEVDepth's depth loss, on a hand-made scene."""

from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import default_rig  # noqa: E402
from fisheye_infer.models import create_model  # noqa: E402
from fisheye_infer.models.training.depth import DepthTargets, depth_loss  # noqa: E402
from fisheye_infer.scenes.render import resized_rig  # noqa: E402
from fisheye_infer.scenes.scene import Scene  # noqa: E402

GROUND = -2.0
#: A 4 m cube standing on the ground, its near face 8 m ahead of the lidar (6.6 m ahead of the front camera).
CUBE = np.array([[10.0, 0.0, GROUND, 4.0, 4.0, 4.0, 0.0]])


@pytest.fixture(scope="module")
def setup(small_bevdet_config):
    rig = resized_rig(default_rig(), 0.2)
    model = create_model("fisheye-bevdet", small_bevdet_config, rig)
    vt = small_bevdet_config.view_transform
    return DepthTargets(model.view_transform.geometry), model.view_transform.geometry, vt, rig


def _centre_rays(geometry) -> np.ndarray:
    f = np.asarray(geometry.frustum[0], np.float64)
    return f / np.linalg.norm(f, axis=-1, keepdims=True)  # H x W x 3, camera frame


def test_a_cell_looking_at_a_box_targets_the_boxs_depth_and_the_ground_cells_the_ground(setup) -> None:
    targets, geometry, vt, rig = setup
    start, _, step = vt.dbound
    bins = targets(Scene(CUBE, np.zeros(1, np.int64), GROUND))
    front = rig.names.index("fisheye_camera_front")
    m = rig.camera("fisheye_camera_front").matrix
    rays = _centre_rays(geometry) @ m[:3, :3].T  # lidar frame
    h, w = np.unravel_index(np.argmax(rays[..., 0]), rays.shape[:2])  # the cell looking straight ahead
    depth = start + step * bins[front, h, w]
    assert abs(depth - (8.0 - m[0, 3])) <= step + 0.1
    bottom = rays.shape[0] - 1  # looks down: meets the ground before the cube
    ground = (m[2, 3] - GROUND) / -rays[bottom, w, 2]
    assert bins[front, bottom, w] == round((ground - start) / step)
    assert (bins[front, 0] == -1).all()  # the top row looks at the sky


def test_without_the_box_the_same_cell_has_no_target_or_the_ground(setup) -> None:
    targets, geometry, vt, rig = setup
    with_box = targets(Scene(CUBE, np.zeros(1, np.int64), GROUND))
    without = targets(Scene(np.zeros((0, 7)), np.zeros(0, np.int64), GROUND))
    changed = with_box != without
    assert changed.any() and (with_box[changed] >= 0).all()
    assert changed[rig.names.index("fisheye_camera_front")].any()
    assert not changed[
        rig.names.index("fisheye_camera_rear")
    ].any()  # the cube lies behind the rear camera's 220 degrees
    assert (without[with_box == -1] == -1).all()  # a box never removes a target


def test_depth_loss_is_small_for_the_right_bin_and_ignores_cells_without_target() -> None:
    target = torch.tensor([[[3, -1]]])  # M x H x W
    right = torch.full((1, 8, 1, 2), 1e-4)
    right[0, 3, 0, 0] = 1 - 7e-4
    wrong = torch.full((1, 8, 1, 2), 1e-4)
    wrong[0, 5, 0, 0] = 1 - 7e-4
    assert float(depth_loss(right, target)) < 0.01 < 10 < float(depth_loss(wrong, target))
    assert float(depth_loss(right, torch.full((1, 1, 2), -1))) == 0.0
    probs = torch.softmax(torch.randn(1, 8, 1, 2), 1)
    expected = -(
        torch.log(probs[0, 3, 0, 0]) + torch.log(1 - probs[0, :, 0, 0]).sum() - torch.log(1 - probs[0, 3, 0, 0])
    )
    assert math.isclose(float(depth_loss(probs, target)), float(expected), rel_tol=1e-5)


@pytest.fixture(scope="module")
def rectified() -> dict:
    """The compact perspective- and cylindrically-rectified BEVDet geometries, and their rig."""
    from fisheye_infer.models.training.compact import compact_setup

    out = {}
    for arch in ("fisheye-bevdet-persp", "fisheye-bevdet-cyl"):
        config, rig = compact_setup(arch)
        out[arch] = create_model(arch, config, rig).view_transform.geometry, rig
    return out


def test_the_compact_rectified_views_show_the_lens_in_every_cell(rectified) -> None:
    for geometry, _ in rectified.values():
        assert geometry.inside_lens.all()


def test_a_view_wider_than_the_lens_has_no_target_beyond_it(rectified) -> None:
    """170-degree views turned 55 degrees reach 140 degrees off the fisheye's axis, past its 110: their outer
    columns show black, where no depth is taught; every other cell keeps its target."""
    from dataclasses import replace

    from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry
    from fisheye_infer.geometry.views import Perspective

    compact, rig = rectified["fisheye-bevdet-persp"]
    views = Perspective(size=compact.params.views.size, fov=170.0, yaws=compact.params.views.yaws)
    wide = PinholeLSSGeometry.from_rig(rig, compact.params.model_copy(update={"views": views}))
    inside = wide.inside_lens  # (cameras x yaws) x H x W, camera by camera
    assert inside.shape[0] == len(rig.names) * 2
    assert not inside.all() and inside[:, :, inside.shape[2] // 2].all()  # the centre column shows the lens
    assert not inside[0, :, 0].any() and not inside[1, :, -1].any()  # the outer edges of the two views do not
    scene = Scene(CUBE, np.zeros(1, np.int64), GROUND)
    bins = DepthTargets(wide)(scene)  # views (camera by camera, each camera's yaws) x H x W
    unmasked = DepthTargets(replace(wide, inside_lens=None))(scene)
    assert (bins[~inside] == -1).all() and (unmasked[~inside] >= 0).any()
    assert np.array_equal(bins[inside], unmasked[inside])
