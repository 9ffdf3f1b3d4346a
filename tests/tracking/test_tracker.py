"""The tracker on constructed scenes: crossings and occlusions without swaps, birth and death, ego motion, dt."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from fisheye_infer import Detections, FrameError, GreedyTracker, OptionError, Tracker, TrackerConfig, Tracks
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.tracking import TURNING_CLASSES, ClassConfig, ConstantVelocity

CAR, PED = CLASSES.index("Car"), CLASSES.index("Pedestrian")


def dets(rows: list[tuple[float, ...]], cameras: int = 6, yaw: float = 0.0) -> Detections:
    """Detections from (x, y, label, score[, yaw]) rows, class-typical sizes."""
    sizes = {CAR: (4.5, 1.9, 1.6), PED: (0.7, 0.7, 1.75)}
    boxes = np.array([[r[0], r[1], -2.0, *sizes[int(r[2])], r[4] if len(r) > 4 else yaw] for r in rows], np.float32)
    return Detections(
        boxes.reshape(-1, 7),
        np.array([r[3] for r in rows], np.float32),
        np.array([r[2] for r in rows], np.int64),
        CLASSES,
        cameras_used=tuple(f"cam{i}" for i in range(cameras)),
    )


def run(tracker: Tracker | GreedyTracker, frames: list[Detections], dt: float = 0.1) -> list[Tracks]:
    return [tracker.update(d, k * dt) for k, d in enumerate(frames)]


def id_at(tracks: Tracks, x: float, y: float) -> int:
    """The id of the track nearest (x, y)."""
    k = int(np.argmin(np.hypot(tracks.boxes[:, 0] - x, tracks.boxes[:, 1] - y)))
    return int(tracks.ids[k])


def test_two_cars_crossing_keep_their_ids() -> None:
    # one drives east along y = 0, the other north along x = 10; they pass the crossing 1 m apart in time
    frames = []
    for k in range(30):
        t = 0.1 * k
        frames.append(dets([(t * 10.0, 0.0, CAR, 0.9, 0.0), (10.0, -13.0 + t * 10.0, CAR, 0.9, math.pi / 2)]))
    out = run(Tracker(), frames)
    first = out[2]
    east, north = id_at(first, 2.0, 0.0), id_at(first, 10.0, -11.0)
    for k, tracks in enumerate(out[2:], start=2):
        t = 0.1 * k
        assert id_at(tracks, t * 10.0, 0.0) == east
        assert id_at(tracks, 10.0, -13.0 + t * 10.0) == north


def test_turning_model_follows_a_car_round_a_bend() -> None:
    # 10 m/s on a 20 m circle; the constant-turn-rate filter learns the turn and keeps one id
    frames, tracker = [], Tracker(TrackerConfig(classes=TURNING_CLASSES))
    for k in range(40):
        a = 0.5 * 0.1 * k
        frames.append(dets([(20 * math.sin(a), 20 * (1 - math.cos(a)), CAR, 0.9, a)]))
    out = run(tracker, frames)
    assert len({int(o.ids[0]) for o in out}) == 1
    a = 0.5 * 3.9
    np.testing.assert_allclose(out[-1].velocities[0], [10 * math.cos(a), 10 * math.sin(a)], atol=0.5)


def test_duplicates_of_one_object_start_one_track() -> None:
    tracker = Tracker()
    out = tracker.update(dets([(10, 0, CAR, 0.9), (10.6, 0.3, CAR, 0.7), (10, 0, PED, 0.8), (16, 0, CAR, 0.5)]), 0.0)
    assert sorted(out.names) == ["Car", "Car", "Pedestrian"]  # the second car box is within 2 m of a better one
    out = tracker.update(dets([(10, 0, CAR, 0.9), (10.6, 0.3, CAR, 0.7), (16, 0, CAR, 0.5)]), 0.1)
    assert len(out) == 2 and tracker.live == 3  # near a live track: no birth either


def test_a_stray_detection_within_the_gate_keeps_the_track() -> None:
    # a parked car; one frame's detection lands 3.5 m off (a camera detector's far-centre error): the 3 m car gate
    # plus twice the prediction's spread (about 0.5 m) still takes it, so the car keeps its id
    tracker = Tracker()
    ids = [int(tracker.update(dets([(10, 0, CAR, 0.9)]), 0.1 * k).ids[0]) for k in range(10)]
    stray = tracker.update(dets([(13.5, 0, CAR, 0.9)]), 1.0)
    assert list(stray.ids) == [ids[0]] and tracker.live == 1


def test_a_parked_car_reports_no_velocity_and_a_driving_one_its_own() -> None:
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 0.3, (30, 2, 2))
    frames = [dets([(10 + noise[k, 0, 0], noise[k, 0, 1], CAR, 0.9), (-20 + k + noise[k, 1, 0], 8, CAR, 0.9)])
              for k in range(30)]  # fmt: skip
    last = run(Tracker(), frames)[-1]
    parked, driving = id_at(last, 10, 0), id_at(last, 9, 8)
    v = dict(zip(last.ids.tolist(), last.velocities.tolist()))
    assert v[parked] == [0.0, 0.0]
    assert math.hypot(v[driving][0] - 10.0, v[driving][1]) < 1.5
    # without the test the parked car's filter velocity is reported as is, the detections' noise in it
    open_config = TrackerConfig(classes={"Car": ClassConfig(ConstantVelocity(0.7, 3.0, 8.0), 3.0)})
    last = run(Tracker(open_config), frames)[-1]
    assert 0 < np.hypot(*last.velocities[np.argmin(np.hypot(last.boxes[:, 0] - 10, last.boxes[:, 1]))]) < 1.5


def test_young_tracks_report_lower_scores() -> None:
    tracker = Tracker(TrackerConfig(young_weight=0.5))
    scores = [float(tracker.update(dets([(5, 5, CAR, 0.8)]), 0.1 * k).scores[0]) for k in range(4)]
    assert scores == pytest.approx([0.8 * (1 - 0.5**h) for h in (1, 2, 3, 4)])


def test_pedestrians_walking_past_each_other_do_not_swap() -> None:
    frames = [dets([(0.1 * k, 0.0, PED, 0.8), (3.0 - 0.1 * k, 0.6, PED, 0.8)]) for k in range(30)]
    out = run(Tracker(), frames)
    left = id_at(out[2], 0.2, 0.0)
    assert all(id_at(tr, 0.1 * k, 0.0) == left for k, tr in enumerate(out[2:], start=2))
    assert set(out[-1].ids) == set(out[2].ids)


def test_occluded_car_comes_back_with_its_id_at_the_predicted_place() -> None:
    rows = [[(8.0 * 0.1 * k, 5.0, CAR, 0.9)] if not 10 <= k < 17 else [] for k in range(25)]
    out = run(Tracker(), [dets(r) for r in rows])
    assert len(out[9]) == 1
    assert all(len(out[k]) == 0 for k in range(10, 17))  # coasting tracks are not reported
    assert out[17].ids.tolist() == out[9].ids.tolist()
    np.testing.assert_allclose(out[20].velocities[0], [8.0, 0.0], atol=0.5)


def test_birth_needs_min_hits_and_a_confident_detection() -> None:
    tracker = Tracker(TrackerConfig(min_hits=3, score_threshold=0.5, low_score=0.1))
    low = [tracker.update(dets([(5, 5, CAR, 0.3)]), 0.1 * k) for k in range(3)]
    assert all(len(t) == 0 for t in low) and tracker.live == 0  # low scores never start a track
    out = [tracker.update(dets([(5, 5, CAR, 0.9)]), 1.0 + 0.1 * k) for k in range(3)]
    assert [len(t) for t in out] == [0, 0, 1]
    assert out[2].ages.tolist() == [2]


def test_low_score_detections_keep_a_confirmed_track_alive() -> None:
    tracker = Tracker(TrackerConfig(max_coast=0.15))
    scores = [0.9, 0.9, 0.9, 0.15, 0.15, 0.15, 0.15, 0.9]
    out = [tracker.update(dets([(5, 5, CAR, s)]), 0.1 * k) for k, s in enumerate(scores)]
    ids = {int(t.ids[0]) for t in out[1:]}
    assert len(ids) == 1 and all(len(t) == 1 for t in out[1:])


def test_death_after_max_coast_and_tentative_tracks_die_at_once() -> None:
    tracker = Tracker(TrackerConfig(max_coast=0.25, min_hits=2))
    for k in range(3):
        tracker.update(dets([(5, 5, CAR, 0.9)]), 0.1 * k)
    tracker.update(dets([(20, 20, CAR, 0.9)]), 0.3)  # a tentative track far away, and a miss for the first
    assert tracker.live == 2
    tracker.update(dets([]), 0.4)
    assert tracker.live == 1  # the tentative one missed once; the first is 0.2 s unmatched
    tracker.update(dets([]), 0.5)
    assert tracker.live == 0  # 0.3 s > max_coast
    out = tracker.update(dets([(5, 5, CAR, 0.9)]), 0.6)
    assert len(out) == 0  # a new object must be confirmed again


def test_degraded_frames_count_no_misses() -> None:
    tracker = Tracker(TrackerConfig(max_coast=0.15))
    for k in range(3):
        tracker.update(dets([(5, 5, CAR, 0.9)]), 0.1 * k)
    for k in range(3, 8):
        tracker.update(dets([], cameras=4), 0.1 * k)  # two cameras missing: not a miss
    assert tracker.live == 1
    tracker.update(dets([]), 0.8)
    tracker.update(dets([]), 0.9)
    assert tracker.live == 0


def test_variable_time_steps_and_dropped_frames() -> None:
    stamps = [0.0, 0.1, 0.2, 0.3, 0.6, 0.7, 1.05, 1.1, 1.2]  # frames dropped and jittered
    tracker = Tracker()
    out = [tracker.update(dets([(12.0 * t, 3.0, CAR, 0.9)]), t) for t in stamps]
    assert len({int(o.ids[0]) for o in out[1:]}) == 1
    np.testing.assert_allclose(out[-1].velocities[0], [12.0, 0.0], atol=0.6)


def test_ego_motion_is_compensated() -> None:
    # a parked car at world (30, 4); the ego drives by at 10 m/s, turning slowly
    tracker, baseline = Tracker(), GreedyTracker()
    for k in range(20):
        t = 0.1 * k
        yaw = 0.05 * t
        pose = np.eye(4)
        pose[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        pose[:2, 3] = [10.0 * t, 0.0]
        ego = np.linalg.inv(pose) @ np.array([30.0, 4.0, -2.0, 1.0])
        d = dets([(float(ego[0]), float(ego[1]), CAR, 0.9)], yaw=-yaw)
        out, base = tracker.update(d, t, ego_pose=pose), baseline.update(d, t, ego_pose=pose)
        if k >= 1:
            np.testing.assert_allclose(out.boxes[0, :2], ego[:2], atol=0.3)
            assert abs(float(out.boxes[0, 6])) < 0.1  # yaw back in the ego frame
        if k >= 5:
            assert np.hypot(*out.velocities[0]) < 0.3  # parked: no speed over ground
            assert np.hypot(*base.velocities[0]) < 0.3
    assert len({int(i) for i in out.ids}) == 1


def test_without_ego_poses_a_parked_car_seems_to_move() -> None:
    tracker = Tracker()
    for k in range(15):
        out = tracker.update(dets([(30.0 - 1.0 * k, 4.0, CAR, 0.9)]), 0.1 * k)
    np.testing.assert_allclose(out.velocities[0], [-10.0, 0.0], atol=0.5)


def test_same_inputs_same_tracks_and_memory_is_capped() -> None:
    rng = np.random.default_rng(0)
    frames = [dets([(float(x), float(y), CAR, 0.9) for x, y in rng.uniform(-40, 40, (60, 2))]) for _ in range(6)]
    a = run(Tracker(TrackerConfig(max_tracks=50)), frames)
    b = run(Tracker(TrackerConfig(max_tracks=50)), frames)
    assert all(np.array_equal(x.ids, y.ids) and np.array_equal(x.boxes, y.boxes) for x, y in zip(a, b))
    tracker = Tracker(TrackerConfig(max_tracks=50))
    for k, f in enumerate(frames):
        tracker.update(f, 0.1 * k)
        assert tracker.live <= 50


def test_greedy_baseline_tracks_a_straight_drive() -> None:
    out = run(GreedyTracker(), [dets([(10.0 * 0.1 * k, 0.0, CAR, 0.9)]) for k in range(10)])
    assert len({int(o.ids[0]) for o in out}) == 1
    np.testing.assert_allclose(out[-1].velocities[0], [10.0, 0.0], atol=1e-3)


def test_records_carry_ids_and_velocities() -> None:
    tracker = Tracker()
    for k in range(5):
        tracks = tracker.update(dets([(10.0 * 0.1 * k, 0.0, CAR, 0.9)]), 0.1 * k)
    (rec,) = tracks.to_nuscenes()
    assert rec["tracking_id"] == str(tracks.ids[0]) and rec["tracking_name"] == "Car"
    assert rec["tracking_score"] == pytest.approx(0.9 * (1 - 0.5**5)) and len(rec["velocity"]) == 2  # young_weight
    (det,) = tracks.detection_records()
    assert det["velocity"] == rec["velocity"] and det["detection_name"] == "Car"


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda t: t.update("boxes", 0.0), "expected a fisheye_infer Detections"),
        (lambda t: t.update(dets([]), float("nan")), "finite"),
        (lambda t: t.update(dets([]), "now"), "seconds as a number"),
        (lambda t: t.update(dets([]), 0.0, ego_pose=np.eye(3)), "4x4"),
        (lambda t: t.update(dets([]), 0.0, ego_pose=np.diag([1, 1, -1, 1.0])), "rigid"),
    ],
)
def test_bad_input_is_named(call, message: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(FrameError, match=message):
        call(Tracker())


def test_stamps_must_increase_and_reset_starts_over() -> None:
    tracker = Tracker()
    tracker.update(dets([(5, 5, CAR, 0.9)]), 1.0)
    with pytest.raises(FrameError, match="not after the previous frame"):
        tracker.update(dets([]), 1.0)
    tracker.reset()
    assert tracker.live == 0
    tracker.update(dets([]), 0.0)


def test_bad_settings_are_named() -> None:
    with pytest.raises(OptionError, match="low_score"):
        TrackerConfig(score_threshold=0.3, low_score=0.5)
    with pytest.raises(OptionError, match="max_tracks"):
        TrackerConfig(max_tracks=0)
    with pytest.raises(OptionError, match="score_threshold"):
        GreedyTracker(score_threshold=1.5)
    with pytest.raises(OptionError, match="'Car': parked_level"):
        TrackerConfig(classes={"Car": ClassConfig(ConstantVelocity(), parked_level=1.0)})


def test_update_at_100_detections_is_fast() -> None:
    rng = np.random.default_rng(1)
    base = rng.uniform(-45, 45, (100, 2))
    tracker = Tracker()
    times = []
    for k in range(20):
        d = dets([(float(x) + 0.5 * k * 0.1, float(y), CAR, 0.9) for x, y in base])
        t0 = time.perf_counter()
        tracker.update(d, 0.1 * k)
        times.append(time.perf_counter() - t0)
    assert np.median(times) < 0.05  # generous for a shared machine; the benchmark measures it
