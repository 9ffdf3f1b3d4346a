"""Tracks of the shipped detectors on synthetic sequences: nuScenes tracking metrics of the tracker and of
CenterPoint's greedy baseline, the tracker on noisy ground truth, velocity errors, the tracker's time per frame.

    python benchmarks/tracking.py [--sequences 8] [--length 40] [--work DIR] [--quick]

1. ``--sequences`` validation sequences (seed 0) of ``--length`` frames at 10 Hz, written in the dataset layout
   through each shipped model's rig (``fisheye-infer synth --stream val --sequences``): objects moving by class,
   entering and leaving the labelled range, the ego parked or driving; ground truth includes objects hidden by
   others (the sequences do not mark visibility), for every detector alike;
2. the shipped FisheyeBEVDet and FisheyePETR, each exported once for its rig (kept in ``--work`` when given), run on
   every frame; their detections then feed (a) ``Tracker`` (birth at the model's demo threshold, kept alive from
   a third of it; constant velocity for every class, and again with ``TURNING_CLASSES``: vehicles on the constant
   turn rate model; and constant velocity with the velocities fitted after the fact by ``smooth_velocities``, 1 s
   either side) and (b) ``GreedyTracker`` (CenterPoint's greedy matching, from the demo threshold); (c) the
   ground truth with noise (centre 0.15 m + 1 % of range, size 5 %, yaw 0.1 rad), 10 % of boxes dropped, scores
   drawn in [0.3, 1], and one false alarm per frame at score < 0.3, into both trackers (and the smoothed
   velocities): the tracker's ceiling;
3. AMOTA, AMOTP, MOTA, MOTP, IDS (and per 1,000 frames), FRAG and recall at 0-30 and 0-48 m (``eval.tracking``,
   equal to nuScenes-devkit), HOTA, DetA, AssA and LocA at 0-48 m where TrackEval is installed (``eval.hota``;
   ``make install`` installs it), and the velocity error (m/s) of reported
   tracks within 2 m of a labelled object of their class, vehicles (Car, Van, Truck, Bus) and the rest apart, and
   vehicles' tracks reported 5 times or more;
4. how each detector's vehicle centres miss their labels (radial and tangential spread, and how long a radial miss
   lasts: its lag-1 autocorrelation from frame to frame), the noisy ground truth's beside them, and what a perfect
   tracker could know of the vehicles' velocities from those centres: a straight line fitted to one vehicle's
   matched centres over the last second (what can be reported at the frame) and over a second either side (a
   second late), against the labelled velocity;
5. the time of one ``update`` with 100 detections (100 objects, 10 Hz, in this process's thread), median of 300
   frames;
6. ``docs/assets/tracking-overlay.png`` (not with ``--quick``): frame 30 of validation sequence 7 (the ego driving
   at 8 m/s) with fisheye-bevdet-compact's ``Tracker`` tracks, each with its id and speed, over the four camera
   images, and a bird's-eye view with each track's velocity (1 s of motion) and its last 2 s of path.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import harness
import numpy as np

from fisheye_infer import Detections, Detector, GreedyTracker, Tracker, TrackerConfig
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import OptionError
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.hota import HOTA_METRICS, evaluate_hota
from fisheye_infer.eval.sequences import TrackingFrame, TrackingSequence, read_sequences
from fisheye_infer.eval.track_run import StreamTracker, run_on, track_sequences
from fisheye_infer.eval.tracking import SequenceResults, evaluate_tracking
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.scenes.sequences import SyntheticSequences, write_sequences
from fisheye_infer.tools.track_viz import TrackPaths, draw_tracks
from fisheye_infer.tools.viz import save_png
from fisheye_infer.tracking import TURNING_CLASSES
from fisheye_infer.tracking.smoothing import fit_line

VEHICLES = ("Car", "Van", "Truck", "Bus")
MODELS = ("fisheye-bevdet-compact", "fisheye-petr-compact")
PICTURE = harness.ROOT / "docs" / "assets" / "tracking-overlay.png"
#: Validation sequence and frame of the picture.
PICTURE_AT = (7, 30)
#: Seconds either side of a frame whose centres ``smooth_velocities`` fits.
SMOOTH = 1.0


def noisy_truth(sequences: list[TrackingSequence], seed: int = 0) -> dict[int, Detections]:
    """Ground truth as a detector with noise, misses and false alarms would give it, by split index."""
    rng = np.random.default_rng(seed)
    out = {}
    for seq in sequences:
        for f in seq.frames:
            boxes = f.gt_boxes.copy()
            dist = np.hypot(boxes[:, 0], boxes[:, 1])
            boxes[:, :2] += rng.normal(size=(len(boxes), 2)) * (0.15 + 0.01 * dist)[:, None]
            boxes[:, 3:6] *= rng.normal(1.0, 0.05, (len(boxes), 3))
            boxes[:, 6] += rng.normal(0, 0.1, len(boxes))
            keep = rng.uniform(size=len(boxes)) >= 0.1
            scores = rng.uniform(0.3, 1.0, len(boxes))
            alarm = np.array([[*rng.uniform(-40, 40, 2), -1.8, 4.5, 1.9, 1.6, rng.uniform(-3, 3)]])
            labels = np.append(f.gt_labels[keep], int(rng.integers(0, len(CLASSES))))
            out[f.split_index] = Detections(
                np.vstack([boxes[keep], alarm]).astype(np.float32),
                np.append(scores[keep], rng.uniform(0.05, 0.3)).astype(np.float32),
                labels.astype(np.int64),
                CLASSES,
            )
    return out


def velocity_errors(results: list[SequenceResults], settled: int = 5) -> dict[str, float]:
    """Mean and median |v_track - v_true| (m/s) of reported tracks within 2 m of a labelled object of their class:
    all of them, and the vehicles' once the track has been reported ``settled`` times (its speed learnt)."""
    from scipy.optimize import linear_sum_assignment

    errors: dict[str, list[float]] = {"vehicles": [], "others": [], f"vehicles after {settled} frames": []}
    for seq in results:
        seen: dict[str, int] = {}
        for gt, pred in zip(seq.gt, seq.pred):
            for r in pred:
                seen[r["tracking_id"]] = seen.get(r["tracking_id"], 0) + 1
            if not gt or not pred:
                continue
            g = np.array([r["translation"][:2] for r in gt])
            p = np.array([r["translation"][:2] for r in pred])
            d = np.hypot(g[:, None, 0] - p[None, :, 0], g[:, None, 1] - p[None, :, 1])
            same = np.array([[a["tracking_name"] == b["tracking_name"] for b in pred] for a in gt])
            cost = np.where(same & (d < 2.0), d, 1e6)
            for i, j in zip(*linear_sum_assignment(cost)):
                if cost[i, j] < 1e6:
                    err = float(np.hypot(*(np.subtract(pred[j]["velocity"], gt[i]["velocity"]))))
                    vehicle = gt[i]["tracking_name"] in VEHICLES
                    errors["vehicles" if vehicle else "others"].append(err)
                    if vehicle and seen[pred[j]["tracking_id"]] >= settled:
                        errors[f"vehicles after {settled} frames"].append(err)
    out = {}
    for group, values in errors.items():
        out[f"v err {group} mean m/s"] = float(np.mean(values)) if values else math.nan
        out[f"v err {group} median m/s"] = float(np.median(values)) if values else math.nan
        out[f"v err {group} n"] = len(values)
    return out


