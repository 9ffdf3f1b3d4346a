"""What every benchmark shares: its command line, alternated timing, the machine, and one JSON result per run.

    bench = harness.Benchmark(__file__, __doc__, quick="1,000 frames")   # --out-dir, --quick
    bench.parser.add_argument("--frames", type=int, default=10_000)
    args = bench.parse()
    timings = harness.alternate({"fp32": run_fp32, "int8": run_int8}, rounds=5, repeat=3)
    bench.save(args, {"Latency": [{"file": name, **t.row()} for name, t in timings.items()]})

Candidates are timed in turns (A, B, A, B, ...) so that drift on a shared machine falls on all of
them alike. A result is one JSON file, ``<benchmark>-<machine slug>-<UTC date-time>.json`` under
``benchmarks/results/``: the benchmark, the command that reproduces it, the machine, the date, the
parameters and the measurements, as tables (title -> rows of column -> value). ``benchmarks/report.py``
turns the results into the pages under ``docs/performance/``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
SCHEMA = 1
#: The instruction-set flags that change which kernels ONNX Runtime, OpenVINO and numpy run.
SIMD_PREFIXES = ("sse4", "avx", "amx", "fma", "f16c")
KEYS = ("schema", "benchmark", "description", "command", "machine", "date", "parameters", "measurements")

T = TypeVar("T")
Row = Mapping[str, Any]
Tables = Mapping[str, Sequence[Row]]


@dataclass(frozen=True)
class Stats:
    """Median and spread (10th to 90th percentile) of repeated measurements: the median resists a
    neighbour's load spikes, the spread shows them."""

    values: tuple[float, ...]

    @property
    def median(self) -> float:
        return float(np.median(self.values))

    @property
    def p10(self) -> float:
        return float(np.percentile(self.values, 10))

    @property
    def p90(self) -> float:
        return float(np.percentile(self.values, 90))

    @property
    def spread(self) -> float:
        """p90 - p10, relative to the median."""
        return (self.p90 - self.p10) / self.median if self.median else math.nan

    def row(self, unit: str = "ms") -> dict[str, float | int]:
        """The columns a table shows for these measurements."""
        return {f"median {unit}": self.median, f"p10 {unit}": self.p10, f"p90 {unit}": self.p90, "n": len(self.values)}


def in_turns(candidates: Mapping[str, Callable[[], T]], rounds: int, flip: bool = False) -> dict[str, list[T]]:
    """Each candidate called once per round, in turn, and what each call returned.

    ``flip``: every other round runs the candidates in reverse order (A B, B A, ...), so that none
    always follows the same neighbour (ONNX Runtime's threads spin on for a while after a call).
    """
    out: dict[str, list[T]] = {name: [] for name in candidates}
    names = list(candidates)
    for r in range(rounds):
        for name in names[::-1] if flip and r % 2 else names:
            out[name].append(candidates[name]())
    return out


def alternate(
    candidates: Mapping[str, Callable[[], object]],
    rounds: int,
    repeat: int = 1,
    warmup: int = 1,
    flip: bool = False,
    sync: Callable[[], object] = lambda: None,
    clock: Callable[[], float] = time.perf_counter,
) -> dict[str, Stats]:
    """Milliseconds per call of each candidate, timed in turns: each round calls every candidate
    ``warmup`` times untimed, then ``repeat`` times timed.

    The untimed calls absorb what the candidate before left behind (worker threads still spinning,
    caches filled with its data), which is that candidate's cost, not this one's. ``sync`` waits for
    asynchronous work (a GPU's) before the clock is read.
    """

    def block(fn: Callable[[], object]) -> Callable[[], list[float]]:
        def run() -> list[float]:
            for _ in range(warmup):
                fn()
            sync()
            times = []
            for _ in range(repeat):
                t0 = clock()
                fn()
                sync()
                times.append((clock() - t0) * 1e3)
            return times

        return run

    blocks = in_turns({name: block(fn) for name, fn in candidates.items()}, rounds, flip)
    return {name: Stats(tuple(t for chunk in chunks for t in chunk)) for name, chunks in blocks.items()}


