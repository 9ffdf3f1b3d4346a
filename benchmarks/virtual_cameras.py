"""A trained detector on other rigs without retraining: virtual cameras against re-baked tables, FDS per test rig.

    python benchmarks/virtual_cameras.py [--model fisheye-bevdet-compact] [--frames 40] [--threads 2] [--quick]
    python benchmarks/virtual_cameras.py --cost-only [--rounds 5] [--model fisheye_bevdet] [--model compact --int8]

1. The shipped model exported once for its training rig (``fisheye-infer export``), then, for each test rig, two
   files written by ``fisheye_infer.export.rebake``: ``virtual`` (the robot's raw images resampled in the graph into
   the training cameras' images) and, where the rig keeps the training image size and OCam lenses, ``tables`` (the
   geometry tables recomputed for the rig, no resampling); for the moved cameras also ``virtual`` with their offsets
   compensated at 10 m (``depth``);
2. ``--frames`` frames of the ``val`` stream (seed 0) rendered through each test rig (the same scenes and looks
   for every rig), scored with the official metric at 0-48 m: FDS, mAP and the labelled objects found (a box within
   2 m of the object's centre, same class, score at least the model's demo threshold);
3. the test rigs: the training rig; every lens centre moved by 1, 2, 4, 8 px; every camera turned on its mount by 2,
   5, 10 degrees about each axis (yaw, pitch, roll); every camera moved 5, 10, 20 cm forward, and 10 cm up; wide-angle
   lenses of other models (double sphere, EUCM, Mei, Kannala-Brandt) at their own resolutions, one camchain with a
   model per camera; the share of the training lens's field each covers is reported;
4. the front end's cost: the virtual file's frame time against the training file's (each session timed alone, the
   median of blocks after warm-up; the two files in turn for ``--rounds`` rounds: the medians of the rounds' times,
   and the median of the rounds' ratios as the share, which a load that drifts between rounds moves less); with
   ``--cost-only``, ``--model`` may also name another file (``model_files.model_path``: an official config's stem,
   the full-size file ``benchmarks/official_configs.py`` wrote, or a path), and ``--int8`` measures the int8 file
   the export writes (``model_files``) in its place.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import harness
import numpy as np
from model_files import MODEL_HELP, SHIPPED, model_path

from fisheye_infer import Detector
from fisheye_infer.cameras.camera_models import DoubleSphere, ExtendedUnified, KannalaBrandt, OCamModel, Omnidirectional
from fisheye_infer.cameras.rig import Rig, RigCamera
from fisheye_infer.eval.evaluate import evaluate_results
from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.scenes.streams import SyntheticFrames

FOUND_RADIUS_M = 2.0
#: The distance at which the moved cameras' offsets are compensated in the third way.
DEPTH_M = 10.0
#: Lenses of the wide-angle models, each scaled so that its 220-degree field fits its image (a 109.5-degree ray 250 px
#: from the centre of a 512x512 image; 236 px in the 640x480 EUCM one), then one narrower lens: TUM-VI's cam0
#: calibration (Kannala-Brandt, 512x512), which sees about 195 degrees.
WIDE_LENSES: dict[str, object] = {
    "double sphere": DoubleSphere(
        width=512, height=512, fx=113.6, fy=113.6, cx=255.5, cy=255.5, xi=-0.172, alpha=0.593, fov=220.0
    ),
    "EUCM 640x480": ExtendedUnified(
        width=640, height=480, fx=124.8, fy=124.8, cx=319.5, cy=239.5, alpha=0.61, beta=1.07, fov=220.0
    ),
    "Mei (omni-radtan)": Omnidirectional(
        width=512,
        height=512,
        xi=1.7,
        fx=395.5,
        fy=395.5,
        cx=255.5,
        cy=255.5,
        distortion=(-0.2, 0.05, 0.0, 0.0),
        fov=220.0,
    ),
    "Kannala-Brandt": KannalaBrandt(
        width=512,
        height=512,
        fx=136.5,
        fy=136.5,
        cx=255.5,
        cy=255.5,
        k=(0.00348, 0.000715, -0.00205, 0.000203),
        fov=220.0,
    ),
}
NARROW_LENS = KannalaBrandt(
    width=512,
    height=512,
    fx=190.98,
    fy=190.97,
    cx=254.93,
    cy=256.90,
    k=(0.00348, 0.000715, -0.00205, 0.000203),
    fov=195.0,
)


def camera_rotation(axis: str, degrees: float) -> np.ndarray:
    """4x4 rotation about a camera axis (OpenCV frame): yaw about y, pitch about x, roll about z."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    r = {
        "yaw": [[c, 0, s], [0, 1, 0], [-s, 0, c]],
        "pitch": [[1, 0, 0], [0, c, -s], [0, s, c]],
        "roll": [[c, -s, 0], [s, c, 0], [0, 0, 1]],
    }[axis]
    m = np.eye(4)
    m[:3, :3] = r
    return m


