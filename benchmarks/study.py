"""The paper's comparisons (its Tables 2, 3 and 4) measured with this product on held-out synthetic scenes.

    python benchmarks/study.py [--model fisheye-bevdet-compact --model runs/pinhole/model.pth ...] [--frames 200]

Each ``--model`` is a shipped model's name, a run folder of ``fisheye-infer train`` or a checkpoint in
one (``config.py`` and ``rig.json`` beside it); the default is every shipped model. Every model is
scored on the same scenes: the validation stream's first ``--frames`` frames (``fisheye-infer synth
--stream val``), rendered through that model's own rig, so a fisheye and a pinhole model see the same
objects, lighting and ground. A model trained on some of its rig's cameras (``fisheye-infer train
--cameras``) is that reduced layout retrained, as the paper trained each. The tables, each row beside
the paper's figure where the paper has one:

- Table 2 (RQ1/RQ2): every model trained with all its cameras, 0-48 m;
- Table 3 (RF1/RF2): the paper's reduced layouts, at run time (degraded mode: the model trained with
  every camera sees only some) and retrained: front + rear and left + right of a four-fisheye rig,
  a six-pinhole rig without its front and rear cameras;
- Table 4 (RF3): 0-30 m against 0-48 m;
- the paper's findings, each with its direction in the paper and in ours, and whether the held-out
  scenes resolve ours: a paired bootstrap over the scenes (``--draws`` resamples, the same for every
  model) gives the 90% interval of our difference; one that holds 0 is "not resolved".
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import harness
import numpy as np
import paper
from model_card import RANGES, heldout, run

from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, PINHOLE_CAMERAS, Rig
from fisheye_infer.eval.bootstrap import frame_draws, interval, resampled_fds, resolved
from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import breakdown_label, evaluate_results
from fisheye_infer.eval.metrics import EvalConfig, MetricsReport
from fisheye_infer.runtime.detector import Detector

Row = dict[str, Any]
#: A score's key: (architecture, cameras, how reduced); see ``_scores``.
Key = tuple[str, str, str]
NEAR, FAR = RANGES
ALL = "all"
#: How a reduced layout's row came about: the model trained with every camera, some missing at run time,
#: or a model trained on those cameras alone.
RUN_TIME, RETRAINED = "run time", "retrained"
#: The paper's families: (spherical detector, perspective-rectified, cylindrically rectified, six pinhole cameras).
FAMILIES = (
    ("fisheye-bevdet", "fisheye-bevdet-persp", "fisheye-bevdet-cyl", "pinhole-bevdet"),
    ("fisheye-petr", "fisheye-petr-persp", "fisheye-petr-cyl", "pinhole-petr"),
)


#: The share of the resampled differences a finding's interval holds.
LEVEL = 0.9


@dataclass(frozen=True)
class Scored:
    """A model's detections on the held-out scenes with some of its cameras: the metric's report, and the boxes it
    scored with their samples in token order, the same scenes in the same order for every model (resamples pair
    them)."""

    report: MetricsReport
    gt: EvalBoxes
    pred: EvalBoxes

    @classmethod
    def of(cls, gt: dict[str, Any], pred: dict[str, Any]) -> Scored:
        """From the records the detector wrote: ``{sample_token: [record, ...]}`` for ground truth and predictions."""
        tokens, names = sorted(gt), EvalConfig().class_names
        return cls(
            evaluate_results(gt, pred),
            EvalBoxes.from_records(gt, names, tokens, ground_truth=True),
            EvalBoxes.from_records(pred, names, tokens),
        )


@dataclass(frozen=True)
class Studied:
    """One model's results: with all the cameras it was trained for, and (for a whole rig) each of the paper's
    layouts at run time."""

    name: str
    arch: str
    layout: str  # ALL, or the reduced layout the model was trained for ("front + rear", ...)
    full: Scored
    layouts: dict[str, Scored]


#: The paper's two-camera layouts of a four-camera rig, by the words their cameras' names end in.
PAIRS = {"front + rear": ("front", "rear"), "left + right": ("left", "right")}


def _end(camera: str) -> str:
    """Which of front, rear, back, left and right ``camera``'s name ends in ("" for none)."""
    low = camera.lower()
    return next((word for word in ("front", "rear", "back", "left", "right") if low.endswith(word)), "")