#: One labelled vehicle's detection at one frame: the frame's number in its sequence, the frame, the detected centre
#: and the labelled one (x, y, ego frame) and the labelled velocity.
Sighting = tuple[int, TrackingFrame, np.ndarray, np.ndarray, np.ndarray]


def sightings(
    detect: Callable[[int], Detections], sequences: list[TrackingSequence], threshold: float
) -> dict[tuple[int, int], list[Sighting]]:
    """Each labelled vehicle's detections, by (sequence, instance id): per frame, each labelled vehicle paired with a
    box of its class at or above ``threshold`` within 3 m (minimum total distance), the association a perfect tracker
    would make."""
    from scipy.optimize import linear_sum_assignment

    vehicles = [CLASSES.index(c) for c in VEHICLES]
    per_object: dict[tuple[int, int], list[Sighting]] = {}
    for s, seq in enumerate(sequences):
        for k, f in enumerate(seq.frames):
            d = detect(f.split_index)
            keep = d.scores >= threshold
            boxes, labels = d.boxes[keep], d.labels[keep]
            if not len(boxes) or not len(f.gt_boxes):
                continue
            dist = np.hypot(*(f.gt_boxes[:, None, :2] - boxes[None, :, :2]).transpose(2, 0, 1))
            cost = np.where((f.gt_labels[:, None] == labels[None]) & (dist < 3.0), dist, 1e6)
            for i, j in zip(*linear_sum_assignment(cost)):
                if cost[i, j] < 1e6 and f.gt_labels[i] in vehicles:
                    seen = (k, f, boxes[j, :2], f.gt_boxes[i, :2], f.gt_velocities[i])
                    per_object.setdefault((s, int(f.gt_ids[i])), []).append(seen)
    return per_object