def session_call(session: Any, feeds: Mapping[str, np.ndarray]) -> Callable[[], object]:
    """One run of an ONNX Runtime session on ``feeds`` as ``Detector`` runs it: denormal floats flushed to zero on the
    calling thread (``fisheye_infer.runtime.denormals``)."""
    from fisheye_infer.runtime.denormals import flushed_denormals

    def run() -> object:
        with flushed_denormals():
            return session.run(None, dict(feeds))

    return run


def measure(fn: Callable[[], object], repeat: int, warmup: int = 1, sync: Callable[[], object] = lambda: None) -> Stats:
    """Milliseconds per call of one function alone: ``warmup`` untimed calls, then ``repeat`` timed ones."""
    return alternate({"": fn}, 1, repeat, warmup, sync=sync)[""]


def machine() -> dict[str, Any]:
    """The machine a result was measured on: ``fisheye-infer bench``'s description, the CPU's name and
    instruction-set flags, numpy's version, and a slug that names the machine in file names."""
    from fisheye_infer.tools.bench import machine as runtime_machine
    from fisheye_infer.tools.cpu import cpu_info

    cpu = cpu_info()
    host = {
        **runtime_machine(),
        "cpu_name": cpu.name,
        "cpu_family": cpu.family,
        "cpu_model": cpu.model,
        "cpu_flags": sorted(flag for flag in cpu.flags if flag.startswith(SIMD_PREFIXES)),
        "numpy": np.__version__,
    }
    return {**host, "slug": machine_slug(host)}


def _slug(text: str) -> str:
    text = re.sub(r"\((r|tm)\)|\bcpu\b|\bprocessor\b|@.*$", " ", text.lower())
    return re.sub(r"[^a-z0-9]+", "-", text).strip("-")


def machine_slug(host: Mapping[str, Any]) -> str:
    """``amd-epyc-f25-m17-2cpu``, ``...-h200`` with a GPU: the CPU's name, generation and core count, and the GPUs.

    The generation is part of it because cloud machines often name the CPU only by its line ("AMD EPYC").
    """
    parts = [_slug(host.get("cpu_name") or host["cpu"]) or "cpu"]
    if host.get("cpu_family") and host.get("cpu_model"):
        parts.append(f"f{host['cpu_family']}-m{host['cpu_model']}")
    parts.append(f"{host['cpu_count']}cpu")
    gpus = [_slug(gpu.split(",")[0]).removeprefix("nvidia-") for gpu in host.get("gpus", [])]
    if gpus:
        parts.append(gpus[0] if len(gpus) == 1 else f"{len(gpus)}x-{gpus[0]}")
    return "-".join(parts)


def format_value(value: Any) -> str:
    """One table cell: numbers to the precision a measurement carries, lists joined, nothing as a dash."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return f"{value:,}"
    if isinstance(value, float):
        size = abs(value)
        if size >= 100 or value == 0:
            return f"{value:,.0f}" if size >= 100 else "0"
        return f"{value:.1f}" if size >= 10 else f"{value:.2f}" if size >= 1 else f"{value:.3g}"
    if isinstance(value, (list, tuple)):
        return ", ".join(format_value(v) for v in value) or "-"
    return str(value)


def markdown_table(rows: Sequence[Row]) -> str:
    """A Markdown table of ``rows``; its columns are the rows' keys in the order they first appear. Markdown's
    characters in the cells are escaped, so that a node name or a flag shows as it is. No rows: a line that says so."""
    if not rows:
        return "(no rows)"
    columns = list(dict.fromkeys(key for row in rows for key in row))
    cell = lambda value: re.sub(r"([\\`*_\[\]|])", r"\\\1", format_value(value)).replace("<", "&lt;").replace("\n", " ")
    lines = ["| " + " | ".join(cell(c) for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell(row.get(c)) for c in columns) + " |" for row in rows]
    return "\n".join(lines)


def _plain(value: Any) -> Any:
    """JSON-ready: paths as strings, numpy scalars as numbers, floats to 6 significant digits (keeps files small)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float):
        return None if not math.isfinite(value) else float(f"{value:.6g}")
    if isinstance(value, (str, int, bool)) or value is None:
        return value
    return str(value)