def paper_layouts(cameras: tuple[str, ...]) -> dict[str, list[str]]:
    """The paper's reduced layouts of a rig, by its camera names (those of the paper's rigs, or of a user's rig
    named alike): a four-camera rig's front + rear and left + right, each where two cameras' names end so, and a
    six-camera rig without its front and rear cameras."""
    if len(cameras) == 4:
        pairs = {label: [c for word in words for c in cameras if _end(c) == word] for label, words in PAIRS.items()}
        return {label: used for label, used in pairs.items() if len(used) == 2}
    centre = [c for c in cameras if _end(c) in ("front", "rear", "back")]
    return {"without front and rear": [c for c in cameras if c not in centre]} if centre else {}


def trained_layout(arch: str, cameras: tuple[str, ...]) -> str:
    """``ALL`` for a model of a whole rig; for one trained on some of the paper's rig (the six pinhole cameras for
    ``pinhole-*``, else the four fisheye cameras), the paper's name of that layout, else its cameras. A model of
    another rig is of a whole rig unless it has two fisheye cameras whose names give one of ``PAIRS`` (``--cameras
    cam_front,cam_rear`` of a user's four-camera rig)."""
    paper_rig = PINHOLE_CAMERAS if arch.startswith("pinhole-") else FISHEYE3DOD_CAMERAS
    if set(cameras) < set(paper_rig):
        for label, used in paper_layouts(paper_rig).items():
            if set(used) == set(cameras):
                return label
        return " + ".join(cameras)
    ends = tuple(sorted(_end(c) for c in cameras))
    pairs = [label for label, words in PAIRS.items() if ends == words and not arch.startswith("pinhole-")]
    return pairs[0] if pairs else ALL


def model_files(spec: str) -> tuple[str, Path, Path, Path]:
    """(name, checkpoint, config, rig) of a shipped model's name, a run folder or a checkpoint in one; a checkpoint
    without the ``config.py`` and ``rig.json`` of its run beside it is refused, before any work."""
    from fisheye_infer.models.pretrained import PRETRAINED

    for shipped in PRETRAINED:
        if spec == shipped.name:
            return shipped.name, shipped.checkpoint, shipped.config, shipped.rig
    path = Path(spec)
    ckpt = path / "model.pth" if path.is_dir() else path
    if not ckpt.is_file():
        raise SystemExit(
            f"--model {spec}: neither a shipped model ({', '.join(m.name for m in PRETRAINED)}), a run folder with "
            "a model.pth, nor a file"
        )
    config, rig = ckpt.with_name("config.py"), ckpt.with_name("rig.json")
    missing = [p.name for p in (config, rig) if not p.is_file()]
    if missing:
        raise SystemExit(
            f"--model {spec}: no {' and no '.join(missing)} beside {ckpt.name}; the study takes a checkpoint in the "
            "run folder `fisheye-infer train` wrote, with its configuration and rig"
        )
    return ckpt.parent.name, ckpt, config, rig


