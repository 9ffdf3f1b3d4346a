"""The report's charts, as SVG under ``docs/assets/charts/``: frame time, the accuracy fp16 and int8 keep, the study.

Needs ``matplotlib`` (the ``dev`` extra). The files are deterministic for one matplotlib version: a fixed
``svg.hashsalt``, no date in the metadata, glyphs drawn as paths.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import harness
import report_index
import report_study

CHARTS = harness.ROOT / "docs" / "assets" / "charts"
STYLE: dict[str, Any] = {
    "svg.hashsalt": "fisheye-infer",
    "svg.fonttype": "path",
    "font.size": 9,
    "axes.spines.top": False,
    "axes.spines.right": False,
}
Bars = Sequence[tuple[str, Mapping[str, float | None]]]


def grouped_bars(
    path: Path,
    panels: Sequence[tuple[str, Bars]],
    series: Sequence[str],
    *,
    xlabel: str,
    title: str,
    fmt: str = "{:.3g}",
) -> None:
    """Write a chart of horizontal grouped bars: panels one above the other, in each one group per label and one
    bar per series, each bar with its value.

    Args:
        path: The SVG file to write.
        panels: (panel title or "", groups) per panel; a group is (label, series -> value or None), drawn from the top.
        series: The series in each group, in order (one colour each, named in the legend).
        xlabel: What the bars measure.
        title: The chart's title.
        fmt: How a bar's value is written beside it.
    """
    import matplotlib

    matplotlib.use("svg")
    import matplotlib.pyplot as plt

    sizes = [len(groups) * (0.16 * len(series) + 0.12) + (0.3 if name else 0.1) for name, groups in panels]
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    with matplotlib.rc_context(STYLE):
        fig, axes = plt.subplots(
            len(panels), 1, figsize=(7.0, sum(sizes) + 1.0), sharex=True, height_ratios=sizes, squeeze=False
        )
        step = 0.8 / len(series)
        for ax, (name, groups) in zip(axes[:, 0], panels):
            for s, key in enumerate(series):
                drawn = [(g - 0.4 + step * (s + 0.5), values.get(key)) for g, (_, values) in enumerate(groups)]
                drawn = [(y, v) for y, v in drawn if v is not None]
                bars = ax.barh(
                    [y for y, _ in drawn], [v for _, v in drawn], height=step * 0.9, color=colours[s], label=key
                )
                ax.bar_label(bars, labels=[fmt.format(v) for _, v in drawn], padding=2, fontsize=7)
            ax.set_yticks(range(len(groups)), [label for label, _ in groups])
            ax.set_ylim(len(groups) - 0.5, -0.5)
            if name:
                ax.set_title(name, loc="left", fontsize=9)
        axes[-1, 0].set_xlabel(xlabel)
        axes[0, 0].margins(x=0.12)
        handles, labels = axes[0, 0].get_legend_handles_labels()
        fig.suptitle(title, x=0.01, ha="left", fontsize=10)
        fig.legend(handles, labels, loc="upper right", ncols=len(series), fontsize=8, frameon=False)
        fig.tight_layout(rect=(0, 0, 1, 0.98))
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, format="svg", metadata={"Date": None})
        plt.close(fig)


def frame_time_chart(path: Path, timed: Mapping[str, tuple[Any, Sequence[Mapping[str, Any]]]], machine: str) -> None:
    """Frame time by model and precision, one bar per thread count.

    Args:
        path: The SVG file to write.
        timed: ``report_index.headline``'s answer for one machine.
        machine: The machine in words.
    """
    groups: dict[str, dict[str, float | None]] = {}
    for model, (_, rows) in timed.items():
        for row in rows:
            groups.setdefault(f"{model}\n{row['precision']}", {})[f"{row['threads']} thread(s)"] = row["frame ms"]
    series = sorted({s for values in groups.values() for s in values}, key=lambda s: int(s.split()[0]))
    grouped_bars(
        path, [("", list(groups.items()))], series, xlabel="ms per frame (median)", title=f"Frame time, {machine}"
    )


def accuracy_chart(path: Path, accuracy: Mapping[str, tuple[Any, Sequence[Mapping[str, Any]]]]) -> None:
    """FDS of each shipped model's fp32, fp16 and int8 files, per range.

    Args:
        path: The SVG file to write.
        accuracy: ``report_index.precision_accuracy``'s answer.
    """
    panels = [
        (model, [(row["range"], {p: row.get(f"FDS {p}") for p in report_index.PRECISIONS}) for row in rows])
        for model, (_, rows) in accuracy.items()
    ]
    grouped_bars(path, panels, report_index.PRECISIONS, xlabel="FDS (higher is better)", title="FDS by precision")


def study_chart(path: Path, result: Mapping[str, Any]) -> None:
    """Our FDS beside the paper's for the rows of a study result's Tables 2 to 4 that the paper has.

    Args:
        path: The SVG file to write.
        result: A ``study.py`` result.
    """
    panels = [
        (panel, [(label, {"ours": ours, "paper": paper}) for label, ours, paper in bars])
        for panel, bars in report_study.study_bars(result)
    ]
    grouped_bars(
        path,
        panels,
        ("ours", "paper"),
        xlabel="FDS (higher is better)",
        title="The study's tables: our FDS and the paper's",
    )


def planned(results: Sequence[Mapping[str, Any]], studies: Mapping[str, str]) -> dict[str, Callable[[Path], None]]:
    """The charts the results allow: file name -> the function that draws it into a path.

    Args:
        results: The latest result of each (machine, benchmark, command).
        studies: Study command -> its chart's file name.

    Returns:
        File name under ``docs/assets/charts/`` -> a function of the path to write.
    """
    plan: dict[str, Callable[[Path], None]] = {}
    for slug in sorted({r["machine"]["slug"] for r in results}):
        ours = [r for r in results if r["machine"]["slug"] == slug]
        timed = report_index.headline(ours)
        if timed:
            words = report_index.machine_words(ours[-1]["machine"])
            plan[report_index.chart_name("frame-time", slug)] = partial(frame_time_chart, timed=timed, machine=words)
    accuracy = report_index.precision_accuracy(results)
    if accuracy:
        plan[report_index.chart_name("int8-accuracy")] = partial(accuracy_chart, accuracy=accuracy)
    for command, name in studies.items():
        ours = [r for r in results if r["command"] == command]
        if ours:
            plan[name] = partial(study_chart, result=max(ours, key=lambda r: r["date"]))
    return plan


def write_charts(results: Sequence[Mapping[str, Any]], studies: Mapping[str, str], folder: Path = CHARTS) -> list[Path]:
    """Write every chart the results allow and remove the charts no result produces any more.

    Args:
        results: The latest result of each (machine, benchmark, command).
        studies: Study command -> its chart's file name.
        folder: Where the charts go.

    Returns:
        The charts written.
    """
    written = []
    for name, draw in planned(results, studies).items():
        written.append(folder / name)
        draw(written[-1])
    for stale in set(folder.glob("*.svg")) - set(written):
        stale.unlink()
    return written
