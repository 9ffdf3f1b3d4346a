"""Motion models of the tracker: a Kalman filter per track on the bird's-eye-view centre, per class.

    cv = ConstantVelocity(position_std=0.5, accel_std=2.0)
    x, p = cv.init(box)                    # state and covariance from a first box (x, y, z, l, w, h, yaw)
    x, p = cv.predict(x, p, dt=0.1)
    x, p = cv.update(x, p, box)            # the matched box's centre (and yaw, for the turning model)

``ConstantVelocity`` (pedestrians): state ``x, y, vx, vy``, linear, white-noise acceleration.
``ConstantTurnRate`` (vehicles, cyclists; CTRV): state ``x, y, heading, speed, turn rate``, an
extended Kalman filter; the box's yaw measures the heading up to a half turn (a box does not say
which end is its front, so the speed may come out negative). Both keep float64 numpy arrays; the
rest of a box (height, size, yaw) is smoothed by the track, not the filter.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["MotionModel", "ConstantVelocity", "ConstantTurnRate", "wrap_angle"]

_STRAIGHT = 1e-4  # below this turn rate (rad/s) a step is expanded to first order in it


def wrap_angle(a: np.ndarray | float, period: float = 2 * math.pi) -> np.ndarray:
    """``a`` wrapped into [-period/2, period/2)."""
    return (np.asarray(a, np.float64) + period / 2) % period - period / 2


def _kalman_update(
    x: np.ndarray, p: np.ndarray, residual: np.ndarray, h: np.ndarray, r: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update with innovation ``residual``, measurement matrix ``h`` and noise ``r`` (Joseph form)."""
    s = h @ p @ h.T + r
    k = np.linalg.solve(s, h @ p).T
    i_kh = np.eye(len(x)) - k @ h
    return x + k @ residual, i_kh @ p @ i_kh.T + k @ r @ k.T


@dataclass(frozen=True)
class MotionModel:
    """What every model shares: measurement noise of the centre, process noise, the initial speed spread.

    Args:
        position_std (float): Standard deviation of a detected centre, metres.
        accel_std (float): Standard deviation of the (white-noise) acceleration, m/s^2.
        speed_std (float): Standard deviation of the speed of a new track, m/s.
    """

    position_std: float = 0.5
    accel_std: float = 2.0
    speed_std: float = 10.0

    def init(self, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    def update(self, x: np.ndarray, p: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        raise NotImplementedError

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        """(2,) velocity over ground, m/s."""
        raise NotImplementedError


@dataclass(frozen=True)
class ConstantVelocity(MotionModel):
    """State ``x, y, vx, vy``; a linear Kalman filter with white-noise acceleration."""

    def init(self, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.array([box[0], box[1], 0.0, 0.0], np.float64)
        return x, np.diag([self.position_std**2] * 2 + [self.speed_std**2] * 2)

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        g = np.array([[dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
        q = self.accel_std**2 * g @ g.T
        return f @ x, f @ p @ f.T + q

    def update(self, x: np.ndarray, p: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        r = np.eye(2) * self.position_std**2
        return _kalman_update(x, p, np.asarray(box[:2], np.float64) - x[:2], h, r)

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        return x[2:4].copy()


@dataclass(frozen=True)
class ConstantTurnRate(MotionModel):
    """State ``x, y, heading, speed, turn rate`` (CTRV); an extended Kalman filter.

    Args:
        yaw_std (float): Standard deviation of a detected yaw, radians.
        turn_accel_std (float): Standard deviation of the turn rate's change, rad/s^2.
        turn_std (float): Standard deviation of the turn rate of a new track, rad/s.
    """

    yaw_std: float = 0.2
    turn_accel_std: float = 0.5
    turn_std: float = 0.3

    def init(self, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.array([box[0], box[1], box[6], 0.0, 0.0], np.float64)
        stds = [self.position_std, self.position_std, self.yaw_std, self.speed_std, self.turn_std]
        return x, np.diag(np.square(stds))

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        px, py, th, v, w = x
        s0, c0 = math.sin(th), math.cos(th)
        f = np.eye(5)
        if abs(w) < _STRAIGHT:
            bend = w * dt * dt / 2  # the turn's first-order effect, so that the step is smooth in w
            new = np.array([px + v * (c0 * dt - s0 * bend), py + v * (s0 * dt + c0 * bend), th + w * dt, v, w])
            f[0, 2], f[0, 3], f[0, 4] = -v * s0 * dt, c0 * dt, -v * s0 * dt * dt / 2
            f[1, 2], f[1, 3], f[1, 4] = v * c0 * dt, s0 * dt, v * c0 * dt * dt / 2
        else:
            s1, c1 = math.sin(th + w * dt), math.cos(th + w * dt)
            new = np.array([px + v / w * (s1 - s0), py + v / w * (c0 - c1), th + w * dt, v, w])
            f[0, 2], f[0, 3] = v / w * (c1 - c0), (s1 - s0) / w
            f[0, 4] = v / (w * w) * (s0 - s1) + v * dt * c1 / w
            f[1, 2], f[1, 3] = v / w * (s1 - s0), (c0 - c1) / w
            f[1, 4] = v / (w * w) * (c1 - c0) + v * dt * s1 / w
        f[2, 4] = dt
        g = np.array([[dt * dt / 2 * c0, 0], [dt * dt / 2 * s0, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
        q = g @ np.diag([self.accel_std**2, self.turn_accel_std**2]) @ g.T
        new[2] = float(wrap_angle(new[2]))
        return new, f @ p @ f.T + q

    def update(self, x: np.ndarray, p: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = np.zeros((3, 5))
        h[0, 0] = h[1, 1] = h[2, 2] = 1.0
        r = np.diag([self.position_std**2, self.position_std**2, self.yaw_std**2])
        residual = np.array([box[0] - x[0], box[1] - x[1], float(wrap_angle(box[6] - x[2], math.pi))])
        new, p = _kalman_update(x, p, residual, h, r)
        new[2] = float(wrap_angle(new[2]))
        return new, p

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        return np.array([x[3] * math.cos(x[2]), x[3] * math.sin(x[2])])