def study(spec: str, work: Path, frames: int, seed: int, threads: int) -> Studied:
    """Export one model and score it on the held-out scenes through its rig, with all its cameras and, for a whole
    rig, each of the paper's layouts."""
    from fisheye_infer.export.exporter import export

    start = time.perf_counter()
    name, ckpt, config, rig_file = model_files(spec)
    rig = Rig.load(rig_file)
    data = heldout(rig, work / f"heldout-{rig.hash}", frames, seed)
    exported = export(ckpt, work / f"{name}.onnx", config=config, rig=rig, progress=lambda _: None)
    detector = Detector(exported.path, threads=threads)
    cameras, arch = detector.info.cameras, detector.info.architecture
    layout = trained_layout(arch, cameras)
    runtime = paper_layouts(cameras) if layout == ALL else {}
    layouts = {label: Scored.of(*run(detector, data, used)[1]) for label, used in runtime.items() if used}
    full = Scored.of(*run(detector, data, list(cameras))[1])
    print(
        f"{name}: {arch}, {layout} cameras, FDS {full.report.distance[FAR].FDS:.3f} at {FAR}"
        + (f"; at run time {', '.join(layouts)}" if layouts else "")
        + f" ({time.perf_counter() - start:.0f} s)",
        file=sys.stderr,
    )
    return Studied(name, arch, layout, full, layouts)


def comparable(models: list[Studied]) -> None:
    """Refuse two models of the same architecture and layout (each finding compares one model with another) and
    models scored on different scenes (a finding's resamples pair them scene by scene)."""
    seen: dict[tuple[str, str], str] = {}
    for m in models:
        other = seen.setdefault((m.arch, m.layout), m.name)
        if other != m.name:
            raise SystemExit(
                f"--model {other} and --model {m.name} are both {m.arch} trained with {m.layout} cameras; "
                "study one model of each architecture and layout at a time"
            )
        if m.full.gt.tokens != models[0].full.gt.tokens:
            raise SystemExit(
                f"--model {models[0].name} and --model {m.name} were scored on different scenes "
                f"({len(models[0].full.gt.tokens)} and {len(m.full.gt.tokens)} frames); a finding pairs them by scene"
            )


def _paper(values: tuple[float, ...] | None, index: int) -> float | None:
    return values[index] if values else None


def table2(models: list[Studied]) -> list[Row]:
    rows = []
    for m in models:
        if m.layout != ALL:
            continue
        s = m.full.report.distance[FAR]
        method, cameras = paper.METHOD.get(m.arch, (m.arch, ""))
        ref = paper.TABLE2.get(m.arch)
        rows.append(
            {
                "model": m.name,
                "paper's row": f"{method}, {cameras}",
                "FDS": s.FDS,
                "mAP": s.mAP,
                "mATE": s.mATE,
                "mASE": s.mASE,
                "mAOE": s.mAOE,
                "paper FDS": _paper(ref, 0),
                "paper mAP": _paper(ref, 1),
            }
        )
    return rows


def _layout_rows(m: Studied) -> list[tuple[str, str, MetricsReport]]:
    """(cameras, how, report) of a model's rows in Table 3."""
    if m.layout != ALL:
        return [(m.layout, RETRAINED, m.full.report)]
    return [*((label, RUN_TIME, scored.report) for label, scored in m.layouts.items()), (ALL, "-", m.full.report)]


def table3(models: list[Studied]) -> list[Row]:
    rows = []
    for m in models:
        ref = paper.TABLE3.get(m.arch, {})
        for label, how, report in _layout_rows(m):
            s = report.distance[FAR]
            rows.append(
                {
                    "model": m.name,
                    "cameras": label,
                    "reduced": how,
                    "FDS": s.FDS,
                    "mAP": s.mAP,
                    "paper FDS": _paper(ref.get(label), 0),
                    "paper mAP": _paper(ref.get(label), 1),
                }
            )
    return rows


def table4(models: list[Studied]) -> list[Row]:
    rows = []
    for m in models:
        if m.layout != ALL:
            continue
        ref = paper.TABLE4.get(m.arch, {})
        for label in RANGES:
            s = m.full.report.distance[label]
            rows.append(
                {
                    "model": m.name,
                    "range": label,
                    "FDS": s.FDS,
                    "mAP": s.mAP,
                    "paper FDS": _paper(ref.get(label), 0),
                    "paper mAP": _paper(ref.get(label), 1),
                }
            )
    return rows


