"""Which modules an int8 file keeps float32, chosen by measuring, so that ``--int8`` alone writes a file
that passes its gate.

    searched = search_int8("model.onnx", "model.int8.onnx", FrameReader(calibration), frames, Comparison(),
                           start=architecture_float("model.onnx"))

Every file built here comes from one calibration (ONNX Runtime's calibration cache, see ``quantize``: a
build after the first costs no inference) and is judged as the gate judges it (``int8_parity`` on the
comparison frames, against fp32 outputs computed once):

1. start: scope ``network`` with the architecture's ``int8_float`` modules float32. It passes: done.
2. sensitivity: the start's int8 layers are grouped into at most ``MAX_CANDIDATES`` modules
   (``candidate_modules``); each is built float32 on top of the start, and its gain is the share of the
   fp32 top-50 boxes it brings back. One that passes on its own is chosen (the largest gain).
3. most sensitive first: the modules with a gain are kept float32 together, one more at a time, up to
   ``MAX_FLOAT_MODULES``, until a file passes.
4. last resort: scope ``trunk`` (the image backbone and neck alone in int8).
5. none passes: nothing chosen; the caller refuses with the table of every trial (``Int8Search``), or
   with ``force`` keeps the trial that kept the most, which is what the output then holds.

The int8 error of a detector is spread over its layers: one module float32 brings back a point or two
of the share, so the ranking needs the boxes themselves, not a layer-by-layer error. The ranking and
the gate use the same comparison frames; figures on frames of their own are the model card's
(``benchmarks/model_card.py``).
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx

from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, Int8Search, Int8Trial, ReducedParityReport
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.session import create_session
from fisheye_infer.tools.cpu import cpu_info

from .graph_stages import name_nodes
from .int8_parity import file_outputs, int8_parity
from .int8_scope import int8_layer_modules
from .options import Comparison
from .quantize import FrameReader, quantize

__all__ = ["MAX_CANDIDATES", "MAX_FLOAT_MODULES", "Searched", "candidate_modules", "search_int8", "search_table"]

#: The most modules whose sensitivity is measured (one build and judgement each).
MAX_CANDIDATES = 12
#: The most modules the search keeps float32 beyond the start before it falls back to the trunk scope.
MAX_FLOAT_MODULES = 5
#: Alternated timed runs of each file for the speed-up the search reports.
SPEED_ROUNDS = 7


@dataclass(frozen=True)
class Searched:
    """What ``search_int8`` leaves at its output: the file of the chosen trial (or, when none passed, of
    the trial that kept the most, if ``force`` asked for it), its scope, float modules and parity."""

    scope: str
    float_modules: tuple[str, ...]
    parity: ReducedParityReport
    record: Int8Search


def candidate_modules(modules: Sequence[str], limit: int = MAX_CANDIDATES) -> list[str]:
    """Group layers by module into state-dict prefixes, at most ``limit`` of them, in graph order.

    ``modules`` holds the module of each int8 layer (``int8_layer_modules``). The groups start as the
    top-level modules (``img_backbone``, ``pts_bbox_head``, ...: never fewer groups than those); the group
    with the most layers is split into its children (``img_backbone.layer1``, ...) while the count stays
    within ``limit``. Layers of no known module (``""``) cannot be named and are left out.
    """
    layers = [m for m in modules if m]
    groups: dict[str, list[str]] = {}
    for m in layers:
        groups.setdefault(m.split(".")[0], []).append(m)
    while True:
        splits = {p: _children(p, members) for p, members in groups.items()}
        splittable = [p for p in groups if len(splits[p]) > 1]
        if not splittable:
            break
        largest = max(splittable, key=lambda p: len(groups[p]))  # first in graph order among equals
        if len(groups) - 1 + len(splits[largest]) > limit:
            break
        groups = {
            key: value
            for p, members in groups.items()
            for key, value in (splits[p].items() if p == largest else [(p, members)])
        }
    first = {m: i for i, m in reversed(list(enumerate(layers)))}
    return sorted(groups, key=lambda p: min(first[m] for m in groups[p]))


def _children(prefix: str, members: list[str]) -> dict[str, list[str]]:
    """``members`` grouped by the next component below ``prefix``, passing through a single child
    (``view_transform`` -> ``view_transform.depthnet``); a layer of ``prefix`` itself keeps its group."""
    while True:
        depth = prefix.count(".") + 1
        kids: dict[str, list[str]] = {}
        for m in members:
            kids.setdefault(m if m == prefix else ".".join(m.split(".")[: depth + 1]), []).append(m)
        if len(kids) == 1 and next(iter(kids)) != prefix:
            prefix = next(iter(kids))
            continue
        return kids


def search_int8(
    fp32_path: str | Path,
    out: str | Path,
    calibration: FrameReader,
    frames: np.ndarray,
    comparison: Comparison,
    *,
    start: Sequence[str] = (),
    weight_bits: int,
    force: bool = False,
    progress: Callable[[str], None] = print,
) -> Searched:
    """Build and judge int8 files of ``fp32_path`` as the module docstring says; the kept one is at ``out``."""
    began = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="fisheye-int8-search-") as tmp:
        search = _Search(Path(fp32_path), Path(out), calibration, frames, comparison, weight_bits, Path(tmp), progress)
        chosen = search.run(tuple(start))
        kept = chosen if chosen is not None else (_best(search.trials) if force else None)
        if kept is not None:
            search.build(kept)
    shown = kept if kept is not None else _best(search.trials)
    record = Int8Search(
        trials=tuple(search.trials),
        chosen=chosen,
        speedup=_speedup(search.src, search.out, frames[:1], comparison.threads) if chosen is not None else None,
        threads=comparison.threads,
        cpu=cpu_info().label,
        seconds=time.perf_counter() - began,
    )
    trial = search.trials[shown]
    return Searched(trial.scope, trial.float_modules, search.reports[shown], record)


class _Search:
    """The trials of one search: each builds a file at ``out`` from the shared calibration and judges it."""

    def __init__(
        self,
        src: Path,
        out: Path,
        calibration: FrameReader,
        frames: np.ndarray,
        comparison: Comparison,
        weight_bits: int,
        workdir: Path,
        progress: Callable[[str], None],
    ) -> None:
        self.src, self.out, self.calibration, self.frames = src, out, calibration, frames
        self.comparison, self.weight_bits, self.progress = comparison, weight_bits, progress
        self.cache = workdir / "ranges.json"
        self.model = onnx.load(str(src), load_external_data=False)
        name_nodes(self.model)  # once, so that each trial's count of int8 layers reads it without a copy
        self.reference = file_outputs(src, frames, comparison.threads)
        self.trials: list[Int8Trial] = []
        self.reports: list[ReducedParityReport] = []
        self.at_out: int | None = None  # the trial whose file ``out`` holds

    def run(self, start: tuple[str, ...]) -> int | None:
        """Steps 1-4 of the module docstring: the index of the trial chosen, None when none passed."""
        first = self.attempt("start", "network", start)
        self.progress(f"int8 search [start] network, float32: {', '.join(start) or 'none'}: {self.line(first)}")
        if first.passed:
            return 0
        candidates = candidate_modules(int8_layer_modules(self.model, "network", start))
        self.progress(f"int8 search [sensitivity] each of {len(candidates)} modules float32 on top of the start")
        gains: dict[str, tuple[float, int]] = {}
        for module in candidates:
            trial = self.attempt("sensitivity", "network", (*start, module))
            gains[module] = (trial.top_matched_fraction - first.top_matched_fraction, len(self.trials) - 1)
            self.progress(f"  + {module}: {self.line(trial)} ({gains[module][0]:+.1%})")
        ranked = sorted((m for m in candidates if gains[m][0] > 0), key=lambda m: -gains[m][0])
        alone = [gains[m][1] for m in ranked if self.trials[gains[m][1]].passed]
        if alone:
            return alone[0]
        for count in range(2, min(MAX_FLOAT_MODULES, len(ranked)) + 1):
            trial = self.attempt("float", "network", (*start, *ranked[:count]))
            self.progress(f"int8 search [float] + {', '.join(ranked[:count])}: {self.line(trial)}")
            if trial.passed:
                return len(self.trials) - 1
        trial = self.attempt("trunk", "trunk", start)
        self.progress(f"int8 search [trunk] the image backbone and neck alone: {self.line(trial)}")
        return len(self.trials) - 1 if trial.passed else None

    def attempt(self, step: str, scope: str, floats: tuple[str, ...]) -> Int8Trial:
        """Build the file of ``scope`` with ``floats`` float32 at ``out`` and judge it; the trial, recorded."""
        self.quantize(scope, floats)
        c = self.comparison
        report = int8_parity(self.src, self.out, self.frames, c.threads, c.min_kept, reference=self.reference)
        trial = Int8Trial(
            step=step,
            scope=scope,
            float_modules=floats,
            int8_layers=len(int8_layer_modules(self.model, scope, floats)),
            top_matched_fraction=report.top_matched_fraction,
            top_matched_standard_error=report.top_matched_standard_error or 0.0,
            passed=report.passed,
        )
        self.trials.append(trial)
        self.reports.append(report)
        self.at_out = len(self.trials) - 1
        return trial

    def build(self, index: int) -> None:
        """Leave trial ``index``'s file at ``out`` (built again unless it is the last one built)."""
        if self.at_out != index:
            self.quantize(self.trials[index].scope, self.trials[index].float_modules)
            self.at_out = index

    def quantize(self, scope: str, floats: tuple[str, ...]) -> None:
        quantize(
            self.src,
            self.out,
            self.calibration,
            scope=scope,
            keep_float=floats,
            weight_bits=self.weight_bits,
            calibration_cache=self.cache,
        )

    def line(self, trial: Int8Trial) -> str:
        """One trial in words, for progress."""
        spread = f" +- {trial.top_matched_standard_error:.1%}" if trial.top_matched_standard_error else ""
        verdict = "passes" if trial.passed else f"below {self.comparison.min_kept:.0%}"
        kept = f"{trial.top_matched_fraction:.1%}{spread} of the fp32 top-50 kept"
        return f"{kept} ({trial.int8_layers} int8 layers) -> {verdict}"


