"""Geometry tables against the official constructors' tables for the shipped rig, hand-computed
cells, and the pooling plan against its np.add.at reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry import (
    BevGrid,
    build_pooling_plan,
    cylindrical_frustum,
    cylindrical_grid,
    depth_bins,
    frustum_to_lidar,
    invalid_mask,
    lid_depths,
    pool_bev,
    pool_bev_reference,
    position_coords,
    sample_bilinear,
    spherical_frustum,
    spherical_grid,
)
from fisheye_infer.geometry.pooling import voxelise

BEV = "fisheye_bevdet/view_transform."
PETR = "fisheye_petr/pts_bbox_head."


@pytest.fixture(scope="module")
def lidar_points(rig: Rig) -> np.ndarray:
    return frustum_to_lidar(spherical_frustum(depth_bins()), rig.cam2lidar())


@pytest.fixture(scope="module")
def plan(lidar_points: np.ndarray):
    return build_pooling_plan(lidar_points, BevGrid())


class TestSphericalGrid:
    def test_matches_official_sphere_grid(self, ocam800: OCamModel, official) -> None:
        grid = spherical_grid(ocam800)
        assert grid.shape == (25, 100, 2) and grid.dtype == np.float32
        np.testing.assert_allclose(grid, official[BEV + "sphere_grid_2d"], atol=1e-5, rtol=0)
        np.testing.assert_array_equal(official[PETR + "sphere_grid_2d"], official[BEV + "sphere_grid_2d"])

    def test_every_depth_slice_of_the_official_3d_grid(self, ocam800: OCamModel, official) -> None:
        """Slices agree except where float32 noise pushes the two horizon rays at exactly +-110 degrees
        (row 12, columns 0 and 99) over the fov threshold in some official slices."""
        grid3d = official[BEV + "sphere_grid_3d"]
        ours = np.broadcast_to(spherical_grid(ocam800), grid3d[..., :2].shape)
        differs = np.abs(grid3d[..., :2] - ours).max(axis=-1) > 1e-4
        assert set(map(tuple, np.argwhere(differs)[:, 1:].tolist())) <= {(12, 0), (12, 99)}
        assert not grid3d[..., 2].any()

    @pytest.mark.parametrize(
        ("h", "w", "expected"), [(12, 0, (-1.0260, -0.0024)), (0, 0, (-0.6615, -0.7036)), (24, 99, (0.6566, 0.6985))]
    )
    def test_cells_quoted_by_the_spec(self, ocam800: OCamModel, h: int, w: int, expected) -> None:
        np.testing.assert_allclose(spherical_grid(ocam800)[h, w], expected, atol=1e-4)

    def test_hand_computed_cell_uses_divisor_w(self, ocam800: OCamModel) -> None:
        """Cell (12, 50): elevation 0, azimuth +1.111 deg; g = 2u/800 - 1 (not 2u/799 - 1)."""
        az = math.radians(110) * (2 * 50 / 99 - 1)
        ray = np.array([[math.sin(az), 0.0, math.cos(az)]])
        theta = -math.atan(ray[0, 2] / abs(ray[0, 0]))
        rho = sum(c * theta**i for i, c in enumerate(ocam800.invpol))
        u = rho + ocam800.center_col
        v = ocam800.d * rho + ocam800.center_row
        np.testing.assert_allclose(spherical_grid(ocam800)[12, 50], [2 * u / 800 - 1, 2 * v / 800 - 1], atol=1e-6)

    def test_rays_outside_the_fov_get_the_sentinel(self, ocam800: OCamModel) -> None:
        narrow = ocam800.model_copy(update={"fov": 180.0})
        grid = spherical_grid(narrow)
        sentinel = np.float32(2 * -1.0 / 800 - 1)
        assert np.all(grid[12, 0] == sentinel) and np.all(grid[12, 99] == sentinel)
        assert np.all(grid[12, 40:60] > -1)

    def test_nothing_assumes_800_or_a_centred_lens(self, ocam1600: OCamModel) -> None:
        grid = spherical_grid(ocam1600.model_copy(update={"fov": 185.0}), (10, 20))
        centre_u = (grid[:, 9:11, 0].mean() + 1) * 1600 / 2
        assert centre_u == pytest.approx(ocam1600.center_col, abs=30)


class TestMasks:
    def test_petr_invalid_mask_reproduces_rounding_cells_bit_for_bit(self, ocam800: OCamModel, official) -> None:
        """From the official grid, the float32 emulation gives the official mask exactly, rounding cells included."""
        ref = official[PETR + "unvalid_area"][0, 0]
        np.testing.assert_array_equal(invalid_mask(ocam800, official[PETR + "sphere_grid_2d"]), ref)
        assert (ref != 0).sum() == 43 and ((ref > 0) & (ref < 1e-6)).sum() == 30

    def test_petr_invalid_mask_from_our_grid_has_the_same_edge_cells(self, ocam800: OCamModel, official) -> None:
        """Our grid differs from the official one by float rounding, so its rounding cells differ
        (that is why a checkpoint's stored mask is preferred); the real edge cells are the same."""
        ref = official[PETR + "unvalid_area"][0, 0]
        mask = invalid_mask(ocam800, spherical_grid(ocam800))
        np.testing.assert_array_equal(mask > 1e-6, ref > 1e-6)
        np.testing.assert_allclose(mask, ref, atol=1e-4)

    def test_bevdet_valid_fov_mask(self, ocam800: OCamModel, official) -> None:
        np.testing.assert_array_equal(
            1 - invalid_mask(ocam800, official[BEV + "sphere_grid_2d"]), official[BEV + "valid_fov_mask"][0, 0]
        )

    def test_sample_bilinear_by_hand(self) -> None:
        image = np.arange(12, dtype=np.float32).reshape(3, 4)
        # align_corners=True: g = -1 -> pixel 0, g = +1 -> last pixel; (x, y) = (1.5, 0.5) -> 0.5*(1+2)/... by hand
        grid = np.array([[[-1.0, -1.0], [1.0, 1.0], [(1.5 / 3) * 2 - 1, (0.5 / 2) * 2 - 1], [-1.2, 0.0]]], np.float32)
        out = sample_bilinear(image, grid)
        row0, row1 = 0.5 * (1 + 2), 0.5 * (5 + 6)
        expected_edge = 0.7 * image[1, 0]  # x = -0.3: 70 % of pixel 0, the outside tap reads 0
        np.testing.assert_allclose(out[0], [0.0, 11.0, 0.5 * (row0 + row1), expected_edge], atol=1e-5)


class TestFrustum:
    def test_depth_bins(self) -> None:
        d = depth_bins()
        assert d.shape == (96,) and d[0] == 0.5 and d[-1] == 48.0

    def test_matches_official_frustum(self, official) -> None:
        frustum = spherical_frustum(depth_bins())
        ref = official[BEV + "frustum"]
        assert frustum.shape == ref.shape == (96, 25, 100, 3)
        rel = np.abs(frustum - ref).max(axis=-1) / np.linalg.norm(ref, axis=-1)
        assert rel.max() < 1e-6
        np.testing.assert_array_equal(official[PETR + "frustum"], ref)

    def test_depth_is_range_along_the_ray(self) -> None:
        frustum = spherical_frustum(depth_bins())
        np.testing.assert_allclose(
            np.linalg.norm(frustum, axis=-1), np.broadcast_to(depth_bins()[:, None, None], (96, 25, 100)), rtol=1e-6
        )
        assert frustum[0, 0, 50, 1] < 0  # row 0 looks up: y (down) negative

    def test_cylindrical_depth_is_horizontal_radius(self) -> None:
        f = cylindrical_frustum(np.array([2.0], np.float32), (5, 7), (-1.0, 1.0), (-0.5, 0.5))
        np.testing.assert_allclose(np.hypot(f[..., 0], f[..., 2]), 2.0, rtol=1e-6)
        np.testing.assert_allclose(f[0, :, 0, 1], np.linspace(-1.0, 1.0, 5), rtol=1e-6)

    def test_to_lidar_uses_each_camera_pose(self, rig: Rig) -> None:
        points = frustum_to_lidar(spherical_frustum(np.array([1.0], np.float32)), rig.cam2lidar())
        # The centre ray (elevation 0, between columns 49 and 50) of the left camera points along +y.
        left = rig.names.index("fisheye_camera_left")
        centre = points[left, 0, 12, 49:51].mean(axis=0) - rig.cameras[left].position
        np.testing.assert_allclose(centre / np.linalg.norm(centre), [0, 1, 0], atol=2e-2)

    def test_cylindrical_grid_shape(self, ocam800: OCamModel) -> None:
        grid = cylindrical_grid(ocam800, (25, 50), (-math.radians(110), math.radians(110)), (-1.0, 1.0))
        assert grid.shape == (25, 50, 2) and grid.dtype == np.float32


class TestPoolingPlan:
    def test_official_bev_constants(self, official) -> None:
        grid = BevGrid()
        np.testing.assert_array_equal(grid.dx, official[BEV + "dx"])
        np.testing.assert_array_equal(grid.bx, official[BEV + "bx"])
        assert grid.nx == tuple(official[BEV + "nx"].tolist())

    def test_figures_of_the_spec(self, plan, lidar_points) -> None:
        """fisheye-bevdet.md §7 for the shipped rig."""
        assert plan.num_points == 960_000
        assert plan.num_kept == 554_668
        occupied = plan.counts[plan.counts > 0]
        assert len(occupied) == 47_944 and occupied.max() == 501 and np.median(occupied) == 7
        assert np.percentile(occupied, 99) == pytest.approx(84, abs=1)
        _, kept = voxelise(lidar_points, BevGrid())
        v = (lidar_points.reshape(-1, 3) - BevGrid().lower) / BevGrid().dx
        floor_kept = np.all((v >= 0) & (v < np.array(BevGrid().nx)), axis=1)
        assert kept.sum() - floor_kept.sum() == 179_433

    def test_trunc_keeps_points_just_below_each_lower_bound(self) -> None:
        grid = BevGrid()
        points = np.array(
            [
                [-48.1, 0.0, 0.0],
                [-48.4, 0.0, 0.0],
                [0.0, 0.0, -14.0],
                [0.0, 0.0, -15.5],
                [47.99, 47.99, 4.9],
                [48.0, 0.0, 0.0],
            ],
            np.float32,
        )
        cells, kept = voxelise(points, grid)
        assert kept.tolist() == [True, False, True, False, True, False]
        assert cells[0] == 0 * 320 + 160 and cells[4] == 319 * 320 + 319

    def test_plan_is_consistent(self, plan) -> None:
        slots = np.concatenate([b.ravel() for b in plan.bucket_points])
        real = slots[slots < plan.num_points]
        assert len(real) == plan.num_kept == len(np.unique(real))
        for pts, size in zip(plan.bucket_points, plan.bucket_sizes):
            assert pts.shape[1] == size
        occupied = plan.counts > 0
        assert np.all(plan.cell_rows[~occupied] == plan.num_rows)
        assert len(np.unique(plan.cell_rows[occupied])) == occupied.sum()
        assert all(len(pts) > 0 for pts in plan.bucket_points)  # an empty bucket holds one padding row
        read = np.zeros(plan.num_rows + 1, bool)
        read[plan.cell_rows] = True
        padding = np.concatenate([np.all(b == plan.num_points, axis=1) for b in plan.bucket_points])
        assert not np.any(read[:-1] & padding) and np.all(read[:-1] | padding)

    def test_pool_matches_add_at_reference(self, plan, lidar_points) -> None:
        rng = np.random.default_rng(0)
        logits = rng.normal(size=(4, 96, 25, 100)).astype(np.float32)
        depth = np.exp(logits) / np.exp(logits).sum(axis=1, keepdims=True)
        ctx = rng.normal(size=(4, 25, 100, 8)).astype(np.float32)
        fast = pool_bev(depth, ctx, plan)
        ref = pool_bev_reference(depth, ctx, lidar_points, BevGrid())
        assert fast.shape == (8, 320, 320)
        np.testing.assert_allclose(fast, ref, atol=1e-6, rtol=1e-5)
        assert np.abs(ref).max() > 1e-2

    def test_mean_pool_by_hand(self) -> None:
        """Two points in one cell, one in another: means, and empty cells stay zero."""
        grid = BevGrid((0.0, 3.0, 1.0), (0.0, 2.0, 1.0), (-1.0, 1.0, 2.0))
        points = np.zeros((1, 3, 1, 1, 3), np.float32)
        points[0, :, 0, 0] = [[0.5, 0.5, 0.0], [0.7, 0.2, 0.0], [2.5, 1.5, 0.0]]
        depth = np.array([0.2, 0.3, 0.5], np.float32).reshape(1, 3, 1, 1)
        ctx = np.array([[[[10.0, 1.0]]]], np.float32)
        bev = pool_bev(depth, ctx, build_pooling_plan(points, grid))
        expected = np.zeros((2, 3, 2), np.float32)
        expected[:, 0, 0] = (0.2 + 0.3) / 2 * np.array([10.0, 1.0])
        expected[:, 2, 1] = 0.5 * np.array([10.0, 1.0])
        np.testing.assert_allclose(bev, expected, rtol=1e-6)

    def test_fixed_bucket_ladder_for_a_second_rig(self, lidar_points) -> None:
        ladder = tuple(2**i for i in range(12))
        plan = build_pooling_plan(lidar_points[:2], BevGrid(), bucket_sizes=ladder)
        assert plan.bucket_sizes == ladder and len(plan.bucket_points) == 12
        assert [len(b) for b in plan.bucket_points][-1] == 1  # no cell holds 2048 points: one padding row
        rng = np.random.default_rng(1)
        depth = rng.random((2, 96, 25, 100)).astype(np.float32)
        ctx = rng.normal(size=(2, 25, 100, 4)).astype(np.float32)
        np.testing.assert_allclose(
            pool_bev(depth, ctx, plan),
            pool_bev_reference(depth, ctx, lidar_points[:2], BevGrid()),
            atol=1e-6,
            rtol=1e-5,
        )
        with pytest.raises(ValueError, match="more than the largest bucket"):
            build_pooling_plan(lidar_points, BevGrid(), bucket_sizes=(1, 2, 4))


class TestPetrCoordinates:
    def test_lid_depths(self) -> None:
        d = lid_depths()
        np.testing.assert_allclose(d[:5], [0.5, 0.52861, 0.58582, 0.67163, 0.78606], atol=1e-5)
        np.testing.assert_allclose(d[-3:], [54.5935, 56.3671, 58.1692], atol=1e-4)

    def test_identity_camera_centre_column_is_logit_half(self) -> None:
        coords = position_coords(np.eye(4)[None], out_hw=(25, 100))
        assert coords.shape == (1, 192, 25, 100) and coords.dtype == np.float32
        # channel 3*i + 0 is x; at elevation 0 on the two centre columns x is +-d sin(1.1 deg), logit ~ 0
        assert abs(coords[0, 0, 12, 49]) < 1e-3 and abs(coords[0, 0, 12, 50]) < 1e-3
        # z forward (channel 2 = lidar z = camera z) grows with depth: logit((d + 10) / 20) at the centre
        d0 = lid_depths()[0]
        assert coords[0, 2, 12, 49] == pytest.approx(math.log((d0 + 10) / 20 / (1 - (d0 + 10) / 20)), abs=1e-3)

    def test_points_outside_position_range_saturate(self) -> None:
        coords = position_coords(np.eye(4)[None], out_hw=(25, 100))
        assert coords.max() == pytest.approx(math.log(1 / 1e-5), abs=1e-3)  # z beyond +10 m
        assert coords.min() >= -math.log(1 / 1e-5) - 1e-3
