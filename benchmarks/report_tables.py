"""The report's building blocks: the machine in words, one provenance line per block, tables that fit the page.

A table fits when the narrowest it can be laid out (each column as wide as its longest word, and at least as wide
as the theme's smallest column) is within ``PAGE_PX``: columns that hold one value in every row become a note
above the table, long texts become numbered notes below it, and what is still too wide is split into several
tables, each with the row's label columns.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from typing import Any

import harness

Row = Mapping[str, Any]
#: The width a table may take: the content column of mkdocs-material at a desktop width (about 1,280 px wide).
PAGE_PX = 680
#: mkdocs-material's smallest column (a header cell's ``min-width: 5rem``) and a cell's padding, in px.
COLUMN_MIN_PX, CELL_PAD_PX = 100, 32
#: The width of one character of the tables' font (0.64rem), in px.
CHAR_PX = 7.5
#: A cell's text longer than this becomes a numbered note below its table.
LONG_CELL = 100

#: AMD's and Intel's microarchitectures by (vendor word, family, lowest model, highest model), from the vendors'
#: family and model numbers.
MICROARCHITECTURES = (
    ("AMD", 23, 0x00, 0x2F, "Zen"),
    ("AMD", 23, 0x30, 0xFF, "Zen 2"),
    ("AMD", 25, 0x00, 0x0F, "Zen 3"),
    ("AMD", 25, 0x10, 0x1F, "Zen 4"),
    ("AMD", 25, 0x20, 0x5F, "Zen 3"),
    ("AMD", 25, 0x60, 0xAF, "Zen 4"),
    ("AMD", 26, 0x00, 0xFF, "Zen 5"),
    ("Intel", 6, 0x55, 0x55, "Skylake/Cascade Lake"),
    ("Intel", 6, 0x6A, 0x6C, "Ice Lake"),
    ("Intel", 6, 0x8F, 0x8F, "Sapphire Rapids"),
    ("Intel", 6, 0xCF, 0xCF, "Emerald Rapids"),
    ("Intel", 6, 0xAD, 0xAE, "Granite Rapids"),
)


def microarchitecture(host: Mapping[str, Any]) -> str | None:
    """The CPU's microarchitecture (``Zen 4``) from its name, family and model; None where unknown.

    Args:
        host: A result's ``machine``.

    Returns:
        The microarchitecture's name, or None.
    """
    name = str(host.get("cpu_name") or host.get("cpu", ""))
    try:
        family, model = int(host["cpu_family"]), int(host["cpu_model"])
    except (KeyError, TypeError, ValueError):
        return None
    for vendor, fam, low, high, arch in MICROARCHITECTURES:
        if vendor.lower() in name.lower() and fam == family and low <= model <= high:
            return arch
    return None


def machine_words(host: Mapping[str, Any]) -> str:
    """The machine in words: ``2-core AMD EPYC (Zen 4)``, with its GPUs where it has some.

    Args:
        host: A result's ``machine``.

    Returns:
        Cores, the CPU's name and its microarchitecture (or family and model where unknown), the GPUs.
    """
    name = host.get("cpu_name") or host["cpu"].split(" (")[0]
    arch = microarchitecture(host)
    if arch is None and host.get("cpu_family") and host.get("cpu_model"):
        arch = f"family {host['cpu_family']}, model {host['cpu_model']}"
    gpus = ", ".join(gpu.split(",")[0] for gpu in host.get("gpus", []))
    return f"{host['cpu_count']}-core {name}" + (f" ({arch})" if arch else "") + (f", {gpus}" if gpus else "")


def when(date: str) -> str:
    """``2025-01-31T12:00:00Z`` as ``2025-01-31 12:00 UTC``."""
    return f"{date[:10]} {date[11:16]} UTC"


def provenance(result: Mapping[str, Any]) -> str:
    """The line that says where a block's figures come from: the command, the machine, the date, the load.

    Args:
        result: One benchmark result.

    Returns:
        One Markdown line.
    """
    host = result["machine"]
    load = result.get("load_average")
    busy = f", load average {load[1]:.1f}" if load else ""
    versions = f"Python {host['python']}, onnxruntime {host['onnxruntime']}, numpy {host['numpy']}"
    return f"Command: `{result['command']}` · {machine_words(host)}; {versions} · {when(result['date'])}{busy}"


def _cell(value: Any) -> str:
    return harness.format_value(value)


def escape(text: str) -> str:
    """Text for Markdown outside code, as ``harness.markdown_table`` writes a cell: Markdown's characters escaped.

    Args:
        text: Plain text.

    Returns:
        The text, shown as it is.
    """
    return re.sub(r"([\\`*_\[\]|])", r"\\\1", text).replace("<", "&lt;").replace("\n", " ")


def column_px(name: str, rows: Sequence[Row]) -> float:
    """The narrowest a column can be laid out: its longest word (a browser breaks a line after a hyphen between
    letters), header included, and the theme's minimum.

    Args:
        name: The column.
        rows: The table's rows.

    Returns:
        The width in px.
    """
    text = " ".join([name, *(_cell(row.get(name)) for row in rows)])
    words = re.split(r"\s+|(?<=[a-z]-)(?=[a-z])", text)
    return max(COLUMN_MIN_PX, CHAR_PX * max((len(w) for w in words), default=1) + CELL_PAD_PX)


def _columns(rows: Sequence[Row]) -> list[str]:
    return list(dict.fromkeys(key for row in rows for key in row))


def constant_columns(rows: Sequence[Row], keep: int = 1) -> dict[str, Any]:
    """The columns (past the first ``keep``) that hold the same value in every one of two or more rows.

    Args:
        rows: The table's rows.
        keep: How many leading columns stay in the table whatever they hold.

    Returns:
        Column -> its one value.
    """
    if len(rows) < 2:
        return {}
    same = {}
    for name in _columns(rows)[keep:]:
        values = {_cell(row.get(name)) for row in rows}
        if len(values) == 1 and all(name in row for row in rows):
            same[name] = rows[0][name]
    return same


def _label_columns(rows: Sequence[Row], columns: Sequence[str]) -> list[str]:
    """The leading columns that name a row (text, not numbers): at most two, at least one."""
    labels = []
    for name in columns[:2]:
        if all(isinstance(row.get(name), str) or row.get(name) is None for row in rows):
            labels.append(name)
        else:
            break
    return labels or list(columns[:1])


def _identifying(rows: Sequence[Row], labels: Sequence[str]) -> list[str]:
    """The fewest leading label columns that tell the rows apart (all of them where none do)."""
    for n in range(1, len(labels) + 1):
        keys = [tuple(_cell(row.get(c)) for c in labels[:n]) for row in rows]
        if len(set(keys)) == len(keys):
            return list(labels[:n])
    return list(labels)


def _units(columns: Sequence[str]) -> list[list[str]]:
    """The columns in the units a split keeps together: a column and its ``paper <column>`` beside it."""
    units: list[list[str]] = []
    for name in columns:
        if name.startswith("paper ") and name.removeprefix("paper ") in columns:
            continue
        units.append([name, *([f"paper {name}"] if f"paper {name}" in columns else [])])
    return units


def split_columns(rows: Sequence[Row], budget: float = PAGE_PX) -> list[list[str]]:
    """The columns of each part of a table: each ``paper <column>`` beside its column, and where the table is too
    wide for ``budget``, parts of the label columns (in the parts after the first, those that tell the rows
    apart) and as many of the others, in order, as fit.

    Args:
        rows: The table's rows.
        budget: The width the table may take, in px.

    Returns:
        One list of columns per part (one part where the table fits).
    """
    units = _units(_columns(rows))
    columns = [c for unit in units for c in unit]
    if sum(column_px(c, rows) for c in columns) <= budget:
        return [columns]
    labels = _label_columns(rows, columns)
    again = _identifying(rows, labels)
    parts: list[list[str]] = []
    for unit in units[len(labels) :]:
        if parts and sum(column_px(c, rows) for c in [*parts[-1], *unit]) <= budget:
            parts[-1] += unit
        else:
            parts.append([*(labels if not parts else again), *unit])
    return _balanced(rows, parts, units[len(labels) :], labels, again, budget)


def _balanced(
    rows: Sequence[Row],
    greedy: list[list[str]],
    units: list[list[str]],
    labels: list[str],
    again: list[str],
    budget: float,
) -> list[list[str]]:
    """``greedy``'s number of parts with the units spread evenly over them, where every part still fits."""
    n = len(greedy)
    share, extra = divmod(len(units), n)
    parts, start = [], 0
    for i in range(n):
        size = share + (1 if i < extra else 0)
        parts.append([*(labels if i == 0 else again), *(c for unit in units[start : start + size] for c in unit)])
        start += size
    fits = all(sum(column_px(c, rows) for c in part) <= budget for part in parts)
    return parts if fits and all(len(part) > len(again) for part in parts) else greedy


