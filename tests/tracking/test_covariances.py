"""The tracks' covariances: the filter's, in the boxes' frame, in every output that carries tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer import Detections, GreedyTracker, Tracker, TrackerConfig, Tracks
from fisheye_infer.ros.autoware import tracked_objects
from fisheye_infer.ros.messages import typestore
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.tracking import TURNING_CLASSES, ConstantTurnRate, ConstantVelocity

CAR = CLASSES.index("Car")


def car(x: float, y: float, yaw: float) -> Detections:
    box = np.array([[x, y, -2.0, 4.5, 1.9, 1.6, yaw]], np.float32)
    return Detections(box, np.array([0.9], np.float32), np.array([CAR], np.int64), CLASSES)


def rotation(angle: float) -> np.ndarray:
    return np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])


def test_constant_velocity_gives_its_covariance_blocks() -> None:
    model = ConstantVelocity(position_std=0.5, accel_std=2.0, speed_std=4.0)
    x, p = model.init(np.array([[10.0, 2.0, -2.0, 4.5, 1.9, 1.6, 0.0]]))
    x, p = model.predict(x, p, 0.1)
    position, velocity = model.covariances(x, p)
    np.testing.assert_array_equal(position, p[:, :2, :2])
    np.testing.assert_array_equal(velocity, p[:, 2:4, 2:4])


@pytest.mark.parametrize(("speed", "within"), [(8.0, 0.01), (0.0, 0.1)])
def test_turning_model_velocity_covariance_is_the_velocitys_spread(speed: float, within: float) -> None:
    """Against the velocities of states drawn from the filter's Gaussian: a moving track (first order holds), and a
    standing one (the heading's spread scaled by the speed's root mean square; within 10 %, the heading and the speed
    correlated)."""
    model = ConstantTurnRate(position_std=0.4, speed_std=3.0, yaw_std=0.2)
    x = np.array([[5.0, -3.0, 0.7, speed, 0.1]])
    p = np.diag([0.2, 0.3, 0.01, 0.25, 0.02])[None]
    p[0, 2, 3] = p[0, 3, 2] = 0.02
    drawn = np.random.default_rng(0).multivariate_normal(x[0], p[0], 400_000)
    _, velocity = model.covariances(x, p)
    spread = np.cov(model.velocity(drawn).T)
    np.testing.assert_allclose(velocity[0], spread, rtol=0, atol=within * np.trace(spread))
    assert np.all(np.linalg.eigvalsh(velocity[0]) > 0.5 * np.linalg.eigvalsh(spread)[0])


def test_a_tracks_velocity_becomes_certain_as_it_is_seen() -> None:
    tracker = Tracker()
    traces = []
    for k in range(12):
        tracks = tracker.update(car(20.0 + 1.0 * k, 3.0, 0.0), 0.1 * k)
        assert tracks.velocity_covariances is not None and tracks.position_covariances is not None
        traces.append(float(np.trace(tracks.velocity_covariances[0])))
        np.testing.assert_allclose(tracks.velocity_covariances[0], tracks.velocity_covariances[0].T)
        assert np.all(np.linalg.eigvalsh(tracks.position_covariances[0]) > 0)
    speed_std = TrackerConfig().for_class("Car").model.speed_std
    assert traces[0] == pytest.approx(2 * speed_std**2, rel=1e-6)  # a new track: its velocity is unknown
    assert all(later < earlier for earlier, later in zip(traces[:-1], traces[1:]))
    assert traces[-1] < 0.1 * traces[0]


def test_covariances_turn_with_the_ego_frame() -> None:
    """A car driving across the world, seen from two egos standing still at the same place but facing 30 degrees
    apart: the same tracks, each reported in its own ego's axes."""
    config = TrackerConfig(classes=TURNING_CLASSES)  # heading-dependent (anisotropic) velocity covariances
    out = {}
    for facing in (0.0, math.pi / 6):
        tracker, pose = Tracker(config), np.eye(4)
        pose[:2, :2] = rotation(facing)
        for k in range(8):
            world = np.array([10.0 + 1.2 * k, 5.0 + 0.4 * k])
            ego = rotation(facing).T @ world
            tracks = tracker.update(car(*ego, math.atan2(0.4, 1.2) - facing), 0.1 * k, ego_pose=pose)
        out[facing] = tracks
    turn = rotation(math.pi / 6)
    for name in ("position_covariances", "velocity_covariances"):
        seen_ahead, seen_turned = getattr(out[0.0], name)[0], getattr(out[math.pi / 6], name)[0]
        assert abs(seen_ahead[0, 1]) > 1e-4  # not a multiple of the identity, so the turn shows
        np.testing.assert_allclose(seen_turned, turn.T @ seen_ahead @ turn, rtol=1e-4, atol=1e-7)


def test_selection_and_shapes() -> None:
    tracker = Tracker()
    tracker.update(car(10.0, 0.0, 0.0), 0.0)
    tracks = tracker.update(car(10.5, 0.0, 0.0), 0.1)
    assert tracks[np.array([True])].velocity_covariances.shape == (1, 2, 2)  # type: ignore[union-attr]
    assert tracks[0:0].position_covariances.shape == (0, 2, 2)  # type: ignore[union-attr]
    empty = tracker.update(Detections.empty(CLASSES), 0.2, degraded=True)
    assert len(empty) == 0 and empty.velocity_covariances is not None and empty.velocity_covariances.shape == (0, 2, 2)
    with pytest.raises(ValueError, match="velocity_covariances"):
        Tracks(tracks.ids, tracks.boxes, tracks.velocities, tracks.scores, tracks.labels, tracks.ages,
               CLASSES, 0.1, tracks.position_covariances, np.zeros((1, 2)))  # fmt: skip
    record = tracks.to_dicts()[0]
    np.testing.assert_allclose(record["velocity_covariance"], tracks.velocity_covariances[0], rtol=1e-6)  # type: ignore[index]
    greedy = GreedyTracker().update(car(10.0, 0.0, 0.0), 0.0)
    assert greedy.velocity_covariances is None and greedy.to_dicts()[0]["velocity_covariance"] is None


def test_autoware_covariances_in_the_box_axes() -> None:
    tracker = Tracker(TrackerConfig(classes=TURNING_CLASSES))
    for k in range(6):
        tracks = tracker.update(car(15.0 + 0.8 * k, 2.0 + 0.6 * k, math.atan2(0.6, 0.8)), 0.1 * k)
    message = tracked_objects(tracks, 1_000_000_000, "base_link", typestore())
    kinematics = message.objects[0].kinematics
    pose_cov = np.asarray(kinematics.pose_with_covariance.covariance).reshape(6, 6)
    twist_cov = np.asarray(kinematics.twist_with_covariance.covariance).reshape(6, 6)
    assert tracks.position_covariances is not None and tracks.velocity_covariances is not None
    np.testing.assert_allclose(pose_cov[:2, :2], tracks.position_covariances[0], rtol=1e-6)
    to_box = rotation(-float(tracks.boxes[0, 6]))
    np.testing.assert_allclose(twist_cov[:2, :2], to_box @ tracks.velocity_covariances[0] @ to_box.T, rtol=1e-5)
    assert twist_cov[0, 0] > twist_cov[1, 1]  # the turning model is surer of the heading than of the speed
    assert not pose_cov[2:].any() and not twist_cov[2:].any()
