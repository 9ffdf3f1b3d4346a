"""``smooth_velocities``: each track's velocity re-fitted after the fact to its detections either side."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fisheye_infer import Detections, GreedyTracker, Tracker, Tracks
from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.tracking import smooth_velocities

CAR = CLASSES.index("Car")


def pose(x: float, y: float, heading: float) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[math.cos(heading), -math.sin(heading)], [math.sin(heading), math.cos(heading)]]
    m[:2, 3] = x, y
    return m


def cars(world_xy: np.ndarray, ego: np.ndarray) -> Detections:
    """Cars at world centres ``world_xy`` (N, 2), as the ego at ``ego`` detects them."""
    xyz = np.column_stack([world_xy, np.full(len(world_xy), -2.0)])
    local = (xyz - ego[:3, 3]) @ ego[:3, :3]
    boxes = np.column_stack([local, np.tile([4.5, 1.9, 1.6, 0.0], (len(local), 1))]).astype(np.float32)
    return Detections(boxes, np.full(len(boxes), 0.9, np.float32), np.full(len(boxes), CAR, np.int64), CLASSES)


def drive(tracker: Tracker | GreedyTracker, noise: float, frames: int = 30) -> tuple[list[Tracks], list[np.ndarray]]:
    """Two cars (7 m/s east, 4 m/s north) seen by an ego turning as it drives, 10 Hz, centres with noise."""
    rng = np.random.default_rng(0)
    history, poses = [], []
    for k in range(frames):
        t = 0.1 * k
        ego = pose(5.0 * t, 0.5 * t, 0.2 * t)
        world = np.array([[10 + 7.0 * t, 3.0], [-8.0, -15 + 4.0 * t]]) + rng.normal(0, noise, (2, 2))
        history.append(tracker.update(cars(world, ego), t, ego_pose=ego))
        poses.append(ego)
    return history, poses


def truth_in_ego(report: Tracks, ego: np.ndarray) -> np.ndarray:
    """The labelled velocity of each track of ``drive``, in the ego's axes (world x > 0: the car driving east)."""
    world_x = report.boxes[:, :2].astype(np.float64) @ ego[0, :2] + ego[0, 3]
    return np.where(world_x[:, None] > 0, [[7.0, 0.0]], [[0.0, 4.0]]) @ ego[:2, :2]


def test_a_straight_path_gives_its_exact_velocity_in_each_frames_axes() -> None:
    history, poses = drive(Tracker(), noise=0.0)
    smoothed = smooth_velocities(history, poses, span=0.5)
    world_v = {}
    for report, ego in zip(smoothed[5:], poses[5:]):
        assert len(report) == 2
        v_world = report.velocities.astype(np.float64) @ ego[:2, :2].T
        for i, v in zip(report.ids.tolist(), v_world):
            world_v.setdefault(i, []).append(v)
        assert report.velocity_covariances is not None
        np.testing.assert_allclose(report.velocity_covariances, 0.0, atol=1e-6)
    speeds = sorted(np.abs(np.array(v)).max(axis=0).round(3).tolist() for v in world_v.values())
    assert speeds == [[0.0, 4.0], [7.0, 0.0]]
    for v in world_v.values():
        np.testing.assert_allclose(np.array(v), np.array(v)[:1].repeat(len(v), 0), atol=1e-4)


def test_each_velocity_is_the_least_squares_slope_of_its_detections_either_side() -> None:
    """Against numpy's polyfit of the same centres: the slope, and its covariance from the residuals (both axes'
    spreads and their correlation, N - 2 degrees of freedom), turned into the frame's axes."""
    history, poses = drive(Tracker(), noise=0.3)
    smoothed = smooth_velocities(history, poses, span=1.0)
    k = 15
    track = int(history[k].ids[0])
    stamps, centres = [], []
    for report, ego in zip(history, poses):
        row = np.flatnonzero(report.ids == track)
        if len(row) and abs(report.stamp - history[k].stamp) <= 1.0 + 1e-6:
            assert report.detected_centres is not None
            local = np.append(report.detected_centres[row[0]], report.boxes[row[0], 2])
            centres.append(ego[:3, :3] @ local + ego[:3, 3])
            stamps.append(report.stamp)
    assert len(stamps) == 21
    t, xy = np.array(stamps), np.array(centres)[:, :2]
    fit = np.polyfit(t, xy, 1)
    residuals = xy - (t[:, None] * fit[0] + fit[1])
    covariance = residuals.T @ residuals / (len(t) - 2) / ((t - t.mean()) ** 2).sum()
    rotation = poses[k][:2, :2]
    np.testing.assert_allclose(smoothed[k].velocities[0], fit[0] @ rotation, atol=1e-4)
    np.testing.assert_allclose(smoothed[k].velocity_covariances[0], rotation.T @ covariance @ rotation, rtol=1e-4)
    assert not np.allclose(smoothed[k].velocities[0], history[k].velocities[0], atol=0.05)
    assert abs(covariance[0, 1]) > 1e-3  # the two axes' residuals correlate here: a pooled spread would not do