def _scores(models: list[Studied]) -> dict[Key, tuple[Scored, str]]:
    """What is scored and at which range (FAR: 0-48 m) by (architecture, cameras, how reduced): (arch, ALL, ALL) for
    all cameras, (arch, layout, RUN_TIME) or (arch, layout, RETRAINED) for a reduced layout, and (arch, ALL, NEAR)
    at 0-30 m."""
    out: dict[Key, tuple[Scored, str]] = {}
    for m in models:
        if m.layout != ALL:
            out[(m.arch, m.layout, RETRAINED)] = (m.full, FAR)
            continue
        out[(m.arch, ALL, ALL)] = (m.full, FAR)
        out[(m.arch, ALL, NEAR)] = (m.full, NEAR)
        for label, scored in m.layouts.items():
            out[(m.arch, label, RUN_TIME)] = (scored, FAR)
    return out


class Resampled:
    """The FDS of each scored key on one set of resamples of the held-out scenes (``comparable`` models share their
    scenes), computed when first asked."""

    def __init__(self, scores: dict[Key, tuple[Scored, str]], draws: int) -> None:
        self.scores = scores
        frames = len(next(iter(scores.values()))[0].gt.tokens) if scores else 1
        self.draws = frame_draws(frames, draws)
        self.ranges = {breakdown_label(r): r for r in EvalConfig().distance_breakdown}
        self.cache: dict[Key, np.ndarray] = {}

    def __getitem__(self, key: Key) -> np.ndarray:
        if key not in self.cache:
            scored, label = self.scores[key]
            self.cache[key] = resampled_fds(scored.gt, scored.pred, self.draws, ref_range=self.ranges[label])
        return self.cache[key]


def _paper_scores() -> dict[Key, float]:
    """The paper's FDS under ``_scores``' keys (its reduced layouts were retrained; run-time rows compare with them)."""
    out: dict[Key, float] = {}
    for arch, row in paper.TABLE2.items():
        out[(arch, ALL, ALL)] = row[0]
    for arch, ranges in paper.TABLE4.items():
        out[(arch, ALL, NEAR)] = ranges[NEAR][0]
    for arch, layouts in paper.TABLE3.items():
        for label, (fds, _map) in layouts.items():
            if label != ALL:
                out[(arch, label, RUN_TIME)] = out[(arch, label, RETRAINED)] = fds
    return out


def _comparisons() -> list[tuple[str, tuple[Key, Key], tuple[Key, Key] | None]]:
    """Each of the paper's comparisons: (what, (first, second), None) for FDS against FDS, or
    (what, (all, reduced), (all, reduced)) for the FDS lost by one rig against that lost by another."""
    out: list[tuple[str, tuple[Key, Key], tuple[Key, Key] | None]] = []

    def name(arch: str) -> str:
        method, cameras = paper.METHOD[arch]
        return method if method.startswith("Fisheye") else f"{method} {cameras}"

    for spherical, persp, cyl, pinhole in FAMILIES:
        whole = {arch: (arch, ALL, ALL) for arch in (spherical, persp, cyl, pinhole)}
        for rectified in (persp, cyl):  # RQ1: pinhole-based detectors on rectified fisheye images
            out.append((f"{name(pinhole)} vs {name(rectified)}", (whole[pinhole], whole[rectified]), None))
        for other in (persp, cyl, pinhole):  # RQ2: the spherical model against the rest
            out.append((f"{name(spherical)} vs {name(other)}", (whole[spherical], whole[other]), None))
        for how in (RUN_TIME, RETRAINED):
            front_rear, left_right = (spherical, "front + rear", how), (spherical, "left + right", how)
            out.append((f"{name(spherical)}: front + rear vs left + right, {how}", (front_rear, left_right), None))
            out.append((f"{name(spherical)}: all four vs front + rear, {how}", (whole[spherical], front_rear), None))
            out.append(
                (
                    f"FDS lost without front and rear: {name(pinhole)} vs {name(spherical)} left + right, {how}",
                    (whole[pinhole], (pinhole, "without front and rear", how)),
                    (whole[spherical], left_right),
                )
            )
        out.append((f"{name(spherical)}: 0-30 m vs 0-48 m", ((spherical, ALL, NEAR), whole[spherical]), None))
    out.append(("FisheyeBEVDet vs FisheyePETR", (("fisheye-bevdet", ALL, ALL), ("fisheye-petr", ALL, ALL)), None))
    return out


