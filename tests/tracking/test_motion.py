"""The motion models against predictions and updates worked out by hand (one track: arrays of n = 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer.tracking.motion import ConstantTurnRate, ConstantVelocity, wrap_angle


def test_constant_velocity_prediction_and_covariance_by_hand() -> None:
    cv = ConstantVelocity(position_std=0.5, accel_std=2.0, speed_std=3.0)
    x = np.array([[1.0, 2.0, 3.0, -1.0]])
    p = np.diag([0.25, 0.25, 9.0, 9.0])[None]
    x1, p1 = cv.predict(x, p, 0.5)
    x1, p1 = x1[0], p1[0]
    np.testing.assert_allclose(x1, [2.5, 1.5, 3.0, -1.0])
    # P' = F P F^T + q G G^T per axis: var x = 0.25 + 0.25 * 9 + 4 * 0.5^4 / 4; cov x,vx = 0.5 * 9 + 4 * 0.5^3 / 2
    np.testing.assert_allclose(p1[0, 0], 0.25 + 2.25 + 0.0625)
    np.testing.assert_allclose(p1[0, 2], 4.5 + 0.25)
    np.testing.assert_allclose(p1[2, 2], 9.0 + 1.0)
    assert p1[0, 1] == 0.0


def test_constant_velocity_update_is_the_scalar_kalman_gain() -> None:
    cv = ConstantVelocity(position_std=1.0)
    x, p = np.zeros((1, 4)), np.diag([3.0, 3.0, 1.0, 1.0])[None]
    x1, p1 = cv.update(x, p, np.array([[4.0, -2.0, 0, 1, 1, 1, 0]]))
    x1, p1 = x1[0], p1[0]
    # gain 3 / (3 + 1) on the position, none on the (uncorrelated) velocity
    np.testing.assert_allclose(x1, [3.0, -1.5, 0.0, 0.0])
    np.testing.assert_allclose(np.diag(p1), [0.75, 0.75, 1.0, 1.0])


def test_turn_rate_moves_on_the_circle() -> None:
    ctrv = ConstantTurnRate()
    v, w, dt = 10.0, 0.5, 1.0
    x1, _ = ctrv.predict(np.array([[0.0, 0.0, 0.0, v, w]]), np.eye(5)[None], dt)
    radius = v / w
    np.testing.assert_allclose(x1[0, :3], [radius * math.sin(w * dt), radius * (1 - math.cos(w * dt)), w * dt])
    np.testing.assert_allclose(ctrv.velocity(x1)[0], [v * math.cos(0.5), v * math.sin(0.5)])


def test_turn_rate_jacobian_matches_finite_differences() -> None:
    ctrv = ConstantTurnRate(accel_std=0.0, turn_accel_std=0.0)
    states = np.array([[1.0, -2.0, 0.3, 7.0, 0.4], [1.0, -2.0, 0.3, 7.0, 0.0]])  # turning and straight, at once
    _, p1 = ctrv.predict(states, np.repeat(np.eye(5)[None], 2, 0), 0.2)
    for x, p in zip(states, p1):
        jac = np.zeros((5, 5))
        for k in range(5):
            e = np.zeros(5)
            e[k] = 1e-6
            step = lambda s: ctrv.predict(s[None], np.eye(5)[None], 0.2)[0][0]
            jac[:, k] = (step(x + e) - step(x - e)) / 2e-6
        np.testing.assert_allclose(p, jac @ jac.T, atol=1e-5)


def test_turn_rate_takes_the_box_yaw_up_to_a_half_turn() -> None:
    ctrv = ConstantTurnRate(yaw_std=0.1)
    x, p = ctrv.init(np.array([[0, 0, 0, 4, 2, 1.5, 0.1]]))
    box = np.array([[0, 0, 0, 4, 2, 1.5, 0.1 + math.pi + 0.05]])  # the same heading, other end first
    x1, _ = ctrv.update(x, p, box)
    assert abs(x1[0, 2] - 0.1) < 0.05


def test_still_is_the_chi_square_test_of_the_velocity() -> None:
    # constant velocity: 2 degrees of freedom, 95 % at 5.99; velocity covariance diag(1, 4)
    p = np.diag([0.1, 0.1, 1.0, 4.0])[None].repeat(3, 0)
    x = np.array([[0, 0, 2.0, 0.0], [0, 0, 0.0, 4.8], [0, 0, 2.0, 2.0]])  # lengths 4, 5.76, 5
    np.testing.assert_array_equal(ConstantVelocity().still(x, p, 0.95), [True, True, True])
    x[:, 2] = [2.5, 1.0, 2.1]  # lengths 6.25, 6.01, 5.41
    np.testing.assert_array_equal(ConstantVelocity().still(x, p, 0.95), [False, False, True])
    # turn rate: the speed alone, 1 degree of freedom, 95 % at 3.84; speed variance 4
    xs = np.array([[0, 0, 0.3, 3.9, 0.0], [0, 0, 0.3, -4.0, 0.0]])  # lengths 3.80, 4.0
    ps = np.diag([0.1, 0.1, 0.1, 4.0, 0.1])[None].repeat(2, 0)
    np.testing.assert_array_equal(ConstantTurnRate().still(xs, ps, 0.95), [True, False])


def test_track_velocity_converges_on_a_straight_drive() -> None:
    ctrv = ConstantTurnRate()
    x, p = ctrv.init(np.array([[0, 0, 0, 4.5, 1.9, 1.6, 0.0]]))
    for k in range(1, 20):
        x, p = ctrv.predict(x, p, 0.1)
        x, p = ctrv.update(x, p, np.array([[1.2 * k, 0, 0, 4.5, 1.9, 1.6, 0.0]]))
    np.testing.assert_allclose(ctrv.velocity(x)[0], [12.0, 0.0], atol=0.2)


@pytest.mark.parametrize(
    "a, expected", [(0.0, 0.0), (math.pi, -math.pi), (3 * math.pi / 2, -math.pi / 2), (-7.0, -7.0 + 2 * math.pi)]
)
def test_wrap_angle(a: float, expected: float) -> None:
    assert float(wrap_angle(a)) == pytest.approx(expected)