def centre_errors(name: str, per_object: dict[tuple[int, int], list[Sighting]]) -> dict[str, object]:
    """How a detector's vehicle centres miss their labels (``sightings``), and how long a miss lasts: the error split
    along the line of sight from the ego origin (radial) and across it (tangential); the lag-1 autocorrelation of an
    object's radial error between consecutive frames, and the spread of its change from one frame to the next (the
    part of the error a filter can average out in a few frames)."""
    split: dict[tuple[int, int], list[tuple[int, float, float]]] = {}
    for key, seen in per_object.items():
        for k, _, detected, labelled, _ in seen:
            sight = labelled / np.hypot(*labelled)
            e = detected - labelled
            split.setdefault(key, []).append((k, float(e @ sight), float(e[1] * sight[0] - e[0] * sight[1])))
    errors = np.array([e for v in split.values() for e in v])
    consecutive = np.array([(a[1], b[1]) for v in split.values() for a, b in zip(v, v[1:]) if b[0] == a[0] + 1])
    return {
        "detections": name,
        "pairs": len(errors),
        "radial mean m": float(errors[:, 1].mean()),
        "radial std m": float(errors[:, 1].std()),
        "tangential std m": float(errors[:, 2].std()),
        "radial lag-1 autocorrelation": float(np.corrcoef(consecutive.T)[0, 1]),
        "radial change frame to frame, std m": float(np.std(consecutive[:, 1] - consecutive[:, 0])),
    }


def fitted_velocity_errors(
    name: str, per_object: dict[tuple[int, int], list[Sighting]], span: float = 1.0, least: int = 12
) -> dict[str, object]:
    """What a perfect tracker could know of vehicles' velocities from these centres: for each vehicle detected at least
    ``least`` times, at each of its sightings, a straight line fitted (least squares, world frame) to its detected
    centres over the last ``span`` seconds (causal: what a tracker can report at that frame) and over ``span``
    seconds either side (centred: ``span`` seconds late), against the labelled velocity; median and mean |error|."""
    errors: dict[str, list[float]] = {"causal": [], "centred": []}
    for seen in per_object.values():
        if len(seen) < least:
            continue
        stamps = np.array([f.stamp for _, f, *_ in seen])
        world = np.array([f.ego_pose[:2, :2] @ detected + f.ego_pose[:2, 3] for _, f, detected, _, _ in seen])
        truth = np.array([f.ego_pose[:2, :2] @ v for _, f, _, _, v in seen])
        for m, t in enumerate(stamps):
            for way, window in (("causal", (t - span, t)), ("centred", (t - span, t + span))):
                inside = (stamps >= window[0] - 1e-6) & (stamps <= window[1] + 1e-6)
                if inside.sum() < 3:
                    continue
                slope, _ = fit_line(stamps[inside] - t, world[inside])
                errors[way].append(float(np.hypot(*(slope - truth[m]))))
    row: dict[str, object] = {"detections": name}
    for way, values in errors.items():
        row[f"{way} median m/s"], row[f"{way} mean m/s"] = float(np.median(values)), float(np.mean(values))
        row[f"{way} n"] = len(values)
    return row


