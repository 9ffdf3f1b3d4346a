"""The tracks picture: paths kept in the world frame and drawn in the ego frame, velocity arrows where they belong."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer import Detections, Tracks
from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.tools.track_viz import ARROW_S, TrackPaths, draw_tracks
from fisheye_infer.tools.viz import bev_pixels, class_colour, draw_detections

CAR = CLASSES.index("Car")
ARROW = (40, 40, 40)


def car(x: float, y: float, v: tuple[float, float], track_id: int = 7) -> Tracks:
    return Tracks(
        np.array([track_id]), np.array([[x, y, -2.0, 4.5, 1.9, 1.6, 0.0]], np.float32),
        np.array([v], np.float32), np.array([0.9], np.float32), np.array([CAR]), np.array([3]), CLASSES,
    )  # fmt: skip


def pose(x: float, y: float, yaw: float) -> np.ndarray:
    m = np.eye(4)
    m[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    m[:2, 3] = x, y
    return m


def test_paths_are_kept_in_the_world_and_drawn_in_the_ego_frame_of_the_last_pose() -> None:
    paths = TrackPaths(points=2)
    # a parked car at world (20, 5) seen from an ego that drives and turns a quarter turn
    for ego in (pose(0, 0, 0), pose(5, 0, 0), pose(10, 0, math.pi / 2)):
        local = np.linalg.inv(ego) @ [20.0, 5.0, 0.0, 1.0]
        paths.add(car(local[0], local[1], (0, 0)), ego)
    # two points kept; world (20, 5) from (10, 0) facing +y: 5 m ahead, 10 m to the right
    np.testing.assert_allclose(paths.in_ego(pose(10, 0, math.pi / 2))[7], [[5, -10], [5, -10]], atol=1e-5)
    np.testing.assert_allclose(paths.in_ego()[7], [[20, 5], [20, 5]], atol=1e-5)


def test_the_arrow_spans_a_second_of_motion_and_the_path_is_in_the_class_colour() -> None:
    rig = default_rig()
    tracks = car(10.0, 0.0, (6.0, 0.0))
    picture = draw_tracks(tracks, rig, paths={7: np.array([[0.0, -20.0], [0.0, -30.0]])}, tile=200)
    assert picture.shape == draw_detections(Detections.empty(CLASSES), rig, tile=200).shape
    size = picture.shape[0]
    bev = picture[:, -size:]
    ahead = np.round(bev_pixels(10.0 + 0.8 * 6.0 * ARROW_S, 0.0, size)).astype(int)  # on the arrow, past the box
    beyond = np.round(bev_pixels(10.0 + 1.3 * 6.0 * ARROW_S, 0.0, size)).astype(int)
    on_path = np.round(bev_pixels(0.0, -25.0, size)).astype(int)
    assert tuple(bev[ahead[1], ahead[0]]) == ARROW
    assert tuple(bev[beyond[1], beyond[0]]) != ARROW
    assert np.abs(bev[on_path[1], on_path[0]].astype(int) - class_colour("Car")).max() < 40  # antialiased
    still = draw_tracks(car(10.0, 0.0, (0.0, 0.0)), rig, tile=200)[:, -size:]
    assert tuple(still[ahead[1], ahead[0]]) != ARROW


def test_labels_must_name_every_box() -> None:
    with pytest.raises(ValueError, match="one per box"):
        draw_detections(Detections.empty(CLASSES), default_rig(), labels=["x"])
