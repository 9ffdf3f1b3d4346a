"""Motion models of the tracker: a Kalman filter per track on the bird's-eye-view centre, per class.

    cv = ConstantVelocity(position_std=0.5, accel_std=2.0)
    x, p = cv.init(boxes)                  # states (n, 4) and covariances (n, 4, 4) from boxes (n, 7)
    x, p = cv.predict(x, p, dt=0.1)        # all n tracks at once
    x, p = cv.update(x, p, boxes)          # the matched boxes' centres (and yaws, for the turning model)
    cv.still(x, p, level=0.95)             # (n,) bool: velocity within the 95 % confidence region of zero
    cv.covariances(x, p)                   # (n, 2, 2) of each centre and (n, 2, 2) of each velocity

``ConstantVelocity`` (pedestrians): state ``x, y, vx, vy``, linear, white-noise acceleration.
``ConstantTurnRate`` (vehicles, cyclists; CTRV): state ``x, y, heading, speed, turn rate``, an
extended Kalman filter; the box's yaw measures the heading up to a half turn (a box does not say
which end is its front, so the speed may come out negative). Both keep float64 numpy arrays; the
rest of a box (height, size, yaw) is smoothed by the track, not the filter. Every method works on
n tracks at once (the tracker's per-frame cost is a few array operations, not one filter per track).
``still`` tells which tracks' velocity cannot be told from zero (the tracker reports those of classes
that park as standing still).
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
    """Kalman update of n states (n, d), (n, d, d) with innovations (n, m), measurement matrix ``h`` (m, d) and noise
    ``r`` (m, m), in Joseph form."""
    ph = p @ h.T  # (n, d, m)
    s = h @ ph + r  # (n, m, m)
    k = np.linalg.solve(s, ph.transpose(0, 2, 1)).transpose(0, 2, 1)  # (n, d, m); s is symmetric
    i_kh = np.eye(x.shape[1]) - k @ h
    x = x + np.einsum("ndm,nm->nd", k, residual)
    return x, i_kh @ p @ i_kh.transpose(0, 2, 1) + k @ r @ k.transpose(0, 2, 1)


@dataclass(frozen=True)
class MotionModel:
    """Base of the motion models: measurement noise of the centre, process noise, the initial speed spread.

    Each method takes n tracks at once: states `(n, d)`, covariances `(n, d, d)`, boxes `(n, 7)` in the
    runtime layout. A model is a frozen dataclass, so one instance serves many classes.

    Args:
        position_std (float): Standard deviation of a detected centre, metres.
        accel_std (float): Standard deviation of the (white-noise) acceleration, m/s^2.
        speed_std (float): Standard deviation of the speed of a new track, m/s.
    """

    position_std: float = 0.5
    accel_std: float = 2.0
    speed_std: float = 10.0

    def init(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states of new tracks started from boxes.

        Args:
            boxes (np.ndarray): `(n, 7)` boxes ``x, y, z_bottom, l, w, h, yaw``.

        Returns:
            tuple[np.ndarray, np.ndarray]: States `(n, d)` and covariances `(n, d, d)`, float64.
        """
        raise NotImplementedError

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The states ``dt`` seconds later.

        Args:
            x (np.ndarray): States `(n, d)`.
            p (np.ndarray): Covariances `(n, d, d)`.
            dt (float): Time step, seconds.

        Returns:
            tuple[np.ndarray, np.ndarray]: Predicted states and covariances.
        """
        raise NotImplementedError

    def update(self, x: np.ndarray, p: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states corrected by one matched box each (Kalman update).

        Args:
            x (np.ndarray): States `(n, d)`.
            p (np.ndarray): Covariances `(n, d, d)`.
            boxes (np.ndarray): `(n, 7)` matched boxes, row i for track i.

        Returns:
            tuple[np.ndarray, np.ndarray]: Corrected states and covariances.
        """
        raise NotImplementedError

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        """The velocities of states.

        Args:
            x (np.ndarray): States `(n, d)`.

        Returns:
            np.ndarray: `(n, 2)` velocities over ground, m/s.
        """
        raise NotImplementedError

    def covariances(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The covariances of each state's centre and of its velocity over ground.

        Args:
            x (np.ndarray): States `(n, d)`.
            p (np.ndarray): Covariances `(n, d, d)`.

        Returns:
            tuple[np.ndarray, np.ndarray]: `(n, 2, 2)` of the centre (m^2) and `(n, 2, 2)` of the velocity
                ((m/s)^2), in the tracking frame's axes.
        """
        return p[:, :2, :2].copy(), self._velocity_covariance(x, p)

    def _velocity_covariance(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def still(self, x: np.ndarray, p: np.ndarray, level: float) -> np.ndarray:
        """Which states' velocity cannot be told from zero: inside the ``level`` confidence region of their
        estimate (chi-square test on the velocity's Mahalanobis length).

        Args:
            x (np.ndarray): States `(n, d)`.
            p (np.ndarray): Covariances `(n, d, d)`.
            level (float): Confidence level in (0, 1), e.g. 0.95.

        Returns:
            np.ndarray: `(n,)` bool, True where zero lies within the velocity's confidence region.
        """
        from scipy.special import chdtri

        length, dof = self._velocity_test(x, p)
        return np.asarray(length < chdtri(dof, 1.0 - level), bool)

    def _velocity_test(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, int]:
        """`(n,)` squared Mahalanobis length of each state's velocity, and its degrees of freedom."""
        raise NotImplementedError


@dataclass(frozen=True)
class ConstantVelocity(MotionModel):
    """State ``x, y, vx, vy``; a linear Kalman filter with white-noise acceleration.

    Args:
        position_std (float): Standard deviation of a detected centre, metres.
        accel_std (float): Standard deviation of the (white-noise) acceleration, m/s^2.
        speed_std (float): Standard deviation of the speed of a new track, m/s.
    """

    def init(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States ``x, y, vx, vy`` of new tracks at the boxes' centres, velocity 0.

        Args:
            boxes (np.ndarray): `(n, 7)` boxes ``x, y, z_bottom, l, w, h, yaw``.

        Returns:
            tuple[np.ndarray, np.ndarray]: States `(n, 4)` and covariances `(n, 4, 4)`, float64.
        """
        b = np.asarray(boxes, np.float64).reshape(-1, 7)
        x = np.zeros((len(b), 4))
        x[:, :2] = b[:, :2]
        p = np.diag([self.position_std**2] * 2 + [self.speed_std**2] * 2)
        return x, np.repeat(p[None], len(b), 0)

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The states ``dt`` seconds later, moving at constant velocity.

        Args:
            x (np.ndarray): States `(n, 4)`.
            p (np.ndarray): Covariances `(n, 4, 4)`.
            dt (float): Time step, seconds.

        Returns:
            tuple[np.ndarray, np.ndarray]: Predicted states and covariances.
        """
        f = np.eye(4)
        f[0, 2] = f[1, 3] = dt
        g = np.array([[dt * dt / 2, 0], [0, dt * dt / 2], [dt, 0], [0, dt]])
        q = self.accel_std**2 * g @ g.T
        return x @ f.T, f @ p @ f.T + q

    def update(self, x: np.ndarray, p: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states corrected by the matched boxes' centres.

        Args:
            x (np.ndarray): States `(n, 4)`.
            p (np.ndarray): Covariances `(n, 4, 4)`.
            boxes (np.ndarray): `(n, 7)` matched boxes, row i for track i.

        Returns:
            tuple[np.ndarray, np.ndarray]: Corrected states and covariances.
        """
        h = np.zeros((2, 4))
        h[0, 0] = h[1, 1] = 1.0
        r = np.eye(2) * self.position_std**2
        return _kalman_update(x, p, np.asarray(boxes, np.float64)[:, :2] - x[:, :2], h, r)

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        """The velocities of states.

        Args:
            x (np.ndarray): States `(n, 4)`.

        Returns:
            np.ndarray: `(n, 2)` velocities over ground, m/s.
        """
        return x[:, 2:4].copy()

    def _velocity_covariance(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        return p[:, 2:4, 2:4].copy()

    def _velocity_test(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, int]:
        v = x[:, 2:4]
        return np.einsum("ni,ni->n", v, np.linalg.solve(p[:, 2:4, 2:4], v[..., None])[..., 0]), 2


@dataclass(frozen=True)
class ConstantTurnRate(MotionModel):
    """State ``x, y, heading, speed, turn rate`` (CTRV); an extended Kalman filter.

    Args:
        position_std (float): Standard deviation of a detected centre, metres.
        accel_std (float): Standard deviation of the (white-noise) acceleration, m/s^2.
        speed_std (float): Standard deviation of the speed of a new track, m/s.
        yaw_std (float): Standard deviation of a detected yaw, radians.
        turn_accel_std (float): Standard deviation of the turn rate's change, rad/s^2.
        turn_std (float): Standard deviation of the turn rate of a new track, rad/s.
    """

    yaw_std: float = 0.2
    turn_accel_std: float = 0.5
    turn_std: float = 0.3

    def init(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States ``x, y, heading, speed, turn rate`` of new tracks: heading from the yaw, speed and turn rate 0.

        Args:
            boxes (np.ndarray): `(n, 7)` boxes ``x, y, z_bottom, l, w, h, yaw``.

        Returns:
            tuple[np.ndarray, np.ndarray]: States `(n, 5)` and covariances `(n, 5, 5)`, float64.
        """
        b = np.asarray(boxes, np.float64).reshape(-1, 7)
        x = np.zeros((len(b), 5))
        x[:, :3] = b[:, [0, 1, 6]]
        stds = [self.position_std, self.position_std, self.yaw_std, self.speed_std, self.turn_std]
        return x, np.repeat(np.diag(np.square(stds))[None], len(b), 0)

    def predict(self, x: np.ndarray, p: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """The states ``dt`` seconds later, moving along a circle arc (first order in the turn rate near 0).

        Args:
            x (np.ndarray): States `(n, 5)`.
            p (np.ndarray): Covariances `(n, 5, 5)`.
            dt (float): Time step, seconds.

        Returns:
            tuple[np.ndarray, np.ndarray]: Predicted states and covariances.
        """
        px, py, th, v, w = x.T
        s0, c0 = np.sin(th), np.cos(th)
        straight = np.abs(w) < _STRAIGHT
        ws = np.where(straight, 1.0, w)  # a safe divisor; the straight rows take the other branch
        s1, c1 = np.sin(th + w * dt), np.cos(th + w * dt)
        bend = w * dt * dt / 2  # the turn's first-order effect, so that the step is smooth in w
        new = np.empty_like(x)
        new[:, 0] = np.where(straight, px + v * (c0 * dt - s0 * bend), px + v / ws * (s1 - s0))
        new[:, 1] = np.where(straight, py + v * (s0 * dt + c0 * bend), py + v / ws * (c0 - c1))
        new[:, 2] = wrap_angle(th + w * dt)
        new[:, 3], new[:, 4] = v, w
        f = np.repeat(np.eye(5)[None], len(x), 0)
        f[:, 0, 2] = np.where(straight, -v * s0 * dt, v / ws * (c1 - c0))
        f[:, 0, 3] = np.where(straight, c0 * dt, (s1 - s0) / ws)
        f[:, 0, 4] = np.where(straight, -v * s0 * dt * dt / 2, v / (ws * ws) * (s0 - s1) + v * dt * c1 / ws)
        f[:, 1, 2] = np.where(straight, v * c0 * dt, v / ws * (s1 - s0))
        f[:, 1, 3] = np.where(straight, s0 * dt, (c0 - c1) / ws)
        f[:, 1, 4] = np.where(straight, v * c0 * dt * dt / 2, v / (ws * ws) * (c1 - c0) + v * dt * s1 / ws)
        f[:, 2, 4] = dt
        g = np.zeros((len(x), 5, 2))
        g[:, 0, 0], g[:, 1, 0], g[:, 2, 1], g[:, 3, 0], g[:, 4, 1] = (
            dt * dt / 2 * c0,
            dt * dt / 2 * s0,
            dt * dt / 2,
            dt,
            dt,
        )
        q = g @ np.diag([self.accel_std**2, self.turn_accel_std**2]) @ g.transpose(0, 2, 1)
        return new, f @ p @ f.transpose(0, 2, 1) + q

    def update(self, x: np.ndarray, p: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The states corrected by the matched boxes' centres and yaws (the yaw up to a half turn).

        Args:
            x (np.ndarray): States `(n, 5)`.
            p (np.ndarray): Covariances `(n, 5, 5)`.
            boxes (np.ndarray): `(n, 7)` matched boxes, row i for track i.

        Returns:
            tuple[np.ndarray, np.ndarray]: Corrected states and covariances.
        """
        b = np.asarray(boxes, np.float64)
        h = np.zeros((3, 5))
        h[0, 0] = h[1, 1] = h[2, 2] = 1.0
        r = np.diag([self.position_std**2, self.position_std**2, self.yaw_std**2])
        residual = np.column_stack([b[:, 0] - x[:, 0], b[:, 1] - x[:, 1], wrap_angle(b[:, 6] - x[:, 2], math.pi)])
        new, p = _kalman_update(x, p, residual, h, r)
        new[:, 2] = wrap_angle(new[:, 2])
        return new, p

    @staticmethod
    def velocity(x: np.ndarray) -> np.ndarray:
        """The velocities of states: speed along the heading.

        Args:
            x (np.ndarray): States `(n, 5)`.

        Returns:
            np.ndarray: `(n, 2)` velocities over ground, m/s.
        """
        return x[:, 3:4] * np.column_stack([np.cos(x[:, 2]), np.sin(x[:, 2])])

    def _velocity_covariance(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        # v = speed * (cos heading, sin heading), to first order in the heading and the speed, the heading's spread
        # scaled by the root mean square speed (a standing track is unsure across its heading too)
        c, s = np.cos(x[:, 2]), np.sin(x[:, 2])
        rms = np.sqrt(x[:, 3] ** 2 + p[:, 3, 3])
        j = np.stack([np.column_stack([-rms * s, c]), np.column_stack([rms * c, s])], axis=1)  # (n, 2, 2)
        return j @ p[:, 2:4, 2:4] @ j.transpose(0, 2, 1)

    def _velocity_test(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, int]:
        return x[:, 3] ** 2 / p[:, 3, 3], 1