def _best(trials: Sequence[Int8Trial]) -> int:
    """The trial that kept the most of the fp32 top-50 (the earliest among equals)."""
    return max(range(len(trials)), key=lambda i: (trials[i].top_matched_fraction, -i))


def _speedup(fp32_path: Path, int8_path: Path, frame: np.ndarray, threads: int) -> float:
    """fp32 time / int8 time for one frame: the median ratio over ``SPEED_ROUNDS`` alternated runs, after a
    warm-up run of each, at ``threads`` intra-op threads."""
    feeds = {INPUT_IMAGES: frame, INPUT_CAMERA_VALID: np.ones(frame.shape[:2], bool)}
    sessions = [create_session(p, threads=threads, providers=["CPUExecutionProvider"]) for p in (fp32_path, int8_path)]
    ratios = []
    with flushed_denormals():
        for session in sessions:
            session.run(None, feeds)
        for _ in range(SPEED_ROUNDS):
            seconds = []
            for session in sessions:
                began = time.perf_counter()
                session.run(None, feeds)
                seconds.append(time.perf_counter() - began)
            ratios.append(seconds[0] / seconds[1])
    return float(np.median(ratios))


def search_table(record: Int8Search, min_kept: float) -> list[str]:
    """The trials as lines of a table: step, scope, int8 layers, share kept (a sensitivity trial's gain over
    the start beside it) and the float32 modules (after the start: those beyond the start's); ``*`` marks
    the trial written."""
    start = record.trials[0]
    lines = ["  trial  step         scope    int8 layers  kept                      float32 modules"]
    for i, t in enumerate(record.trials):
        spread = f" +- {t.top_matched_standard_error:.1%}" if t.top_matched_standard_error else ""
        gain = t.top_matched_fraction - start.top_matched_fraction
        kept = f"{t.top_matched_fraction:.1%}{spread}" + (f" ({gain:+.1%})" if t.step == "sensitivity" else "")
        beyond = [m for m in t.float_modules if m not in start.float_modules]
        floats = (", ".join(t.float_modules) or "none") if i == 0 else " + ".join(["start", *beyond])
        lines.append(
            f" {'*' if i == record.chosen else ' '}{i + 1:>5}  {t.step:<11}  {t.scope:<7}  {t.int8_layers:>11}  "
            f"{kept:<24}  {floats}"
        )
    return [*lines, f"  (* written; the gate: {min_kept:.0%} of the fp32 top-50 boxes within 0.5 m, same label)"]
