"""The performance index: how fast each model runs, on what, at a glance, and what fp16 and int8 keep of the accuracy.

The frame times come from the benchmarks that time whole frames of a model's files (``frame_times``); for each
model the index shows the one result that times most of its precisions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import harness
from report_pages import NOTICE, questions, quick
from report_tables import machine_words, provenance, when

Result = Mapping[str, Any]
#: The index's charts, relative to the pages under ``docs/performance/``.
CHARTS = "../assets/charts"
#: What a frame time of the index measures, by the benchmark it comes from.
SOURCES = {
    "int8": (
        "`Detector.run_arrays` on one frame, the files timed in turns. int8 is the file "
        "`fisheye-infer export --int8` writes (its int8 search's choice); int8 (network) and int8 (trunk) are the "
        "two scopes chosen by hand."
    ),
    "virtual_cameras": "The model's file for its training rig, one frame (the front end's cost there).",
    "compare": "`Detector.detect` end to end on one frame, the files timed in turns.",
}
#: The precisions in the order the headline shows them.
PRECISIONS = ("fp32", "fp16", "int8")
#: ``benchmarks/model_files.py``'s model names as the shipped models' names.
MODEL_NAMES = {"compact": "fisheye-bevdet-compact"}


def frame_times(result: Result) -> list[dict[str, Any]]:
    """The frame times (one frame of every camera) a result holds: model, precision, threads, ms.

    ``int8.py``'s latency table (``auto``, the file ``export --int8`` writes, is the model's int8),
    ``virtual_cameras.py``'s training files and ``compare.py``'s ONNX Runtime files end to end.

    Args:
        result: One benchmark result.

    Returns:
        One row per (model, precision, threads); none where the benchmark measures no frame time.
    """
    tables, params = result["measurements"], result.get("parameters", {})
    rows: list[dict[str, Any]] = []
    if result["benchmark"] == "int8" and params.get("ckpt"):
        model = Path(params["ckpt"]).parent.name.replace("_", "-")
        for row in tables.get("Latency, one frame, files in turns", []):
            name = row["file"]
            precision = name if name in PRECISIONS else "int8" if name == "auto" else f"int8 ({name})"
            rows.append({"model": model, "precision": precision, "threads": row["threads"], "ms": row["median ms"]})
    elif result["benchmark"] == "virtual_cameras":
        for row in tables.get("Front end cost", []):
            rows.append(
                {
                    "model": params["model"],
                    "precision": "int8" if params.get("int8") else "fp32",
                    "threads": row["threads"],
                    "ms": row["training file ms"],
                }
            )
    elif result["benchmark"] == "compare":
        for row in tables.get("Runtimes, one frame, in turns", []):
            parts = row["runtime"].split()
            if row["runtime"].startswith("ONNX Runtime") and row["runtime"].endswith("end to end"):
                model = MODEL_NAMES.get(row["model"], row["model"])
                rows.append(
                    {
                        "model": model,
                        "precision": parts[2].rstrip(","),
                        "threads": row["threads"],
                        "ms": row["median ms"],
                    }
                )
    return rows


def headline(results: Sequence[Result]) -> dict[str, tuple[Result, list[dict[str, Any]]]]:
    """Per model, the result that times most of its precisions (then: not ``--quick``, the newest), and its rows with
    frames per second and the speed-up over fp32 at the same thread count.

    Args:
        results: One machine's latest results.

    Returns:
        Model -> (the result, rows of precision, threads, frame ms, frames/s, speed-up), in the precisions' order.
    """
    best: dict[str, tuple[tuple[int, bool, str], Result, list[dict[str, Any]]]] = {}
    for result in results:
        timed = frame_times(result)
        for model in dict.fromkeys(row["model"] for row in timed):
            ours = [row for row in timed if row["model"] == model]
            key = (len({row["precision"] for row in ours}), not quick(result), result["date"])
            if model not in best or key > best[model][0]:
                best[model] = (key, result, ours)
    out = {}
    for model, (_, result, ours) in sorted(best.items()):
        fp32 = {row["threads"]: row["ms"] for row in ours if row["precision"] == "fp32"}
        rank = lambda row: (
            PRECISIONS.index(row["precision"][:4]) if row["precision"][:4] in PRECISIONS else 9,
            row["precision"],
            row["threads"],
        )
        rows = [
            {
                "precision": row["precision"],
                "threads": row["threads"],
                "frame ms": row["ms"],
                "frames/s": 1e3 / row["ms"],
                "speed-up": fp32[row["threads"]] / row["ms"] if row["threads"] in fp32 else None,
            }
            for row in sorted(ours, key=rank)
        ]
        out[model] = (result, rows)
    return out


def precision_accuracy(results: Sequence[Result]) -> dict[str, tuple[Result, list[dict[str, Any]]]]:
    """Per shipped model, FDS of its fp32, fp16 and int8 files and how many of the fp32 top-50 boxes each keeps,
    from the newest ``model_card.py`` result of each model.

    Args:
        results: The latest results, of every machine.

    Returns:
        Model -> (the result, rows of range, FDS per precision, top-50 kept per reduced precision).
    """
    newest: dict[str, Result] = {}
    for result in results:
        if result["benchmark"] == "model_card" and not quick(result):
            model = result["parameters"].get("model") or "fisheye-bevdet-compact"
            if model not in newest or result["date"] > newest[model]["date"]:
                newest[model] = result
    out = {}
    for model, result in sorted(newest.items()):
        rows: dict[str, dict[str, Any]] = {}
        for title, table in result["measurements"].items():
            precision = next((p for p in ("int8", "fp16") if title.startswith(p) and "against the fp32" in title), None)
            for row in table if precision else []:
                into = rows.setdefault(row["range"], {"range": row["range"], "FDS fp32": row["FDS fp32"]})
                into[f"FDS {precision}"] = row[f"FDS {precision}"]
                into[f"{precision} top-50 kept"] = row["top-50 kept"]
        if rows:
            order = ["range", "FDS fp32", "FDS fp16", "FDS int8", "fp16 top-50 kept", "int8 top-50 kept"]
            out[model] = (result, [{k: row[k] for k in order if k in row} for row in rows.values()])
    return out


def chart_name(kind: str, slug: str | None = None) -> str:
    """A chart's file name under ``docs/assets/charts/``: ``frame-time-<machine slug>.svg``, ``int8-accuracy.svg``."""
    return f"{kind}-{slug}.svg" if slug else f"{kind}.svg"