def test_a_window_closes_on_stamps_a_span_apart_within_rounding() -> None:
    """Stamps 0.1 s apart as floats sum them (0.1 + 0.2 = 0.30000000000000004): a span of 0.1 s still reaches both
    neighbours of a frame."""
    tracker, history = Tracker(), []
    for stamp in (0.0, 0.1, 0.1 + 0.2, 0.1 + 0.2 + 0.1):
        history.append(tracker.update(cars(np.array([[10 + 5.0 * stamp, 2.0]]), np.eye(4)), stamp))
    smoothed = smooth_velocities(history, span=0.2)
    np.testing.assert_allclose(smoothed[2].velocities, [[5.0, 0.0]], atol=1e-4)
    assert not np.array_equal(smoothed[2].velocities, history[2].velocities)


def test_smoothing_is_closer_to_the_truth_than_the_filter() -> None:
    history, poses = drive(Tracker(), noise=0.4, frames=40)
    smoothed = smooth_velocities(history, poses, span=1.0)
    errors = {"online": [], "smoothed": []}
    for online, after, ego in zip(history[3:], smoothed[3:], poses[3:]):
        truth = truth_in_ego(online, ego)
        errors["online"] += np.hypot(*(online.velocities - truth).T).tolist()
        errors["smoothed"] += np.hypot(*(after.velocities - truth).T).tolist()
    assert np.median(errors["smoothed"]) < 0.8 * np.median(errors["online"])


def test_the_tracker_reports_the_centres_of_the_detections_it_took() -> None:
    history, poses = drive(Tracker(), noise=0.3, frames=8)
    rng = np.random.default_rng(0)
    for k, (report, ego) in enumerate(zip(history, poses)):
        t = 0.1 * k
        world = np.array([[10 + 7.0 * t, 3.0], [-8.0, -15 + 4.0 * t]]) + rng.normal(0, 0.3, (2, 2))
        assert report.detected_centres is not None and report.detected_centres.shape == (len(report), 2)
        if len(report):
            expected = cars(world, ego).boxes[:, :2]
            np.testing.assert_allclose(np.sort(report.detected_centres, 0), np.sort(expected, 0), atol=1e-4)
            if k >= 3:  # the filter's centre has left the detection's
                assert not np.allclose(report.detected_centres, report.boxes[:, :2], atol=1e-3)


def test_frames_with_too_few_centres_in_reach_keep_the_trackers_velocity() -> None:
    history, poses = drive(Tracker(), noise=0.3, frames=12)
    smoothed = smooth_velocities(history[:4], poses[:4], span=0.1)  # within 0.1 s: at most 3 centres, at the ends 2
    first = next(k for k, r in enumerate(history[:4]) if len(r))
    np.testing.assert_array_equal(smoothed[first].velocities, history[first].velocities)
    np.testing.assert_array_equal(smoothed[first].velocity_covariances, history[first].velocity_covariances)
    middle = smoothed[first + 1]
    assert not np.array_equal(middle.velocities, history[first + 1].velocities)


def test_a_tracker_without_covariances_keeps_none() -> None:
    history, poses = drive(GreedyTracker(0.3), noise=0.3, frames=15)
    assert all(r.detected_centres is None for r in history)
    smoothed = smooth_velocities(history, poses)
    assert all(r.velocity_covariances is None for r in smoothed)
    assert not np.array_equal(smoothed[10].velocities, history[10].velocities)


def test_without_poses_tracks_are_in_one_fixed_frame() -> None:
    tracker, history = Tracker(), []
    for k in range(20):
        t = 0.1 * k
        history.append(tracker.update(cars(np.array([[10 + 6.0 * t, 2.0 - 3.0 * t]]), np.eye(4)), t))
    smoothed = smooth_velocities(history, span=0.5)
    np.testing.assert_allclose(smoothed[10].velocities, [[6.0, -3.0]], atol=1e-4)
    assert smooth_velocities([]) == []


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda h, p: smooth_velocities(h, p, span=0.0), "span: expected seconds > 0"),
        (lambda h, p: smooth_velocities(h, p, span=float("nan")), "span: expected seconds > 0"),
        (lambda h, p: smooth_velocities(h, p, span="1"), "span: expected seconds > 0"),  # type: ignore[arg-type]
        (lambda h, p: smooth_velocities(h[::-1], p[::-1]), r"history\[1\]: stamp .* must be finite and increase"),
        (lambda h, p: smooth_velocities([*h[:2], replace(h[2], stamp=math.nan)], p[:3]), "must be finite"),
        (
            lambda h, p: smooth_velocities([*h[:2], {"stamp": 1.0}], p[:3]),
            r"history\[2\]: expected a .*Tracks, got dict",
        ),
        (lambda h, p: smooth_velocities([h[0], h[1][[0, 0]]], p[:2]), r"history\[1\]: a track id appears twice"),
        (lambda h, p: smooth_velocities(h, p[:-1]), "poses: expected one per report"),
    ],
)
def test_refusals(call, message: str) -> None:  # type: ignore[no-untyped-def]
    history, poses = drive(Tracker(), noise=0.0, frames=5)
    assert len(history[1]) == 2
    with pytest.raises(ValueError, match=message):
        call(history, poses)


def test_a_pose_that_is_not_rigid_is_refused() -> None:
    history, poses = drive(Tracker(), noise=0.0, frames=5)
    poses[2] = poses[2] * 2.0
    with pytest.raises(FrameError, match="ego_pose: not a rigid transform"):
        smooth_velocities(history, poses)
