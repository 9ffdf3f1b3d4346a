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
import report_charts
import report_index
import report_pages
import report_study
import report_tables
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
    assert page.startswith("# 2-core Test CPU 9000 (family 6, model 143)\n")
    assert f"## {report_pages.OTHER}" in page and "### thing" in page  # a benchmark GROUPS does not name
    section = page[page.index("#### Latency") :]
    assert "| fp32 | 413 |" in section and "| int8 | 0.0417 |" in section
    provenance = next(line for line in section.splitlines() if line.startswith("Command: "))
    assert section.index("| int8 |") < section.index(provenance)  # under the table
    assert f"`python {tmp_path / 'thing.py'} --quick --out-dir {tmp_path / 'results'}`" in provenance
    assert "2-core Test CPU 9000 (family 6, model 143)" in provenance and "onnxruntime 1.20.0" in provenance
    assert "2025-01-02 03:04 UTC" in provenance


def test_a_block_of_several_tables_states_its_provenance_once_and_tabs_them(tmp_path: Path) -> None:
    saved(tmp_path, {"A": [{"v": 1.0}], "B": [{"w": 2.0}]}, name="compare")
    page = report.render(harness.read_results(tmp_path / "results"))[f"{HOST['slug']}.md"]
    assert page.count("Command: ") == 1
    assert '=== "A"' in page and '=== "B"' in page and "    | 1.00 |" in page
    question, title = report_pages.GROUPS["compare"]
    assert page.index(f"## {question}") < page.index(f"### {title}") < page.index('=== "A"')


@pytest.mark.parametrize(
    "host, words",
    [
        ({**HOST, "cpu_name": "AMD EPYC", "cpu_family": "25", "cpu_model": "17"}, "2-core AMD EPYC (Zen 4)"),
        ({**HOST, "cpu_name": "AMD EPYC", "cpu_family": "25", "cpu_model": "1"}, "2-core AMD EPYC (Zen 3)"),
        (
            {**HOST, "cpu_name": "Intel(R) Xeon(R) Platinum 8480C"},
            "2-core Intel(R) Xeon(R) Platinum 8480C (Sapphire Rapids)",
        ),
        ({**HOST, "cpu_name": "Odd CPU", "cpu_family": "9", "cpu_model": "9"}, "2-core Odd CPU (family 9, model 9)"),
        ({**HOST, "gpus": ["NVIDIA H200, 570.1"]}, "2-core Test CPU 9000 (family 6, model 143), NVIDIA H200"),
    ],
)
def test_machine_in_words(host: dict[str, Any], words: str) -> None:
    assert report_tables.machine_words(host) == words


def test_fitted_table_notes_the_columns_of_one_value_and_the_long_texts() -> None:
    long = "x" * (report_tables.LONG_CELL + 1)
    rows = [{"file": "a", "threads": 2, "scope": long, "ms": 1.5}, {"file": "b", "threads": 2, "scope": "s", "ms": 2.5}]
    text = report_tables.fitted_table(rows)
    assert text.startswith("Every row: threads: 2.\n")
    assert "| file | scope | ms |" in text and "| a | note 1 | 1.50 |" in text and f"1. {long}" in text
    assert report_tables.fitted_table([{"file": "a", "threads": 2}]).count("threads") == 1  # one row: kept


def test_a_wide_table_is_split_with_the_columns_that_name_its_rows() -> None:
    rows = [
        {"model": m, "tracker": t, **{f"metric {i}": float(i) for i in range(12)}, "paper metric 3": 9.0}
        for m in ("one", "two")
        for t in ("A", "B")
    ]
    parts = report_tables.split_columns(rows)
    assert len(parts) > 1 and all(part[:2] == ["model", "tracker"] for part in parts)
    assert sum(report_tables.column_px(c, rows) for c in parts[0]) <= report_tables.PAGE_PX
    flat = [c for part in parts for c in part[2:]]
    assert sorted(flat) == sorted(c for c in rows[0] if c not in ("model", "tracker"))
    assert flat.index("paper metric 3") == flat.index("metric 3") + 1  # the paper's figure beside ours
    unique = [{"model": m, "row": f"{m} long", **{f"metric {i}": 1.0 for i in range(12)}} for m in ("a", "b")]
    assert [part[:1] for part in report_tables.split_columns(unique)[1:]] == [["model"]] * 2
    assert report_tables.split_columns(unique)[0][:2] == ["model", "row"]