def _verdict(paper_first_larger: bool, low: float, high: float) -> str:
    if not resolved(low, high):
        return "not resolved"
    return "yes" if paper_first_larger == (low > 0) else "no"


def findings(models: list[Studied], draws: int = 200) -> list[Row]:
    """Each of the paper's comparisons that the studied models allow: which side is larger (FDS, 0-48 m, or the
    FDS a rig loses) in the paper and here, our difference's interval over ``draws`` resamples of the scenes, and
    whether ours goes the paper's way ("not resolved" when the interval holds 0)."""
    scores, theirs = _scores(models), _paper_scores()
    resampled = Resampled(scores, draws)
    ours = {key: scored.report.distance[label].FDS for key, (scored, label) in scores.items()}

    def value(values: Any, pair: tuple[Key, Key], lost: tuple[Key, Key] | None) -> tuple[Any, Any]:
        if lost is None:
            return values[pair[0]], values[pair[1]]
        return values[pair[0]] - values[pair[1]], values[lost[0]] - values[lost[1]]

    rows = []
    for what, pair, lost in _comparisons():
        needed = [*pair, *(lost or ())]
        if not all(key in ours for key in needed):
            continue
        first, second = value(ours, pair, lost)
        first_drawn, second_drawn = value(resampled, pair, lost)
        low, high = interval(first_drawn - second_drawn, LEVEL)
        said = value(theirs, pair, lost) if all(key in theirs for key in needed) else None
        rows.append(
            {
                "comparison (FDS, 0-48 m)": what,
                "paper": f"{said[0]:.3f} vs {said[1]:.3f}" if said else None,
                "ours": f"{first:.3f} vs {second:.3f}",
                f"ours, difference ({LEVEL:.0%} interval)": f"{first - second:+.3f} ({low:+.3f} to {high:+.3f})",
                "same direction": _verdict(said[0] > said[1], low, high) if said else None,
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    from fisheye_infer.models.pretrained import PRETRAINED

    bench = harness.Benchmark(__file__, __doc__, quick="20 held-out frames")
    bench.parser.add_argument(
        "--model",
        action="append",
        help="a shipped model's name, a run folder or a checkpoint in one (default: every shipped model)",
    )
    bench.parser.add_argument("--frames", type=int, default=200, help="held-out frames (default 200)")
    bench.parser.add_argument("--seed", type=int, default=0, help="seed of the validation stream (default 0)")
    bench.parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads (default 2)")
    bench.parser.add_argument("--work-dir", default="artifacts/study", help="folder for the frames and the files")
    bench.parser.add_argument(
        "--draws", type=int, default=200, help="resamples of the scenes behind each finding's interval (default 200)"
    )
    args = bench.parse(argv)
    if args.draws < 1:
        bench.parser.error(f"--draws: expected at least 1 resample, got {args.draws}")
    if args.quick:
        args.frames = 20
    specs = args.model or [m.name for m in PRETRAINED]
    for spec in specs:
        model_files(spec)
    models: list[Studied] = []
    for spec in specs:
        models.append(study(spec, Path(args.work_dir), args.frames, args.seed, args.threads))
        comparable(models)
    bench.save(
        args,
        {
            f"Table 2 (RQ1/RQ2): every model with all its cameras, 0-48 m, {args.frames} held-out scenes": table2(
                models
            ),
            "Table 3 (RF1/RF2): reduced layouts, at run time (degraded mode) or retrained, 0-48 m": table3(models),
            "Table 4 (RF3): 0-30 m against 0-48 m": table4(models),
            "The paper's findings: which side is larger, in the paper and here": findings(models, args.draws),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