def with_cameras(rig: Rig, name: str, change: Callable[[RigCamera], RigCamera]) -> Rig:
    return rig.model_copy(update={"name": name, "cameras": tuple(change(c) for c in rig.cameras)})


def test_rigs(rig: Rig, quick: bool) -> dict[str, Rig]:
    """Test rig name -> rig, the cameras keeping the training rig's names."""

    def moved_lens(px: float) -> Callable[[RigCamera], RigCamera]:
        def change(c: RigCamera) -> RigCamera:
            m = c.model
            assert isinstance(m, OCamModel)
            lens = m.model_copy(update={"center_row": m.center_row + px, "center_col": m.center_col + px})
            return c.model_copy(update={"model": lens})

        return change

    def turned(axis: str, degrees: float) -> Callable[[RigCamera], RigCamera]:
        return lambda c: c.model_copy(
            update={"cam2lidar": tuple(map(tuple, (c.matrix @ camera_rotation(axis, degrees)).tolist()))}
        )

    def shifted(dx: float, dz: float) -> Callable[[RigCamera], RigCamera]:
        def change(c: RigCamera) -> RigCamera:
            m = c.matrix.copy()
            m[0, 3] += dx
            m[2, 3] += dz
            return c.model_copy(update={"cam2lidar": tuple(map(tuple, m.tolist()))})

        return change

    def lens(model: object) -> Callable[[RigCamera], RigCamera]:
        return lambda c: c.model_copy(update={"model": model})

    rigs = {"training rig": rig}
    for px in (1, 8) if quick else (1, 2, 4, 8):
        rigs[f"lens centres +{px} px"] = with_cameras(rig, f"lens+{px}", moved_lens(px))
    for axis in ("yaw", "pitch", "roll"):
        for deg in (5,) if quick else (2, 5, 10):
            rigs[f"{axis} {deg}°"] = with_cameras(rig, f"{axis}{deg}", turned(axis, deg))
    for cm in (10,) if quick else (5, 10, 20):
        rigs[f"{cm} cm forward"] = with_cameras(rig, f"fwd{cm}", shifted(cm / 100, 0.0))
    rigs["10 cm up"] = with_cameras(rig, "up10", shifted(0.0, 0.1))
    for name, model in WIDE_LENSES.items():
        rigs[name] = with_cameras(rig, name, lens(model))
    rigs["Kannala-Brandt 195° (TUM-VI cam0)"] = with_cameras(rig, "narrow", lens(NARROW_LENS))
    models = list(WIDE_LENSES.values())
    rigs["camchain, a model per camera"] = rig.model_copy(
        update={
            "name": "mixed",
            "cameras": tuple(c.model_copy(update={"model": m}) for c, m in zip(rig.cameras, models)),
        }
    )
    return rigs


def score(detector: Detector, stream: SyntheticFrames, rig: Rig, frames: int, threshold: float) -> dict[str, float]:
    """FDS and mAP (0-48 m) and the share of labelled objects found on ``frames`` frames rendered through ``rig``."""
    gt, pred = {}, {}
    found = labelled = 0
    for i in range(frames):
        _, pictures, records = stream.draw(i, rig)
        dets = detector.detect(pictures)
        gt[str(i)], pred[str(i)] = list(records), dets.to_nuscenes()
        kept = dets.filter(min_score=threshold)
        for rec in records:
            labelled += 1
            centre = np.asarray(rec["translation"][:2])
            near = [
                n == rec["detection_name"] and np.hypot(*(b[:2] - centre)) < FOUND_RADIUS_M
                for b, n in zip(kept.boxes, kept.names)
            ]
            found += any(near)
    report = evaluate_results(gt, pred, EvalConfig())
    return {"FDS": report.FDS, "mAP": report.mAP, "found": found / max(1, labelled)}