def score(
    name: str,
    detect: Callable[[int], Detections],
    sequences: list[TrackingSequence],
    tracker: StreamTracker,
    smooth: float = 0.0,
) -> dict[str, object]:
    results = track_sequences(detect, sequences, tracker, smooth=smooth)
    report = evaluate_tracking(results)
    frames = sum(len(s.frames) for s in sequences)
    detections, tracker_name = name.split(" + ")
    row: dict[str, object] = {"detections": detections, "tracker": tracker_name}
    for ref in (30.0, 48.0):
        m = report.overall[ref]
        row.update({f"AMOTA {ref:g}m": m["amota"], f"AMOTP {ref:g}m": m["amotp"], f"MOTA {ref:g}m": m["mota"]})
        row.update({f"IDS {ref:g}m": m["ids"], f"IDS/1k frames {ref:g}m": m["ids"] * 1000 / frames})
        row.update({f"FRAG {ref:g}m": m["frag"], f"recall {ref:g}m": m["recall"]})
    try:
        hota = evaluate_hota(results)["overall"]
        row.update({f"{name} 48m": hota[m] for m, name in zip(HOTA_METRICS, ("HOTA", "DetA", "AssA", "LocA"))})
    except OptionError:
        pass  # TrackEval is not installed
    row.update(velocity_errors(results))
    row["per class 0-48m"] = {c: report.classes[48.0][c]["amota"] for c in CLASSES}
    return row


def track_picture(
    detect: Callable[[int], Detections],
    sequence: TrackingSequence,
    frame: int,
    dataset: Fisheye3DOD,
    rig: Rig,
    tracker: Tracker,
) -> np.ndarray:
    """The tracks of ``frame`` of ``sequence`` (tracked from its start) drawn over its images, with their paths."""
    paths = TrackPaths()
    tracker.reset()
    for f in sequence.frames[: frame + 1]:
        tracks = tracker.update(detect(f.split_index), f.stamp, ego_pose=f.ego_pose)
        paths.add(tracks, f.ego_pose)
    f = sequence.frames[frame]
    images = {camera: cv2.imread(str(path)) for camera, path in dataset.image_paths(f.split_index).items()}
    return draw_tracks(tracks, rig, images, paths.in_ego(f.ego_pose), tile=360)


def update_time(make: Callable[[], StreamTracker], frames: int) -> harness.Stats:
    """Median time of one ``update`` with 100 moving cars and pedestrians (ms)."""
    rng = np.random.default_rng(0)
    start, vel = rng.uniform(-45, 45, (100, 2)), rng.uniform(-8, 8, (100, 2))
    labels = np.where(np.arange(100) % 3 == 0, CLASSES.index("Pedestrian"), CLASSES.index("Car")).astype(np.int64)
    tracker, times = make(), []
    for k in range(frames):
        xy = start + vel * 0.1 * k + rng.normal(0, 0.2, (100, 2))
        boxes = np.column_stack(
            [xy, np.full(100, -1.8), np.full((100, 3), [4.5, 1.9, 1.6]), np.arctan2(vel[:, 1], vel[:, 0])]
        )
        dets = Detections(boxes.astype(np.float32), np.full(100, 0.9, np.float32), labels, CLASSES)
        t0 = time.perf_counter()
        tracker.update(dets, 0.1 * k)
        times.append((time.perf_counter() - t0) * 1e3)
    return harness.Stats(tuple(times[20:]))


