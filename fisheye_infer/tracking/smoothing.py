"""Velocities fitted after the fact: each track's velocity at each frame re-estimated from its detections a span of
time either side, for results files, labelling and evaluation (what can wait for the frames that follow).

    history = [tracker.update(dets, stamp, ego_pose=pose) for dets, stamp, pose in sequence]
    smoothed = smooth_velocities(history, poses, span=1.0)

A tracker reports at each frame what the frames before it tell; the velocity of a detector's noisy centres is
known far better a second later. ``smooth_velocities`` fits a straight line (least squares, world frame) to the
centres a track took within ``span`` seconds of each of its frames, before and after, and reports its slope with
the fit's covariance (also where a tracker reported a standing vehicle's velocity as exactly 0). A frame with
fewer than three of its track's centres in reach keeps the tracker's velocity.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from fisheye_infer.tracking.frames import check_pose, covariances_to_ego, to_world, velocities_to_ego
from fisheye_infer.tracking.tracks import Tracks

__all__ = ["fit_line", "smooth_velocities"]

#: Centres a line is fitted to, at least: two give a slope, a third its spread.
LEAST_CENTRES = 3


def smooth_velocities(
    history: Sequence[Tracks], poses: Sequence[np.ndarray] | None = None, span: float = 1.0
) -> list[Tracks]:
    """Each track's velocity at each frame, fitted to its centres within ``span`` seconds either side.

    Args:
        history (Sequence[Tracks]): One tracker's reports over a sequence, in time order.
        poses (Sequence[np.ndarray] | None): The 4x4 ego-to-world pose of each report's frame, as the tracker was
            given them; None: the ego stood still (tracks in one fixed frame).
        span (float): Seconds either side of a frame whose centres enter its fit; > 0.

    Returns:
        list[Tracks]: ``history`` with velocities (and velocity covariances, where the tracker keeps them)
            re-fitted where a track had at least three centres within ``span`` of the frame (its detections'
            centres where the tracker reports them, else its boxes'); all else unchanged. A fitted velocity is
            the line's slope, a standing vehicle's too (not the exact 0 a ``Tracker`` reports for it); its
            covariance is the slope's from the residuals, as if the centres' errors were independent from frame
            to frame (a detector's that persist make it too small).

    Raises:
        ValueError: ``span`` is not a positive number of seconds, a report is not a ``Tracks`` or repeats an id,
            the stamps are not finite or do not increase, or ``poses`` does not match ``history``.
        FrameError: A pose is not a rigid 4x4 transform.
    """
    if isinstance(span, bool) or not isinstance(span, numbers.Real) or not 0 < span < math.inf:
        raise ValueError(f"span: expected seconds > 0, got {span!r}")
    _check_history(history)
    if not history:
        return []
    stamps = np.array([t.stamp for t in history], np.float64)
    if poses is not None and len(poses) != len(history):
        raise ValueError(f"poses: expected one per report ({len(history)}), got {len(poses)}")
    frames = [np.eye(4)] * len(history) if poses is None else [check_pose(p) for p in poses]
    ids = np.concatenate([t.ids for t in history])
    frame_of = np.repeat(np.arange(len(history)), [len(t) for t in history])
    row_of = np.concatenate([np.arange(len(t)) for t in history])
    flat = np.concatenate([_world_centres(t, pose) for t, pose in zip(history, frames)])
    velocities = [np.array(t.velocities, np.float64) for t in history]
    covariances = [np.zeros((len(t), 2, 2)) for t in history]
    fitted = [np.zeros(len(t), bool) for t in history]
    order = np.argsort(ids, kind="stable")  # each track's reports together, in time order
    for mine in np.split(order, np.flatnonzero(np.diff(ids[order])) + 1):
        t, xy = stamps[frame_of[mine]], flat[mine]
        for k, row, at in zip(frame_of[mine], row_of[mine], t):
            near = np.abs(t - at) <= span + 1e-6  # stamps a span apart, within rounding
            if near.sum() < LEAST_CENTRES:
                continue
            slope, covariance = fit_line(t[near] - at, xy[near])
            velocities[k][row], covariances[k][row], fitted[k][row] = slope, covariance, True
    out = []
    for report, pose, v, c, done in zip(history, frames, velocities, covariances, fitted):
        v_ego = np.where(done[:, None], velocities_to_ego(v, pose), report.velocities).astype(np.float32)
        if report.velocity_covariances is None:
            out.append(replace(report, velocities=v_ego))
            continue
        c_ego = np.where(done[:, None, None], covariances_to_ego(c, pose), report.velocity_covariances)
        out.append(replace(report, velocities=v_ego, velocity_covariances=c_ego.astype(np.float32)))
    return out


def _check_history(history: Sequence[Tracks]) -> None:
    """A ``ValueError`` naming the first report that is not a ``Tracks``, repeats an id, or breaks the time order."""
    last = -math.inf
    for k, report in enumerate(history):
        if not isinstance(report, Tracks):
            raise ValueError(f"history[{k}]: expected a fisheye_infer Tracks, got {type(report).__name__}")
        if not math.isfinite(report.stamp) or report.stamp <= last:
            raise ValueError(f"history[{k}]: stamp {report.stamp} s; the reports' stamps must be finite and increase")
        if len(np.unique(report.ids)) != len(report.ids):
            raise ValueError(f"history[{k}]: a track id appears twice in one report")
        last = report.stamp


def _world_centres(tracks: Tracks, pose: np.ndarray) -> np.ndarray:
    """(K, 2) world centres of the detections the tracks took (their boxes' where the tracker gives none)."""
    boxes = np.array(tracks.boxes, np.float64)
    if tracks.detected_centres is not None:
        boxes[:, :2] = tracks.detected_centres
    return to_world(boxes, pose)[:, :2]


def fit_line(dt: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The velocity of a least-squares line through centres, and its covariance.

    Args:
        dt (np.ndarray): `(N,)` times of the centres, seconds (N >= 3, not all equal).
        xy (np.ndarray): `(N, 2)` centres, metres.

    Returns:
        tuple[np.ndarray, np.ndarray]: The slope `(2,)`, m/s, and its `(2, 2)` covariance: the residuals'
            (N - 2 degrees of freedom) over the times' spread, (m/s)^2.
    """
    centred = dt - dt.mean()
    spread = float(centred @ centred)
    slope = centred @ (xy - xy.mean(axis=0)) / spread
    residuals = xy - xy.mean(axis=0) - np.outer(centred, slope)
    return slope, residuals.T @ residuals / (len(dt) - 2) / spread