class Benchmark:
    """One benchmark script: its command line (the shared options, then its own) and its result."""

    def __init__(self, script: str | Path, doc: str | None, quick: str | None = None) -> None:
        """``script``: the script's ``__file__``; ``doc``: its docstring (the first paragraph says what
        it measures); ``quick``: what ``--quick`` cuts, when the script has a quick variant."""
        self.script = Path(script).resolve()
        self.name = self.script.stem
        self.description = " ".join((doc or "").strip().split("\n\n")[0].split())
        self.parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
        self.parser.add_argument(
            "--out-dir", type=Path, default=RESULTS, help="folder of the JSON results (default benchmarks/results)"
        )
        if quick:
            self.parser.add_argument("--quick", action="store_true", help=f"a short run: {quick}")
        self.argv: list[str] = []

    def parse(self, argv: Sequence[str] | None = None) -> argparse.Namespace:
        self.argv = list(sys.argv[1:] if argv is None else argv)
        return self.parser.parse_args(self.argv)

    @property
    def command(self) -> str:
        """The command line that reproduces this run, from the repository's root."""
        try:
            script = self.script.relative_to(ROOT).as_posix()
        except ValueError:
            script = str(self.script)
        return shlex.join(["python", script, *self.argv])

    def save(
        self,
        args: argparse.Namespace,
        measurements: Tables,
        *,
        host: Mapping[str, Any] | None = None,
        when: datetime | None = None,
        echo: bool = True,
    ) -> Path:
        """Write the result to ``args.out_dir`` and return its path; ``echo`` also prints the tables."""
        host = dict(host or machine())
        hidden = {action.dest for action in self.parser._actions if action.help == argparse.SUPPRESS}  # worker modes
        when = (when or datetime.now(timezone.utc)).astimezone(timezone.utc).replace(microsecond=0)
        result = {
            "schema": SCHEMA,
            "benchmark": self.name,
            "description": self.description,
            "command": self.command,
            "machine": host,
            "date": when.strftime("%Y-%m-%dT%H:%M:%SZ"),
            "load_average": list(os.getloadavg()),
            "parameters": {k: v for k, v in vars(args).items() if k != "out_dir" and k not in hidden},
            "measurements": {title: list(rows) for title, rows in measurements.items()},
        }
        path = Path(args.out_dir) / f"{self.name}-{host['slug']}-{when.strftime('%Y%m%dT%H%M%SZ')}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(_plain(result), indent=1) + "\n")
        if echo:
            for title, rows in measurements.items():
                print(f"\n## {title}\n\n{markdown_table(rows)}")
            print(f"\nwrote {path}")
        return path


def read_results(folder: str | Path = RESULTS) -> list[dict[str, Any]]:
    """Every result under ``folder``, by machine, benchmark and date; a file that is not one is named in the error."""
    results = []
    for path in sorted(Path(folder).glob("*.json")):
        result = json.loads(path.read_text())
        absent = [key for key in KEYS if key not in result]
        if absent or result["schema"] != SCHEMA:
            raise ValueError(f"{path}: not a benchmark result (schema {result.get('schema')!r}, missing {absent})")
        results.append(result)
    return sorted(results, key=lambda r: (r["machine"]["slug"], r["benchmark"], r["date"], r["command"]))


def missing(names: Iterable[str]) -> list[str]:
    """The modules of ``names`` that cannot be imported here (an optional runtime a benchmark compares with)."""
    import importlib.util

    return [name for name in names if importlib.util.find_spec(name) is None]