def fitted_table(rows: Sequence[Row], keep: int = 1) -> str:
    """``rows`` as Markdown that fits the page: a note of the columns with one value, long texts as numbered notes
    below, and the rest split into as many tables as it takes.

    Args:
        rows: The table's rows.
        keep: How many leading columns stay in the table even where they hold one value.

    Returns:
        Markdown: the note, the table or tables, the long texts.
    """
    if not rows:
        return "_No rows._"
    same = constant_columns(rows, keep)
    notes: list[str] = []
    trimmed: list[dict[str, Any]] = []
    for row in rows:
        out = {}
        for name, value in row.items():
            if name in same:
                continue
            text = _cell(value)
            if isinstance(value, str) and len(text) > LONG_CELL:
                if text not in notes:
                    notes.append(text)
                value = f"note {notes.index(text) + 1}"
            out[name] = value
        trimmed.append(out)
    lines = []
    if same:
        lines += [
            "Every row: " + escape("; ".join(f"{name}: {_cell(value)}" for name, value in same.items())) + ".",
            "",
        ]
    parts = split_columns(trimmed)
    for columns in parts:
        lines += [harness.markdown_table([{c: row.get(c) for c in columns if c in row} for row in trimmed]), ""]
    for i, text in enumerate(notes, 1):
        lines.append(f"{i}. {escape(text)}")
    return "\n".join(lines).rstrip()


def short_title(title: str, limit: int = 70) -> tuple[str, str]:
    """A table's title for a heading, and what it said in parentheses where the whole is longer than ``limit``.

    Args:
        title: The table's title in the result.
        limit: The longest heading kept whole.

    Returns:
        (heading, the parenthesised text moved out of it or ""): only a parenthesis longer than half ``limit``
        moves.
    """
    if len(title) <= limit or " (" not in title:
        return title, ""
    head, rest = title.split(" (", 1)
    depth, inner = 1, ""
    for i, ch in enumerate(rest):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth == 0:
            inner, tail = rest[:i], rest[i + 1 :]
            return (f"{head}{tail}".strip(), inner) if len(inner) > limit // 2 else (title, "")
    return title, ""
