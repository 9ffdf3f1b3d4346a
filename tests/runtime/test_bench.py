"""`fisheye-infer bench`: what it measures and writes (not how fast anything is)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from fisheye_infer.cli import main
from fisheye_infer.export.graph_stages import STAGES


def test_bench_writes_every_figure(small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bench.json"
    assert (
        main(
            [
                "bench",
                str(small_export.onnx),
                "--threads",
                "1",
                "--batch",
                "1,2",
                "--repeat",
                "2",
                "--warmup",
                "1",
                "--out",
                str(out),
                "--providers",
                '[["CPUExecutionProvider", {"use_arena": "1"}]]',
            ]
        )
        == 0
    )  # provider options, as JSON
    doc = json.loads(out.read_text())
    assert (
        doc["providers"] == ["CPUExecutionProvider"]
        and doc["machine"]["cpu_count"] >= 1
        and isinstance(doc["machine"]["gpus"], list)
    )
    assert [(r["threads"], r["batch"]) for r in doc["runs"]] == [(1, 1), (1, 2)]
    for run in doc["runs"]:
        assert {"total", "decode", "preprocess", "inference", "postprocess"} <= set(run)
        assert (
            run["total"]["median"] >= run["inference"]["median"] > 0 and run["total"]["p90"] >= run["total"]["median"]
        )
    assert set(doc["stages"]["1"]) == set(STAGES) and all(v["median"] > 0 for v in doc["stages"]["1"].values())
    assert 50 < doc["peak_rss_mb"]["1"] < 4000
    assert doc["architecture"] == "fisheye-bevdet" and doc["quantization"] == "fp32"
    printed = capsys.readouterr().out
    assert (
        "threads batch | total med/p90 ms" in printed
        and "peak RSS at 1 thread(s)" in printed
        and "fp32; CPUExecutionProvider)" in printed
    )


def test_bench_refuses_bad_options(small_export, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        main(["bench", str(small_export.onnx), "--threads", "0"])
    assert "expected comma-separated positive integers" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # a provider this onnxruntime lacks is a usage error that lists the ones it has
        main(["bench", str(small_export.onnx), "--providers", "NoSuchExecutionProvider,CPUExecutionProvider"])
    assert "--providers: NoSuchExecutionProvider not offered by the installed onnxruntime" in (
        err := capsys.readouterr().err
    )
    assert "CPUExecutionProvider" in err.split("available:")[1]
    for text, message in [
        ("[CPUExecutionProvider", "--providers: not a JSON list"),
        (
            '[["CPUExecutionProvider", {"use_arena": [1]}]]',
            "CPUExecutionProvider option 'use_arena': expected a string, number or boolean",
        ),
        (
            '[["CPUExecutionProvider"]]',
            "expected a provider name or a (name, options dict) pair, got ('CPUExecutionProvider',)",
        ),
        (" , ", "--providers: none given"),
    ]:
        with pytest.raises(SystemExit):
            main(["bench", str(small_export.onnx), "--providers", text])
        assert message in capsys.readouterr().err


def test_peak_rss_is_the_childs_own_not_its_parents() -> None:
    """A parent holding 1.5 GB starts the child that reports; the child's figure must not include it."""
    parent = textwrap.dedent("""
        import subprocess, sys
        import numpy as np
        held = np.ones(1_500_000_000 // 8)  # touched: resident in the parent
        child = "from fisheye_infer.tools.bench import _own_peak_rss_mb; print(_own_peak_rss_mb())"
        print(subprocess.run([sys.executable, "-c", child], capture_output=True, text=True, check=True).stdout.strip())
    """)
    done = subprocess.run([sys.executable, "-c", parent], capture_output=True, text=True, timeout=120, check=True)
    child_mb = float(done.stdout.strip().splitlines()[-1])
    assert 10 < child_mb < 600, child_mb
