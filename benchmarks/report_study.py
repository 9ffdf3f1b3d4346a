"""The study page's generated parts: the answer (the paper's findings and ours, one short table) and the figures
the study's tables hold for a chart (our FDS beside the paper's)."""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import harness

Result = Mapping[str, Any]
#: The findings' table in a study result.
FINDINGS = "The paper's findings: which side is larger, in the paper and here"
#: The paper's questions (RQ) and findings (RF), by the words of a comparison that belongs to them (first match).
FINDING_OF = (
    (r"0-30 m vs 0-48 m", "RF3: range"),
    (r"front \+ rear vs left \+ right", "RF2: two-camera layouts"),
    (r"all four vs front \+ rear|without front and rear", "RF1: cameras lost"),
    (r"^FisheyeBEVDet vs FisheyePETR", "BEVDet against PETR"),
    (r" 6 x P vs | vs \w+ 6 x P$", "RQ1: pinhole against fisheye"),
    (r"^Fisheye\w+ vs ", "RQ2: fisheye model against rectified"),
)
#: The answer's order: the paper's questions, then its findings, then the rest.
ORDER = [
    "RQ1: pinhole against fisheye",
    "RQ2: fisheye model against rectified",
    "RF1: cameras lost",
    "RF2: two-camera layouts",
    "RF3: range",
    "BEVDet against PETR",
]


def finding_of(comparison: str) -> str:
    """The paper's question or finding a comparison of ``study.py``'s findings table answers.

    Args:
        comparison: The row's comparison, e.g. ``BEVDet 6 x P vs BEVDet 4 x F, perspective-rectified``.

    Returns:
        Its label, e.g. ``RQ1: pinhole against fisheye``; ``other`` where none matches.
    """
    return next((label for pattern, label in FINDING_OF if re.search(pattern, comparison)), "other")


def _difference(pair: str | None) -> str | None:
    """``0.563 vs 0.440`` as ``+0.123``."""
    if not pair or " vs " not in pair:
        return None
    first, second = (float(v) for v in pair.split(" vs "))
    return f"{first - second:+.3f}"


def answer_rows(result: Result) -> list[dict[str, Any]]:
    """The answer's table: each comparison of the findings with its finding, the paper's difference and ours.

    Args:
        result: A ``study.py`` result.

    Returns:
        Rows of finding, comparison, the paper's difference, ours (with its interval), same direction; by finding.
    """
    rows = []
    for row in result["measurements"].get(FINDINGS, []):
        ours = next(v for k, v in row.items() if k.startswith("ours, difference"))
        rows.append(
            {
                "finding": finding_of(row["comparison (FDS, 0-48 m)"]),
                "comparison (FDS, 0-48 m)": row["comparison (FDS, 0-48 m)"],
                "paper's difference": _difference(row.get("paper")),
                "our difference (90% interval)": ours,
                "same direction": row.get("same direction"),
            }
        )
    return sorted(rows, key=lambda r: ORDER.index(r["finding"]) if r["finding"] in ORDER else len(ORDER))


def answer_block(result: Result, chart: str | None) -> str:
    """The answer's Markdown: the table, the chart, the provenance line.

    Args:
        result: A ``study.py`` result.
        chart: The chart's path relative to the page, or None.

    Returns:
        Markdown.
    """
    from report_tables import provenance

    lines = [harness.markdown_table(answer_rows(result)), ""]
    if chart:
        lines += [f"![Our FDS beside the paper's, for each row of the study's tables]({chart})", ""]
    return "\n".join([*lines, provenance(result)])


def _label(row: Mapping[str, Any], keys: Sequence[str]) -> str:
    return ", ".join(str(row[k]) for k in keys if row.get(k) not in (None, "-", "all"))


def study_bars(result: Result) -> list[tuple[str, list[tuple[str, float, float | None]]]]:
    """Our FDS and the paper's for each row of the study's Tables 2, 3 and 4 that the paper has (Table 3's
    rows of every camera are Table 2's: left out).

    Args:
        result: A ``study.py`` result.

    Returns:
        One (panel title, [(row label, ours, paper or None)]) per table.
    """
    panels = []
    for title, rows in result["measurements"].items():
        if not title.startswith("Table") or not rows:
            continue
        keys = [k for k in ("model", "cameras", "reduced", "range") if k in rows[0]]
        bars = [(_label(row, keys), float(row["FDS"]), row["paper FDS"]) for row in rows if row.get("paper FDS")]
        if title.startswith("Table 3"):  # its rows of every camera are Table 2's
            bars = [bar for bar, row in zip(bars, [r for r in rows if r.get("paper FDS")]) if row.get("reduced") != "-"]
        if bars:
            panels.append((title.split(":")[0], bars))
    return panels
