"""The tracking metric equals nuScenes-devkit's on the same random sequences (run where the devkit is importable).

The devkit (with motmetrics, pandas, scikit-learn and matplotlib) pins numpy below 2, so it is not part of the
``dev`` extra; install it beside the project (``pip install --no-deps --target DIR nuscenes-devkit motmetrics ...``
and ``PYTHONPATH=DIR``) to run these tests.
"""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np
import pytest

algo = pytest.importorskip("nuscenes.eval.tracking.algo")
from nuscenes.eval.common.config import config_factory
from nuscenes.eval.common.utils import center_distance
from nuscenes.eval.tracking.constants import AVG_METRIC_MAP, MOT_METRIC_MAP
from nuscenes.eval.tracking.data_classes import TrackingBox
from nuscenes.eval.tracking.loaders import interpolate_tracks

from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.eval.tracking import TRACKING_METRICS, SequenceResults, evaluate_tracking

config_factory("tracking_nips_2019")  # registers the devkit's tracking class names
NAMES = {
    "Car": "car",
    "Van": "trailer",
    "Truck": "truck",
    "Bus": "bus",
    "Pedestrian": "pedestrian",
    "Cyclist": "bicycle",
}
WORST = {"amota": 0.0, "amotp": 2.0, "recall": 0.0, "motar": 0.0, "mota": 0.0, "motp": 2.0, "mt": 0.0, "ml": -1.0,
         "faf": 500, "gt": -1, "tp": 0.0, "fp": -1.0, "fn": -1.0, "ids": -1.0, "frag": -1.0, "tid": 20, "lgd": 20}  # fmt: skip


def random_sequence(rng: np.random.Generator, name: str, frames: int = 15) -> SequenceResults:
    """Objects on straight paths seen by a turning ego; tracks with noise, gaps, swaps, false alarms and misses."""
    n = int(rng.integers(3, 9))
    labels = rng.choice(list(NAMES), n)
    start, vel = rng.uniform(-45, 45, (n, 2)), rng.uniform(-6, 6, (n, 2))
    poses, gt, pred = [], [], []
    next_track = [f"{name}-t{i}" for i in range(n)]
    for k in range(frames):
        yaw, pose = 0.05 * k, np.eye(4)
        pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        pose[:2, 3] = [3.0 * k, 0.5 * k]
        poses.append(pose)
        g, p = [], []
        for i in range(n):
            world = np.array([*(start[i] + vel[i] * 0.1 * k), 0.0, 1.0])
            local = np.linalg.inv(pose) @ world
            if rng.uniform() < 0.9:
                g.append({"translation": list(local[:3]), "tracking_id": f"{name}-{i}", "tracking_name": labels[i]})
            if rng.uniform() < 0.05:
                next_track[i] = f"{next_track[i]}'"  # the track restarts under a new id
            if rng.uniform() < 0.8:
                noisy = local[:3] + np.append(rng.normal(0, 0.6, 2), 0)
                score = float(np.clip(rng.normal(0.6, 0.2), 0.01, 1))
                p.append({"translation": list(noisy), "tracking_id": next_track[i], "tracking_name": labels[i],
                          "tracking_score": score})  # fmt: skip
        for j in range(int(rng.integers(0, 3))):
            xy = rng.uniform(-40, 40, 2)
            p.append({"translation": [*xy, 0.0], "tracking_id": f"{name}-fa{k}-{j}", "tracking_name": rng.choice(list(NAMES)),
                      "tracking_score": float(rng.uniform(0, 0.5))})  # fmt: skip
        gt.append(g)
        pred.append(p)
    return SequenceResults(name, [0.1 * k for k in range(frames)], np.stack(poses), gt, pred)


def devkit_tracks(seqs: list[SequenceResults], which: str, ranges: dict[str, float]) -> dict:  # type: ignore[type-arg]
    """The devkit's ``create_tracks`` without a NuScenes object: range filter, mean track scores, interpolation."""
    tracks: dict = {}  # type: ignore[type-arg]
    for seq in seqs:
        frames = defaultdict(list)
        for k, records in enumerate(seq.gt if which == "gt" else seq.pred):
            stamp = int(round(seq.stamps[k] * 1e6))
            frames[stamp] = []
            for r in records:
                t = np.asarray(r["translation"])
                if not math.hypot(t[0], t[1]) < ranges[r["tracking_name"]]:
                    continue
                world = seq.poses[k][:3, :3] @ t + seq.poses[k][:3, 3]
                frames[stamp].append(TrackingBox(
                    sample_token=f"{seq.name}-{k}", translation=tuple(world), size=(2, 4, 1.5), rotation=(1, 0, 0, 0),
                    velocity=(0, 0), ego_translation=tuple(t), tracking_id=r["tracking_id"],
                    tracking_name=NAMES[r["tracking_name"]], tracking_score=r.get("tracking_score", -1.0),
                ))  # fmt: skip
        if which == "pred":
            scores = defaultdict(list)
            for boxes in frames.values():
                for b in boxes:
                    scores[b.tracking_id].append(b.tracking_score)
            for boxes in frames.values():
                for b in boxes:
                    b.tracking_score = float(np.mean(scores[b.tracking_id]))
        tracks[seq.name] = interpolate_tracks(frames)
    return tracks


def devkit_metrics(gt: dict, pred: dict, name: str) -> dict[str, float]:  # type: ignore[type-arg]
    """``TrackingEval.evaluate`` for one class."""
    ev = algo.TrackingEvaluation(gt, pred, name, center_distance, 2.0, 0.1, 40, WORST, verbose=False)
    md = ev.accumulate()
    out: dict[str, float] = {}
    if not np.all(np.isnan(md.mota)):
        best = int(np.nanargmax(md.mota))
        out = {m: float(md.get_metric(m)[best]) for m in MOT_METRIC_MAP.values() if m}
    for metric, per in AVG_METRIC_MAP.items():
        values = np.array(md.get_metric(per))
        out[metric] = (
            math.nan if np.all(np.isnan(values)) else float(np.mean(np.where(np.isnan(values), WORST[metric], values)))
        )
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equal_to_the_devkit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    seqs = [random_sequence(rng, f"s{k}") for k in range(3)]
    config = EvalConfig()
    report = evaluate_tracking(seqs, config)
    for ref in config.distance_breakdown:
        ranges = dict(zip(config.class_names, config.class_ranges(ref).tolist()))
        gt, pred = devkit_tracks(seqs, "gt", ranges), devkit_tracks(seqs, "pred", ranges)
        for ours, theirs in NAMES.items():
            want = devkit_metrics(gt, pred, theirs)
            got = report.classes[ref][ours]
            for metric in TRACKING_METRICS:
                assert got[metric] == pytest.approx(want.get(metric, math.nan), nan_ok=True, abs=1e-9), (
                    ref,
                    ours,
                    metric,
                )