def test_short_title_moves_a_long_parenthesis_out_of_the_heading() -> None:
    scope = "network: 28 weighted layers, 20 in the image backbone+neck and 8 beyond it; float32: heads"
    assert report_tables.short_title(f"int8 ({scope}) against the fp32 file") == ("int8 against the fp32 file", scope)
    title = "Table 2 (RQ1/RQ2): every model with all its cameras, 0-48 m, 200 held-out scenes"
    assert report_tables.short_title(title) == (title, "")


def _int8_result(date: str = "2025-01-02T03:04:05Z", quick: bool = False) -> dict[str, Any]:
    latency = [
        {"threads": t, "file": f, "median ms": ms}
        for t, f, ms in ((1, "fp32", 100.0), (1, "auto", 40.0), (2, "fp32", 60.0), (2, "auto", 30.0))
    ]
    return {
        "benchmark": "int8",
        "command": "python benchmarks/int8.py" + (" --quick" if quick else ""),
        "machine": HOST,
        "date": date,
        "parameters": {"quick": quick, "ckpt": "/x/models/pretrained/fisheye_bevdet_compact/model.pth"},
        "measurements": {"Latency, one frame, files in turns": latency},
    }


def test_the_index_answers_how_fast_on_what() -> None:
    quick = {**_int8_result("2025-02-01T00:00:00Z", quick=True), "measurements": {}}
    index = report_index.index_page([_int8_result(), quick])
    assert "## 2-core Test CPU 9000 (family 6, model 143)" in index and "### fisheye-bevdet-compact" in index
    assert "| precision | threads | frame ms | frames/s | speed-up |" in index
    assert "| fp32 | 1 | 100 | 10.0 | 1.00 |" in index and "| int8 | 2 | 30.0 | 33.3 | 2.00 |" in index
    assert "Command: `python benchmarks/int8.py` · 2-core Test CPU 9000" in index
    assert f"../assets/charts/frame-time-{HOST['slug']}.svg" in index


def test_the_headline_prefers_the_result_that_times_most_precisions_then_not_quick() -> None:
    quick = _int8_result("2025-02-01T00:00:00Z", quick=True)
    [(result, rows)] = report_index.headline([_int8_result(), quick]).values()
    assert result["command"] == "python benchmarks/int8.py" and len(rows) == 4


def test_the_stage_table_says_why_its_stages_add_up_to_more() -> None:
    stages = "fisheye-infer bench: graph stages, batch 1"
    result = {"benchmark": "compare", **_int8_result(), "measurements": {stages: [{"stage": "head", "ms": 1.0}]}}
    block = "\n".join(report_pages.result_block({**result, "benchmark": "compare"}))
    assert "nothing is fused across a cut" in block


@pytest.mark.parametrize(
    "comparison, finding",
    [
        ("BEVDet 6 x P vs BEVDet 4 x F, perspective-rectified", "RQ1"),
        ("FisheyeBEVDet vs BEVDet 6 x P", "RQ1"),
        ("FisheyeBEVDet vs BEVDet 4 x F, cylindrically rectified", "RQ2"),
        ("FDS lost without front and rear: BEVDet 6 x P vs FisheyeBEVDet left + right, run time", "RF1"),
        ("FisheyePETR: front + rear vs left + right, run time", "RF2"),
        ("FisheyeBEVDet: 0-30 m vs 0-48 m", "RF3"),
    ],
)
def test_each_comparison_of_the_study_has_its_finding(comparison: str, finding: str) -> None:
    assert report_study.finding_of(comparison).startswith(finding)


