"""Synthetic sequences: deterministic, train and val apart, motion by class, and their files read back."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.cli import main
from fisheye_infer.eval.sequences import read_sequences
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.scenes.render import resized_rig
from fisheye_infer.scenes.sequences import SyntheticSequences


@pytest.fixture(scope="module")
def small_rig() -> Rig:
    return resized_rig(default_rig(), 0.08)


def world_xy(frame) -> dict[int, np.ndarray]:  # type: ignore[no-untyped-def]
    """Instance id -> world x, y of a frame's labelled objects."""
    xy = frame.boxes[:, :2] @ frame.ego_pose[:2, :2].T + frame.ego_pose[:2, 3]
    return dict(zip(frame.ids.tolist(), xy))


def test_same_seed_same_sequence_and_splits_never_share_one(small_rig: Rig) -> None:
    a = SyntheticSequences(small_rig, "val", 0, length=12).sequence(2)
    b = SyntheticSequences(small_rig, "val", 0, length=12).sequence(2)
    for fa, fb in zip(a.frames, b.frames):
        assert np.array_equal(fa.boxes, fb.boxes) and np.array_equal(fa.ids, fb.ids)
        assert np.array_equal(fa.ego_pose, fb.ego_pose)
    starts = {
        split: {tuple(np.round(f.boxes[0], 6)) for k in range(20) for f in [seqs.sequence(k).frames[0]] if len(f.boxes)}
        for split in ("train", "val")
        for seqs in [SyntheticSequences(small_rig, split, 0, length=1)]
    }
    assert not starts["train"] & starts["val"]
    other = SyntheticSequences(small_rig, "val", 1, length=12).sequence(2)
    assert not np.array_equal(other.frames[0].boxes, a.frames[0].boxes)


def test_objects_move_by_class_and_velocities_match_their_paths(small_rig: Rig) -> None:
    seqs = SyntheticSequences(small_rig, "val", 0, length=40)
    speeds: dict[str, list[float]] = {name: [] for name in CLASSES}
    entered = left = 0
    for k in range(6):
        seq = seqs.sequence(k)
        for f0, f1 in zip(seq.frames, seq.frames[1:]):
            p0, p1 = world_xy(f0), world_xy(f1)
            v0 = dict(zip(f0.ids.tolist(), f0.velocities @ f0.ego_pose[:2, :2].T))  # back to world axes
            for i in set(p0) & set(p1):
                np.testing.assert_allclose((p1[i] - p0[i]) / 0.1, v0[i], atol=1e-6)  # the path steps by its velocity
            entered += len(set(p1) - set(p0))
            left += len(set(p0) - set(p1))
            for label, v in zip(f0.labels, f0.velocities):
                speeds[CLASSES[label]].append(float(np.hypot(*v)))
    assert entered > 0 and left > 0
    assert max(speeds["Car"]) <= 15.0 + 1e-9 and max(speeds["Car"]) > 8.0
    assert max(speeds["Pedestrian"]) < 3.0 and np.median(speeds["Pedestrian"]) > 0
    assert min(speeds["Car"]) == 0.0  # some are parked


def test_ego_moves_and_parked_objects_stay_put_in_the_world(small_rig: Rig) -> None:
    seqs = SyntheticSequences(small_rig, "val", 0, length=20, ego_speed=10.0)
    moved, checked = False, 0
    for k in range(6):
        seq = seqs.sequence(k)
        first, last = seq.frames[0], seq.frames[-1]
        moved |= bool(np.hypot(*(last.ego_pose[:2, 3] - first.ego_pose[:2, 3])) > 5)
        still = {i for f in seq.frames for i, v in zip(f.ids.tolist(), f.velocities) if np.hypot(*v) == 0}
        moving = {i for f in seq.frames for i, v in zip(f.ids.tolist(), f.velocities) if np.hypot(*v) > 0}
        a, b = world_xy(first), world_xy(last)
        for i in (still - moving) & set(a) & set(b):  # at rest in every frame it is labelled
            np.testing.assert_allclose(a[i], b[i], atol=1e-9)
            checked += 1
    assert moved and checked > 0
    parked = SyntheticSequences(small_rig, "val", 0, length=5, ego_speed=0).sequence(0)
    assert not np.any(parked.frames[-1].ego_pose[:2, 3])


def test_synth_writes_sequences_that_read_back(small_rig: Rig, tmp_path: Path) -> None:
    rig_path = tmp_path / "rig.json"
    small_rig.save(rig_path)
    out = tmp_path / "seqs"
    assert (
        main(
            ["synth", "--rig", str(rig_path), "--stream", "val", "--sequences", "2", "--length", "6", "--out", str(out)]
        )
        == 0
    )
    seqs = read_sequences(out, "val")
    truth = SyntheticSequences(small_rig, "val", 0, length=6)
    assert [s.name for s in seqs] == [f"{truth.scene_name(k)}/ego0" for k in range(2)]
    for k, seq in enumerate(seqs):
        for got, want in zip(seq.frames, truth.sequence(k).frames):
            assert got.stamp == pytest.approx(want.stamp)
            np.testing.assert_allclose(got.ego_pose[:2], want.ego_pose[:2], atol=1e-9)
            np.testing.assert_allclose(got.gt_boxes, want.boxes, atol=1e-6)
            np.testing.assert_array_equal(got.gt_ids, want.ids)
            np.testing.assert_allclose(got.gt_velocities, want.velocities)


def test_sequences_need_a_stream(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["synth", "--sequences", "2", "--out", str(tmp_path)]) == 2
    assert "--sequences needs --stream" in capsys.readouterr().err
    assert main(["synth", "--stream", "val", "--sequences", "1", "--rate", "3", "--out", str(tmp_path)]) == 2
    assert "rate: expected one of" in capsys.readouterr().err