def frame_ms(path: Path, threads: int, images: dict[str, np.ndarray], blocks: int = 5, per_block: int = 5) -> float:
    """Median per-frame time of ``path`` over blocks after warm-up, the session timed alone."""
    detector = Detector(path, threads=threads)
    for _ in range(3):
        detector.detect(images)
    times = []
    for _ in range(blocks):
        t0 = time.perf_counter()
        for _ in range(per_block):
            detector.detect(images)
        times.append((time.perf_counter() - t0) / per_block * 1e3)
    return float(np.median(times))


def main() -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="10 frames, fewer rigs")
    bench.parser.add_argument(
        "--model",
        default="fisheye-bevdet-compact",
        help="a shipped model's name; with --cost-only also " + MODEL_HELP,
    )
    bench.parser.add_argument("--frames", type=int, default=40)
    bench.parser.add_argument("--threads", type=int, default=2)
    bench.parser.add_argument("--cost-only", action="store_true", help="only the front end's cost (step 4)")
    bench.parser.add_argument("--rounds", type=int, default=5, help="rounds of the cost timing, the two files in turn")
    bench.parser.add_argument("--int8", action="store_true", help="with --cost-only: the model's int8 file")
    args = bench.parse()
    from fisheye_infer.export.exporter import export
    from fisheye_infer.export.rebake import rebake
    from fisheye_infer.models.pretrained import PRETRAINED, pretrained

    frames = 10 if args.quick else args.frames
    rounds = 1 if args.quick else args.rounds
    shipped = pretrained(args.model) if args.model in {m.name for m in PRETRAINED} else None
    if shipped is None and not args.cost_only:
        raise SystemExit(f"--model {args.model}: not a shipped model (other files: --cost-only)")
    if args.int8 and not args.cost_only:
        raise SystemExit("--int8 measures the front end's cost only: add --cost-only")
    rows, costs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        if args.int8:
            trained = model_path(next((k for k, v in SHIPPED.items() if v == args.model), args.model), "int8")
        elif shipped is not None:
            trained = Path(tmp) / "model.onnx"
            export(shipped.checkpoint, trained, config=shipped.config, rig=shipped.rig, frames=1)
        else:
            trained = model_path(args.model)
        rig = read_meta(trained).rig
        stream = SyntheticFrames(rig, "val", 0)
        for n, (name, test_rig) in enumerate(test_rigs(rig, args.quick).items() if not args.cost_only else ()):
            same_kind = all(
                isinstance(c.model, OCamModel) and (c.model.width, c.model.height) == (t.model.width, t.model.height)
                for c, t in zip(test_rig.cameras, rig.cameras)
            )
            moved = "forward" in name or "up" in name
            ways = {
                "tables": {"mode": "tables"} if same_kind else None,
                "virtual": {"mode": "virtual"},
                f"virtual at {DEPTH_M:g} m": {"mode": "virtual", "depth": DEPTH_M} if moved else None,
            }
            row: dict[str, object] = {"test rig": name}
            for way, options in ways.items():
                if options is None:
                    row.update({f"{way} FDS": None, f"{way} mAP": None, f"{way} found": None})
                    continue
                path = Path(tmp) / f"{n}-{way}.onnx"
                meta = rebake(trained, test_rig, path, **options)  # type: ignore[arg-type]
                if way == "virtual":
                    assert meta.virtual_cameras is not None
                    row["coverage"] = min(c.coverage for c in meta.virtual_cameras.cameras)
                detector = Detector(path, threads=args.threads)
                assert shipped is not None
                s = score(detector, stream, test_rig, frames, shipped.score_threshold)
                row.update({f"{way} FDS": s["FDS"], f"{way} mAP": s["mAP"], f"{way} found": s["found"]})
            print(row, file=sys.stderr, flush=True)
            rows.append(row)
        _, pictures, _ = stream.draw(0, rig)
        virtual = Path(tmp) / "0-virtual.onnx"
        rebake(trained, rig, virtual, mode="virtual")
        for threads in (1, 2):
            files = (trained, virtual)
            timed = [tuple(frame_ms(f, threads, pictures) for f in files) for _ in range(rounds)]
            plain, front = (float(np.median(t)) for t in zip(*timed))
            share = float(np.median([v / p for p, v in timed])) - 1  # each round's pair, timed one after the other
            costs.append(
                {
                    "threads": threads,
                    "rounds": rounds,
                    "training file ms": plain,
                    "virtual file ms": front,
                    "front end share": share,
                }
            )
    tables = {"Front end cost": costs}
    if rows:
        tables = {f"FDS at 0-48 m on {frames} val frames, {args.model}": rows, **tables}
    bench.save(args, tables)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
