"""The paper's comparisons (its Tables 2, 3 and 4) measured with this product on held-out synthetic scenes.

    python benchmarks/study.py [--model fisheye-bevdet-compact --model runs/pinhole/model.pth ...] [--frames 200]

Each ``--model`` is a shipped model's name or a trained checkpoint (``config.py`` and ``rig.json``
beside it); the default is every shipped model. Every model is scored on the same scenes: the
validation stream's first ``--frames`` frames (``fisheye-infer synth --stream val``), rendered
through that model's own rig, so a fisheye and a pinhole model see the same objects, lighting and
ground. The tables, each row beside the paper's figure where the paper has one:

- Table 2 (RQ1/RQ2): every model with all its cameras, 0-48 m;
- Table 3 (RF1/RF2): the paper's layouts at run time (degraded mode, no retraining; the paper
  retrained each): front + rear and left + right of a four-fisheye rig, a six-pinhole rig without
  its front and rear cameras;
- Table 4 (RF3): 0-30 m against 0-48 m;
- the paper's findings, each with its direction in the paper and in ours.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import harness
import paper
from model_card import RANGES, heldout, run

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.eval.metrics import MetricsReport
from fisheye_infer.runtime.detector import Detector

Row = dict[str, Any]
FAR = RANGES[1]


@dataclass(frozen=True)
class Studied:
    """One model's results: all cameras, and each layout of the paper its rig has."""

    name: str
    arch: str
    full: MetricsReport
    layouts: dict[str, MetricsReport]


def paper_layouts(cameras: tuple[str, ...]) -> dict[str, list[str]]:
    """The paper's reduced layouts of a rig, by its camera names: a four-camera rig's front + rear and left + right,
    a six-camera rig without its front and rear cameras."""
    named = {c: c.lower() for c in cameras}

    def has(word: str) -> list[str]:
        return [c for c, low in named.items() if low.endswith(word)]

    if len(cameras) == 4:
        return {"front + rear": has("front") + has("rear"), "left + right": has("left") + has("right")}
    centre = [c for c, low in named.items() if low.endswith(("front", "rear", "back"))]
    return {"without front and rear": [c for c in cameras if c not in centre]} if centre else {}


def model_files(spec: str) -> tuple[str, Path, Path, Path]:
    """(name, checkpoint, config, rig) of a shipped model's name or a checkpoint path."""
    from fisheye_infer.models.pretrained import PRETRAINED

    for shipped in PRETRAINED:
        if spec == shipped.name:
            return shipped.name, shipped.checkpoint, shipped.config, shipped.rig
    ckpt = Path(spec)
    if not ckpt.is_file():
        raise SystemExit(
            f"--model {spec}: neither a shipped model ({', '.join(m.name for m in PRETRAINED)}) nor a file"
        )
    return ckpt.parent.name, ckpt, ckpt.with_name("config.py"), ckpt.with_name("rig.json")


def study(spec: str, work: Path, frames: int, seed: int, threads: int) -> Studied:
    """Export one model and score it on the held-out scenes through its rig, with all cameras and each layout."""
    from fisheye_infer.export.exporter import export

    name, ckpt, config, rig_file = model_files(spec)
    rig = Rig.load(rig_file)
    data = heldout(rig, work / f"heldout-{rig.hash}", frames, seed)
    exported = export(ckpt, work / f"{name}.onnx", config=config, rig=rig, progress=lambda _: None)
    detector = Detector(exported.path, threads=threads)
    cameras = detector.info.cameras
    layouts = {label: run(detector, data, used)[0] for label, used in paper_layouts(cameras).items() if used}
    return Studied(name, detector.info.architecture, run(detector, data, list(cameras))[0], layouts)


def _paper(values: tuple[float, ...] | None, index: int) -> float | None:
    return values[index] if values else None


def table2(models: list[Studied]) -> list[Row]:
    rows = []
    for m in models:
        s = m.full.distance[FAR]
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