def test_the_study_page_opens_with_the_answer() -> None:
    """docs/study.md: the answer (findings table and chart) before the method and the tables."""
    page = (ROOT / "docs" / "study.md").read_text()
    begin = report.answer_begin(report.ANSWER_COMMAND)
    assert page.index(begin) < page.index("## Method") < page.index(report.card_begin(report.ANSWER_COMMAND))
    answer = page[page.index(begin) : page.index(report.CARD_END, page.index(begin))]
    assert "| finding |" in answer and "assets/charts/study-bevdet-family.svg" in answer
    assert answer.count("Command: ") == 1
    results = harness.read_results(harness.RESULTS)
    assert report.study_answer(results, page) == page, "run `python benchmarks/report.py`"


def test_committed_charts_are_there_and_are_svg() -> None:
    """Every chart the committed results give is under docs/assets/charts/ and is an SVG document, and no other.

    The bytes are not compared with a fresh drawing: matplotlib's SVG differs between its versions. Within one
    version the drawing is deterministic (``test_charts_are_deterministic``).
    """
    import xml.etree.ElementTree as ET

    names = report_charts.planned(report.latest(harness.read_results(harness.RESULTS)), report.STUDY_CHARTS)
    assert {"int8-accuracy.svg", "study-bevdet-family.svg", "study-shipped.svg"} <= set(names)
    assert sorted(p.name for p in report_charts.CHARTS.glob("*.svg")) == sorted(names)
    for name in names:
        root = ET.parse(report_charts.CHARTS / name).getroot()
        assert root.tag == "{http://www.w3.org/2000/svg}svg", name
    for page in [*report.DOCS.glob("*.md"), ROOT / "docs" / "study.md"]:
        for target in re.findall(r"\]\(([^)]*assets/charts/[^)]+)\)", page.read_text()):
            assert (page.parent / target).resolve().is_file(), f"{page.name}: chart {target}"


def test_charts_are_deterministic(tmp_path: Path) -> None:
    """Two drawings of the same results are the same bytes (fixed hash salt, no date)."""
    pytest.importorskip("matplotlib")
    results = [_int8_result()]
    first = report_charts.write_charts(results, {}, tmp_path / "a")
    second = report_charts.write_charts(results, {}, tmp_path / "b")
    assert [p.name for p in first] == [f"frame-time-{HOST['slug']}.svg"]
    assert first[0].read_bytes() == second[0].read_bytes()
    assert b"<dc:date>" not in first[0].read_bytes()


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
    assert not list((tmp_path / "assets" / "charts").glob("*.svg"))  # no result that a chart shows


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
    assert f"Command: `{report.CARD_COMMAND}`" in block and "| 0.100 |" not in block and "--quick" not in block
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


def test_committed_pages_link_only_to_pages_beside_them_their_sections_and_charts() -> None:
    for path in report.DOCS.glob("*.md"):
        text = path.read_text()
        anchors = {report_pages.anchor(line.lstrip("#")) for line in text.splitlines() if line.startswith("#")}
        for target in re.findall(r"\]\(([^)]+)\)", text):
            if target.startswith("#"):
                assert target[1:] in anchors, f"{path.name}: link {target}"
                continue
            if target.startswith(f"{report_index.CHARTS}/"):
                assert (report.DOCS / target).resolve().is_file(), f"{path.name}: chart {target}"
                continue
            assert "/" not in target and (report.DOCS / target).is_file(), f"{path.name}: link {target}"


# -- the scripts -------------------------------------------------------------------------------------------------


def _scripts() -> set[str]:
    return {p.stem for p in (ROOT / "benchmarks").glob("*.py") if not p.stem.startswith("report_")} - {
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
