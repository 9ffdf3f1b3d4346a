"""The benchmark harness and the report: timing order and statistics, the JSON result, the generated pages.

Nothing here times anything real: the callables are cheap and the clock is a fake where figures are checked.
"""

from __future__ import annotations

import ast
import json
import re
import sys
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import harness
import report
import run_all

HOST = {
    "cpu": "Test CPU 9000 (family 6, model 143)",
    "cpu_count": 2,
    "platform": "Linux-test",
    "python": "3.11.7",
    "onnxruntime": "1.20.0",
    "avx512": True,
    "vnni": True,
    "avx2": True,
    "gpus": [],
    "cpu_name": "Test CPU 9000",
    "cpu_family": "6",
    "cpu_model": "143",
    "cpu_flags": ["avx2", "avx512f"],
    "numpy": "2.0.0",
}
HOST = {**HOST, "slug": harness.machine_slug(HOST)}
WHEN = datetime(2025, 1, 2, 3, 4, 5, tzinfo=timezone.utc)
DOC = "Speed of the thing, measured.\n\n    python benchmarks/thing.py\n\nMore words."


class FakeClock:
    """A clock that moves only when a candidate says how long it took."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def takes(self, ms: list[float]) -> Any:
        durations = iter(ms)

        def call() -> None:
            self.now += next(durations) / 1e3

        return call


def bench_for(tmp_path: Path, name: str = "thing") -> harness.Benchmark:
    script = tmp_path / f"{name}.py"
    script.write_text("")
    bench = harness.Benchmark(script, DOC, quick="less of it")
    bench.parser.add_argument("--frames", type=int, default=10)
    return bench


def saved(
    tmp_path: Path,
    tables: dict[str, list[dict[str, Any]]],
    argv: list[str] | None = None,
    when: datetime = WHEN,
    name: str = "thing",
) -> Path:
    bench = bench_for(tmp_path, name)
    args = bench.parse([*(argv or []), "--out-dir", str(tmp_path / "results")])
    return bench.save(args, tables, host=HOST, when=when, echo=False)


# -- timing ------------------------------------------------------------------------------------------------------


def test_alternate_calls_each_candidate_in_turns_warmup_first() -> None:
    calls: list[str] = []
    timings = harness.alternate({"A": lambda: calls.append("A"), "B": lambda: calls.append("B")}, rounds=3, repeat=2)
    assert calls == ["A"] * 3 + ["B"] * 3 + ["A"] * 3 + ["B"] * 3 + ["A"] * 3 + ["B"] * 3
    assert {name: len(t.values) for name, t in timings.items()} == {"A": 6, "B": 6}  # warm-up calls are not timed


def test_in_turns_flip_reverses_every_other_round() -> None:
    calls: list[str] = []
    candidates = {"A": lambda: calls.append("A") or 1, "B": lambda: calls.append("B") or 2}
    result = harness.in_turns(candidates, rounds=4, flip=True)
    assert calls == ["A", "B", "B", "A", "A", "B", "B", "A"]
    assert result == {"A": [1, 1, 1, 1], "B": [2, 2, 2, 2]}


def test_alternate_samples_and_statistics_with_a_fake_clock() -> None:
    clock = FakeClock()
    # each round: one warm-up call, then two timed ones
    a_ms, b_ms = [9.0, 1.0, 2.0, 9.0, 3.0, 4.0], [9.0, 10.0, 30.0, 9.0, 20.0, 40.0]
    timings = harness.alternate({"A": clock.takes(a_ms), "B": clock.takes(b_ms)}, rounds=2, repeat=2, clock=clock)
    assert timings["A"].values == pytest.approx((1.0, 2.0, 3.0, 4.0))
    assert timings["B"].values == pytest.approx((10.0, 30.0, 20.0, 40.0))
    b = timings["B"]
    assert b.median == pytest.approx(25.0)
    assert b.p10 == pytest.approx(np.percentile([10, 20, 30, 40], 10))
    assert b.p90 == pytest.approx(np.percentile([10, 20, 30, 40], 90))
    assert b.spread == pytest.approx((b.p90 - b.p10) / 25.0)
    assert b.row() == {"median ms": b.median, "p10 ms": b.p10, "p90 ms": b.p90, "n": 4}


def test_measure_and_sync() -> None:
    clock_calls: list[str] = []
    timing = harness.measure(
        lambda: clock_calls.append("call"), repeat=3, warmup=2, sync=lambda: clock_calls.append("sync")
    )
    assert len(timing.values) == 3
    assert clock_calls == ["call", "call", "sync"] + ["call", "sync"] * 3


# -- machine -----------------------------------------------------------------------------------------------------


def test_machine_describes_this_machine() -> None:
    host = harness.machine()
    for key in ("cpu", "cpu_name", "cpu_flags", "cpu_count", "python", "onnxruntime", "numpy", "gpus", "slug"):
        assert key in host
    assert host["slug"] == harness.machine_slug(host)


@pytest.mark.parametrize(
    "host, slug",
    [
        (
            {
                "cpu_name": "Intel(R) Xeon(R) Platinum 8480C CPU @ 2.00GHz",
                "cpu_family": "6",
                "cpu_model": "143",
                "cpu_count": 8,
                "gpus": [],
            },
            "intel-xeon-platinum-8480c-f6-m143-8cpu",
        ),
        (
            {
                "cpu_name": "AMD EPYC",
                "cpu_family": "25",
                "cpu_model": "17",
                "cpu_count": 2,
                "gpus": ["NVIDIA H200, 570.1"],
            },
            "amd-epyc-f25-m17-2cpu-h200",
        ),
        ({"cpu": "arm64", "cpu_count": 10, "gpus": ["NVIDIA A10G, 1", "NVIDIA A10G, 1"]}, "arm64-10cpu-2x-a10g"),
    ],
)
def test_machine_slug(host: dict[str, Any], slug: str) -> None:
    assert harness.machine_slug(host) == slug


# -- the JSON result ---------------------------------------------------------------------------------------------


def test_result_is_written_and_read_back(tmp_path: Path) -> None:
    rows = [{"step": "metric", "median ms": 123.456789123, "n": 3}, {"step": "records", "median ms": np.float64(0.5)}]
    path = saved(tmp_path, {"Metric time": rows}, ["--quick", "--frames", "5"])
    assert path.parent == tmp_path / "results"
    assert path.name == f"thing-{HOST['slug']}-20250102T030405Z.json"
    [result] = harness.read_results(tmp_path / "results")
    assert set(result) == {*harness.KEYS, "load_average"} and len(result["load_average"]) == 3
    assert result["benchmark"] == "thing"
    assert result["description"] == "Speed of the thing, measured."
    assert result["command"].startswith(f"python {tmp_path / 'thing.py'} --quick --frames 5 --out-dir ")
    assert result["machine"] == HOST
    assert result["date"] == "2025-01-02T03:04:05Z"
    assert result["parameters"] == {"quick": True, "frames": 5}
    assert result["measurements"] == {
        "Metric time": [{"step": "metric", "median ms": 123.457, "n": 3}, {"step": "records", "median ms": 0.5}]
    }


def test_command_is_relative_to_the_repository() -> None:
    bench = harness.Benchmark(ROOT / "benchmarks" / "metric_speed.py", DOC)
    bench.parser.add_argument("--frames")
    bench.parser.add_argument("name")
    bench.parse(["--frames", "10", "two words"])
    assert bench.command == "python benchmarks/metric_speed.py --frames 10 'two words'"


def test_read_results_names_a_file_that_is_not_a_result(tmp_path: Path) -> None:
    (tmp_path / "other.json").write_text(json.dumps({"benchmark": "x"}))
    with pytest.raises(ValueError, match="other.json"):
        harness.read_results(tmp_path)


# -- tables and the report ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "value, text",
    [
        (1234.5, "1,234"),
        (123.44, "123"),
        (12.34, "12.3"),
        (1.234, "1.23"),
        (0.01234, "0.0123"),
        (0.0, "0"),
        (3, "3"),
        (12000, "12,000"),
        (True, "yes"),
        (None, "-"),
        (float("nan"), "-"),
        (["a", 1.5], "a, 1.50"),
        ([], "-"),
        ("x", "x"),
    ],
)
def test_format_value(value: Any, text: str) -> None:
    assert harness.format_value(value) == text


def test_markdown_table_columns_and_escaping() -> None:
    table = harness.markdown_table([{"a": 1, "b": "x|y"}, {"a": 2, "c": "< 0.05"}])
    assert table.splitlines() == ["| a | b | c |", "|---|---|---|", "| 1 | x\\|y | - |", "| 2 | - | &lt; 0.05 |"]
    assert harness.markdown_table([]) == "(no rows)"  # not an empty header


def test_report_tables_carry_the_figures_command_machine_and_date(tmp_path: Path) -> None:
    rows = [{"file": "fp32", "median ms": 412.7}, {"file": "int8", "median ms": 0.0417}]
    saved(tmp_path, {"Latency": rows}, ["--quick"])
    pages = report.render(harness.read_results(tmp_path / "results"))
    assert sorted(pages) == sorted(["index.md", f"{HOST['slug']}.md"])
    page = pages[f"{HOST['slug']}.md"]
    assert report.NOTICE in page and report.NOTICE in pages["index.md"]
    assert f"({HOST['slug']}.md)" in pages["index.md"]
    section = page[page.index("### Latency") :]
    head = section.splitlines()[2]
    assert f"`python {tmp_path / 'thing.py'} --quick --out-dir {tmp_path / 'results'}`" in head
    assert "Test CPU 9000 (family 6, model 143), 2 cores" in head and "onnxruntime 1.20.0" in head
    assert "2025-01-02 03:04 UTC" in head
    assert "| fp32 | 413 |" in section and "| int8 | 0.0417 |" in section


def test_report_keeps_the_latest_result_of_each_command(tmp_path: Path) -> None:
    saved(tmp_path, {"T": [{"v": 1.0}]}, when=WHEN)
    saved(tmp_path, {"T": [{"v": 2.0}]}, when=WHEN.replace(day=3))
    saved(tmp_path, {"T": [{"v": 3.0}]}, ["--quick"], when=WHEN)
    page = report.render(harness.read_results(tmp_path / "results"))[f"{HOST['slug']}.md"]
    assert "| 2.00 |" in page and "| 3.00 |" in page and "| 1.00 |" not in page


def test_report_writes_pages_and_removes_stale_generated_ones(tmp_path: Path) -> None:
    docs = tmp_path / "docs"
    docs.mkdir()
    (docs / "gone-machine.md").write_text(f"# old\n\n{report.NOTICE}\n")
    (docs / "notes.md").write_text("# written by hand\n")
    card = tmp_path / "MODEL_CARD.md"
    empty = f"# card\n\n{report.card_begin(report.CARD_COMMAND)}\n{report.CARD_END}\n"
    card.write_text(empty)
    saved(tmp_path, {"T": [{"v": 1.0}]})
    argv = ["--results", str(tmp_path / "results"), "--docs", str(docs), "--card", f"{report.CARD_COMMAND}={card}"]
    assert report.main(argv) == 0
    assert sorted(p.name for p in docs.glob("*.md")) == sorted(["index.md", f"{HOST['slug']}.md", "notes.md"])
    assert card.read_text() == empty  # no model_card result: unchanged


def test_model_card_figures_come_from_the_latest_model_card_result(tmp_path: Path) -> None:
    begin = report.card_begin(report.CARD_COMMAND)
    card = f"# card\n\n## Figures\n\n{begin}\nold tables\n{report.CARD_END}\n\n## Limitations\n"
    result = {
        "command": report.CARD_COMMAND,
        "machine": HOST,
        "date": "2025-01-02T03:04:05Z",
        "measurements": {"Sensor failure": [{"cameras": "front + rear", "FDS 0-30 m": 0.335}]},
    }
    older = {**result, "date": "2025-01-01T00:00:00Z", "measurements": {"Sensor failure": [{"FDS 0-30 m": 0.1}]}}
    quick = {**result, "command": f"{report.CARD_COMMAND} --quick", "date": "2025-02-01T00:00:00Z"}
    text = report.card_figures([older, result, quick], card)
    block = text[text.index(begin) : text.index(report.CARD_END)]
    assert "### Sensor failure" in block and "| front + rear | 0.335 |" in block and "old tables" not in block
    assert f"`{report.CARD_COMMAND}`" in block and "| 0.100 |" not in block and "--quick" not in block
    assert text.startswith("# card\n\n## Figures") and text.endswith(f"{report.CARD_END}\n\n## Limitations\n")
    with pytest.raises(ValueError, match="no"):
        report.card_figures([result], "# a card without the markers\n")


def test_a_page_holds_the_blocks_of_several_commands() -> None:
    """Each command's latest result fills its own block; the others are left as they are."""
    first, second = "python benchmarks/study.py", "python benchmarks/study.py --model runs/a/model.pth"
    page = (
        f"# study\n\n{report.card_begin(first)}\nold first\n{report.CARD_END}\n\n## Runs\n\n"
        f"{report.card_begin(second)}\nold second\n{report.CARD_END}\n"
    )
    result = {
        "command": second,
        "machine": HOST,
        "date": "2025-01-02T03:04:05Z",
        "measurements": {"Table 2": [{"model": "a", "FDS": 0.25}]},
    }
    text = report.card_figures([result], page, second)
    assert "old first" in text and "old second" not in text and "| a | 0.25 |" in text
    assert text.index("## Runs") < text.index("| a | 0.25 |")
    assert report.card_figures([result], text, first) == text  # no result of the first command: unchanged
    with pytest.raises(ValueError, match="no"):
        report.card_figures([result], page, "python benchmarks/study.py --frames 20")