def table3(models: list[Studied]) -> list[Row]:
    rows = []
    for m in models:
        ref = paper.TABLE3.get(m.arch, {})
        for label, report in {**m.layouts, "all": m.full}.items():
            s = report.distance[FAR]
            rows.append(
                {
                    "model": m.name,
                    "cameras": label,
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
        ref = paper.TABLE4.get(m.arch, {})
        for label in RANGES:
            s = m.full.distance[label]
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


def findings(models: list[Studied]) -> list[Row]:
    """Each of the paper's comparisons that the studied models allow: which side wins (FDS, 0-48 m) in the paper
    and here."""
    fds = {m.arch: m.full.distance[FAR].FDS for m in models}
    layouts = {m.arch: {k: r.distance[FAR].FDS for k, r in m.layouts.items()} for m in models}
    pairs: list[tuple[str, float | None, float | None, float, float]] = []

    def compare(what: str, ours: tuple[float, float] | None, theirs: tuple[float, float] | None) -> None:
        if ours is not None:
            pairs.append((what, *(theirs or (None, None)), *ours))  # type: ignore[arg-type]

    for spherical, persp, cyl, pinhole in (
        ("fisheye-bevdet", "fisheye-bevdet-persp", "fisheye-bevdet-cyl", "pinhole-bevdet"),
        ("fisheye-petr", "fisheye-petr-persp", "fisheye-petr-cyl", "pinhole-petr"),
    ):
        for other in (persp, cyl, pinhole):
            if spherical in fds and other in fds:
                compare(
                    f"{paper.METHOD[spherical][0]} vs {paper.METHOD[other][0]} {paper.METHOD[other][1]}",
                    (fds[spherical], fds[other]),
                    (paper.TABLE2[spherical][0], paper.TABLE2[other][0]),
                )
        split = layouts.get(spherical, {})
        if {"front + rear", "left + right"} <= set(split):
            ref = paper.TABLE3[spherical]
            compare(
                f"{paper.METHOD[spherical][0]}: front + rear vs left + right",
                (split["front + rear"], split["left + right"]),
                (ref["front + rear"][0], ref["left + right"][0]),
            )
            compare(
                f"{paper.METHOD[spherical][0]}: all four vs front + rear",
                (fds[spherical], split["front + rear"]),
                (ref["all"][0], ref["front + rear"][0]),
            )
        near = {m.arch: m.full.distance[RANGES[0]].FDS for m in models}
        if spherical in near:
            ref4 = paper.TABLE4[spherical]
            compare(
                f"{paper.METHOD[spherical][0]}: 0-30 m vs 0-48 m",
                (near[spherical], fds[spherical]),
                (ref4["0-30 m"][0], ref4["0-48 m"][0]),
            )
    if "fisheye-bevdet" in fds and "fisheye-petr" in fds:
        compare(
            "FisheyeBEVDet vs FisheyePETR",
            (fds["fisheye-bevdet"], fds["fisheye-petr"]),
            (paper.TABLE2["fisheye-bevdet"][0], paper.TABLE2["fisheye-petr"][0]),
        )
    rows = []
    for what, p_first, p_second, first, second in pairs:
        paper_says = None if p_first is None else ("first" if p_first > p_second else "second")  # type: ignore[operator]
        ours = "first" if first > second else "second"
        rows.append(
            {
                "comparison (FDS, 0-48 m)": what,
                "paper": f"{p_first:.3f} vs {p_second:.3f}" if p_first is not None else None,
                "ours": f"{first:.3f} vs {second:.3f}",
                "same direction": None if paper_says is None else paper_says == ours,
            }
        )
    return rows


def main(argv: list[str] | None = None) -> int:
    from fisheye_infer.models.pretrained import PRETRAINED

    bench = harness.Benchmark(__file__, __doc__, quick="20 held-out frames")
    bench.parser.add_argument(
        "--model", action="append", help="a shipped model's name or a checkpoint (default: every shipped model)"
    )
    bench.parser.add_argument("--frames", type=int, default=200, help="held-out frames (default 200)")
    bench.parser.add_argument("--seed", type=int, default=0, help="seed of the validation stream (default 0)")
    bench.parser.add_argument("--threads", type=int, default=2, help="ONNX Runtime threads (default 2)")
    bench.parser.add_argument("--work-dir", default="artifacts/study", help="folder for the frames and the files")
    args = bench.parse(argv)
    if args.quick:
        args.frames = 20
    specs = args.model or [m.name for m in PRETRAINED]
    models = [study(spec, Path(args.work_dir), args.frames, args.seed, args.threads) for spec in specs]
    bench.save(
        args,
        {
            f"Table 2 (RQ1/RQ2): every model with all its cameras, 0-48 m, {args.frames} held-out scenes": table2(
                models
            ),
            "Table 3 (RF1/RF2): reduced layouts at run time (degraded mode; the paper retrained each), 0-48 m": table3(
                models
            ),
            "Table 4 (RF3): 0-30 m against 0-48 m": table4(models),
            "The paper's findings: which side wins, in the paper and here": findings(models),
        },
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