def main() -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="2 sequences of 20 frames, one model")
    bench.parser.add_argument("--sequences", type=int, default=8)
    bench.parser.add_argument("--length", type=int, default=40)
    bench.parser.add_argument("--threads", type=int, default=2)
    bench.parser.add_argument("--work", type=Path, help="folder for the exports and sequences (kept; reused)")
    args = bench.parse()
    from fisheye_infer.export.exporter import export
    from fisheye_infer.models.pretrained import pretrained

    count, length = (2, 20) if args.quick else (args.sequences, args.length)
    models = MODELS[:1] if args.quick else MODELS
    rows, timing, errors, fitted = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        for name in models:
            shipped = pretrained(name)
            rig = Rig.load(shipped.rig)
            onnx = work / f"{name}.onnx"
            if not onnx.is_file():
                export(shipped.checkpoint, onnx, config=shipped.config, rig=shipped.rig, frames=1)
            data = work / f"seqs-{name}-{count}x{length}"
            if not (data / "ImageSets-2hz" / "val.json").is_file():
                write_sequences(SyntheticSequences(rig, "val", 0, length=length), data, range(count))
            sequences = read_sequences(data, "val")
            detector = Detector(onnx, threads=args.threads)
            dataset = Fisheye3DOD(data, "val", cameras=list(detector.info.cameras))
            run = run_on(detector, dataset)
            detections = {f.split_index: run(f.split_index) for s in sequences for f in s.frames}
            th = shipped.score_threshold
            config = TrackerConfig(score_threshold=th, low_score=th / 3)
            seen = sightings(detections.__getitem__, sequences, th)
            errors.append(centre_errors(name, seen))
            fitted.append(fitted_velocity_errors(name, seen))
            rows.append(score(f"{name} + Tracker", detections.__getitem__, sequences, Tracker(config)))
            smoothed = f"{name} + Tracker, velocities smoothed offline ({SMOOTH:g} s either side)"
            rows.append(score(smoothed, detections.__getitem__, sequences, Tracker(config), smooth=SMOOTH))
            rows.append(score(f"{name} + greedy", detections.__getitem__, sequences, GreedyTracker(th)))
            turning = Tracker(TrackerConfig(score_threshold=th, low_score=th / 3, classes=TURNING_CLASSES))
            rows.append(score(f"{name} + Tracker (turning vehicles)", detections.__getitem__, sequences, turning))
            print(*rows[-4:], sep="\n", flush=True)
            if name == MODELS[0] and not args.quick:
                seq, frame = PICTURE_AT
                picture = track_picture(
                    detections.__getitem__, sequences[seq], frame, dataset, detector.info.rig, Tracker(config)
                )
                print(f"wrote {save_png(PICTURE, picture)}")
        truth = noisy_truth(sequences)
        seen = sightings(truth.__getitem__, sequences, 0.3)
        errors.append(centre_errors("noisy ground truth", seen))
        fitted.append(fitted_velocity_errors("noisy ground truth", seen))
        rows.append(score("noisy ground truth + Tracker", truth.__getitem__, sequences, Tracker()))
        smoothed = f"noisy ground truth + Tracker, velocities smoothed offline ({SMOOTH:g} s either side)"
        rows.append(score(smoothed, truth.__getitem__, sequences, Tracker(), smooth=SMOOTH))
        turning = Tracker(TrackerConfig(classes=TURNING_CLASSES))
        rows.append(score("noisy ground truth + Tracker (turning vehicles)", truth.__getitem__, sequences, turning))
        rows.append(score("noisy ground truth + greedy", truth.__getitem__, sequences, GreedyTracker(0.3)))
    for label, make in (("Tracker", Tracker), ("greedy", lambda: GreedyTracker(0.3))):
        timing.append({"tracker": label, "detections": 100, **update_time(make, 320).row()})  # type: ignore[arg-type]
    per_class = [{"run": f"{r['detections']} + {r['tracker']}", **r.pop("per class 0-48m")} for r in rows]  # type: ignore[dict-item]
    bench.save(
        args,
        {
            "Tracking (overall, nuScenes tracking metrics)": rows,
            "AMOTA per class, 0-48 m": per_class,
            "Vehicle centres against their labels (matched within 3 m)": errors,
            "Vehicle velocities fitted to the matched centres (a perfect tracker's, 1 s of centres)": fitted,
            "Time of one update, 100 detections (single-threaded)": timing,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