def test_committed_pages_are_what_the_report_generates() -> None:
    """Hand edits of docs/performance/ fail here: the pages come from benchmarks/results/ alone."""
    pages = report.render(harness.read_results(harness.RESULTS))
    committed = {path.name: path.read_text() for path in report.DOCS.glob("*.md")}
    assert committed == pages, "run `python benchmarks/report.py` and commit docs/performance/"


@pytest.mark.parametrize("command", list(report.CARDS))
def test_committed_model_card_figures_are_what_the_report_generates(command: str) -> None:
    """Hand edits of a card's figures fail here: they come from the latest model_card result alone."""
    card = report.CARDS[command].read_text()
    results = harness.read_results(harness.RESULTS)
    assert card == report.card_figures(results, card, command), "run `python benchmarks/report.py`"


def test_committed_pages_link_only_to_pages_beside_them() -> None:
    for path in report.DOCS.glob("*.md"):
        for target in re.findall(r"\]\(([^)]+)\)", path.read_text()):
            assert "/" not in target and (report.DOCS / target).is_file(), f"{path.name}: link {target}"


# -- the scripts -------------------------------------------------------------------------------------------------


def _scripts() -> set[str]:
    return {p.stem for p in (ROOT / "benchmarks").glob("*.py")} - {
        "harness",
        "report",
        "model_files",
        "run_all",
        "paper",
    }


def test_run_all_runs_every_benchmark() -> None:
    assert {step.script for step in run_all.STEPS} == _scripts()


@pytest.mark.parametrize("name", sorted(_scripts()))
def test_every_benchmark_is_built_on_the_harness(name: str) -> None:
    tree = ast.parse((ROOT / "benchmarks" / f"{name}.py").read_text())
    calls = [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "Benchmark"
    ]
    assert calls, f"benchmarks/{name}.py does not build a harness.Benchmark"


def test_run_all_refuses_an_unknown_benchmark(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        run_all.main(["--only", "metric_speed,nope"])
    assert exc.value.code == 2 and "nope" in capsys.readouterr().err
