"""Objects that move as their class moves, and the ego vehicle's drive, simulated in a flat world frame.

    states = simulate_actors(rng, labels, sizes, start_xy, length, dt)     # (T, N, 5) x, y, heading, speed, turn rate

Vehicles (Car, Van, Truck, Bus) drive smooth paths: the speed follows a target drawn in 0-15 m/s (a
quarter of them parked at 0) with bounded acceleration and braking, the curvature wanders and
returns to straight, limited by the class's turning circle and by a lateral acceleration of 3 m/s^2.
Cyclists ride at 2-6 m/s with livelier steering; pedestrians walk at 0.5-1.8 m/s, turn at random and
stop now and then. A vehicle or cyclist that would come within 0.5 m of another actor in the next 1.5 s
(both keeping their motion) brakes at 6 m/s^2, at 10 m/s^2 when it is a step away (boxes may then touch);
a pedestrian stops. Everything is
drawn from the caller's seeded generator, in a fixed order, so a seed gives the same paths.
"""

from __future__ import annotations

import math

import numpy as np

from fisheye_infer.runtime.records import CLASSES

__all__ = ["simulate_actors", "simulate_ego", "VEHICLES"]

VEHICLES = ("Car", "Van", "Truck", "Bus")
#: Largest curvature (1 / turning radius, 1/m) per class.
_MAX_CURVATURE = {"Car": 0.15, "Van": 0.12, "Truck": 0.08, "Bus": 0.06, "Cyclist": 0.4, "Pedestrian": 2.0}
_LATERAL = {"Cyclist": 2.0}  # m/s^2; vehicles 3
_CYCLIST, _PEDESTRIAN = CLASSES.index("Cyclist"), CLASSES.index("Pedestrian")


def _targets(rng: np.random.Generator, labels: np.ndarray) -> np.ndarray:
    """A target speed per actor for its class (m/s)."""
    out = np.zeros(len(labels))
    for i, label in enumerate(labels.tolist()):
        if label == _PEDESTRIAN:
            out[i] = rng.uniform(0.5, 1.8)
        elif label == _CYCLIST:
            out[i] = rng.uniform(2.0, 6.0)
        else:
            out[i] = 0.0 if rng.uniform() < 0.25 else rng.uniform(3.0, 15.0)
    return out


def _blocked(i: int, mine: np.ndarray, others: np.ndarray, xy: np.ndarray, radii: np.ndarray) -> bool:
    """Whether actor ``i`` at ``mine`` comes within 0.5 m of another actor (at ``others``, one row per actor) while
    closing in on it from where both are now (``xy``)."""
    rest = np.arange(len(xy)) != i
    now, then = np.hypot(*(xy[i] - xy[rest]).T), np.hypot(*(mine - others[rest]).T)
    return bool(np.any((then - radii[i] - radii[rest] < 0.5) & (then < now)))


def simulate_actors(
    rng: np.random.Generator, labels: np.ndarray, radii: np.ndarray, start: np.ndarray, length: int, dt: float
) -> np.ndarray:
    """Paths of ``len(labels)`` actors over ``length`` steps of ``dt`` seconds.

    Args:
        rng (np.random.Generator): The sequence's generator.
        labels (np.ndarray): (N,) class ids (``CLASSES``).
        radii (np.ndarray): (N,) footprint radius of each actor, metres (for keeping apart).
        start (np.ndarray): (N, 3) starting x, y, heading in the world frame.
        length (int): Frames to simulate.
        dt (float): Seconds between frames.

    Returns:
        np.ndarray: (length, N, 5) ``x, y, heading, speed, turn rate`` per frame and actor.
    """
    n = len(labels)
    names = [CLASSES[int(c)] for c in labels]
    target = _targets(rng, labels)
    speed = target * rng.uniform(0.6, 1.0, n)
    curvature = np.zeros(n)
    xy, heading = start[:, :2].astype(np.float64).copy(), start[:, 2].astype(np.float64).copy()
    out = np.zeros((length, n, 5))
    walker = labels == _PEDESTRIAN
    kmax = np.array([_MAX_CURVATURE[c] for c in names])
    lateral = np.array([_LATERAL.get(c, 3.0) for c in names])
    for t in range(length):
        # per-class steering and speed changes, all drawn every step in the same order
        steer, jolt, change, new_target = (
            rng.normal(size=n),
            rng.normal(size=n),
            rng.uniform(size=n),
            _targets(rng, labels),
        )
        target = np.where(change < 0.02 * dt / 0.1, np.where(target > 0, new_target, target), target)
        accel = np.clip(1.0 * (target - speed) + 0.5 * jolt, -4.0, 2.0)
        accel[walker] = 2.0 * (target[walker] - speed[walker]) + 0.8 * jolt[walker]
        speed = np.clip(speed + accel * dt, 0.0, None)
        stop = walker & (change > 1 - 0.01 * dt / 0.1)
        target[stop] = np.where(target[stop] > 0, 0.0, rng.uniform(0.5, 1.8, int(stop.sum())))
        curvature = np.where(walker, 0.0, 0.97 * curvature + steer * np.where(labels == _CYCLIST, 0.04, 0.01))
        limit = np.minimum(kmax, lateral / np.maximum(speed, 1e-3) ** 2)
        curvature = np.clip(curvature, -limit, limit)
        turn = np.where(walker, steer * 0.8, speed * curvature)
        ahead = np.stack([np.cos(heading), np.sin(heading)], 1)
        moving = speed[:, None] * ahead
        for i in range(n):
            if any(_blocked(i, xy[i] + moving[i] * tau, xy + moving * tau, xy, radii) for tau in (0.5, 1.0, 1.5)):
                speed[i] = 0.0 if walker[i] else max(0.0, speed[i] - 6.0 * dt)  # brake, or stop on foot
            elif _blocked(i, xy[i] + moving[i] * dt, xy + moving * dt, xy, radii):
                speed[i] = 0.0 if walker[i] else max(0.0, speed[i] - 10.0 * dt)  # emergency braking
        proposal = xy + (speed * dt)[:, None] * ahead
        out[t, :, 0:2], out[t, :, 2], out[t, :, 3], out[t, :, 4] = xy, heading, speed, turn
        xy = proposal
        heading = (heading + turn * dt + math.pi) % (2 * math.pi) - math.pi
    return out


def simulate_ego(rng: np.random.Generator, length: int, dt: float, max_speed: float) -> np.ndarray:
    """The ego vehicle's (length, 4, 4) ego-to-world poses (a level, flat drive from the origin heading +x).

    A third of the drives (and all with ``max_speed`` 0) stay parked; the others hold a speed drawn in
    [max_speed / 3, max_speed] m/s on a gently curving road.
    """
    moving = max_speed > 0 and rng.uniform() >= 1 / 3
    speed = rng.uniform(max_speed / 3, max_speed) if moving else 0.0
    curvature, drift = 0.0, rng.normal(size=length)
    x = y = heading = 0.0
    poses = np.zeros((length, 4, 4))
    for t in range(length):
        c, s = math.cos(heading), math.sin(heading)
        poses[t] = np.array([[c, -s, 0, x], [s, c, 0, y], [0, 0, 1, 0], [0, 0, 0, 1]])
        curvature = float(np.clip(0.95 * curvature + 0.003 * drift[t], -0.03, 0.03))
        x, y = x + speed * c * dt, y + speed * s * dt
        heading += speed * curvature * dt
    return poses