def index_page(results: Sequence[Result]) -> str:
    """The performance index: each machine's frame times per model and precision, a chart of them, what int8 and
    fp16 keep of the accuracy, and the machines' pages.

    Args:
        results: The latest result of each (machine, benchmark, command).

    Returns:
        The page's Markdown.
    """
    slugs = sorted({r["machine"]["slug"] for r in results})
    lines = [
        "# Performance",
        "",
        NOTICE,
        "",
        "How fast each model runs, on what: the median time of one frame of every camera through ONNX Runtime's "
        "CPU provider, by precision and thread count, and the speed-up over the fp32 file at the same thread count. "
        "Every block ends with the command that measured it, the machine and the date; "
        "`python benchmarks/run_all.py` runs every benchmark.",
        "",
    ]
    for slug in slugs:
        ours = [r for r in results if r["machine"]["slug"] == slug]
        timed = headline(ours)
        if not timed:
            continue
        words = machine_words(ours[-1]["machine"])
        lines += [
            f"## {words}",
            "",
            f"![Frame time by model, precision and threads on a {words}]({CHARTS}/{chart_name('frame-time', slug)})",
            "",
        ]
        for model, (result, rows) in timed.items():
            lines += [f"### {model}", "", harness.markdown_table(rows), ""]
            lines += [SOURCES[result["benchmark"]], ""] if result["benchmark"] in SOURCES else []
            lines += [provenance(result), ""]
    accuracy = precision_accuracy(results)
    if accuracy:
        lines += [
            "## What fp16 and int8 keep of the accuracy",
            "",
            "FDS of each shipped model's fp32, fp16 and int8 files on the same held-out frames, and the share of the "
            "fp32 file's 50 best boxes per frame that each reduced file keeps.",
            "",
            f"![FDS of the fp32, fp16 and int8 files of each shipped model]({CHARTS}/{chart_name('int8-accuracy')})",
            "",
        ]
        for model, (result, rows) in accuracy.items():
            lines += [f"### {model}", "", harness.markdown_table(rows), "", provenance(result), ""]
    lines += ["## Every figure, by machine", ""]
    for slug in slugs:
        ours = [r for r in results if r["machine"]["slug"] == slug]
        lines.append(
            f"- [{machine_words(ours[-1]['machine'])}]({slug}.md): {len(ours)} result(s), latest "
            f"{when(max(r['date'] for r in ours))}; " + ", ".join(q.rstrip("?").lower() for q in questions(ours))
        )
    if not slugs:
        lines.append("No results yet.")
    return "\n".join(lines).rstrip() + "\n"
