"""Every fenced block marked ``<!-- runnable -->`` in the README and the docs runs as written.

A page's runnable blocks run in order in one namespace (a later block may use an earlier block's names), in a
folder laid out as a user's checkout after ``make demo``: ``models/`` (the repository's, with the shipped models'
held-out frame), ``artifacts/demo/fisheye-bevdet-compact.onnx`` and ``model.onnx`` (the shipped compact
FisheyeBEVDet, exported once here). Python blocks are executed; bash blocks run in ``bash -euo pipefail`` with
this environment's ``fisheye-infer`` first on the PATH.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", ROOT / "docs" / "getting-started.md", *sorted((ROOT / "docs" / "guides").glob("*.md"))]
RUNNABLE = re.compile(r"^<!-- runnable -->\n```(?P<lang>python|bash)\n(?P<code>.*?)^```", re.MULTILINE | re.DOTALL)


def _blocks(page: Path) -> list[tuple[str, str]]:
    return [(m["lang"], m["code"]) for m in RUNNABLE.finditer(page.read_text(encoding="utf-8"))]


@pytest.fixture(scope="module")
def checkout(shipped_exports, tmp_path_factory: pytest.TempPathFactory) -> Path:
    onnx = shipped_exports("fisheye-bevdet-compact").onnx
    folder = tmp_path_factory.mktemp("checkout")
    (folder / "artifacts" / "demo").mkdir(parents=True)
    (folder / "artifacts" / "demo" / "fisheye-bevdet-compact.onnx").symlink_to(onnx)
    (folder / "model.onnx").symlink_to(onnx)
    (folder / "models").symlink_to(ROOT / "models")
    return folder


@contextlib.contextmanager
def _working_directory(folder: Path) -> Iterator[None]:
    before = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(before)


def test_the_pages_mark_their_runnable_blocks() -> None:
    marked = {page.name: len(_blocks(page)) for page in PAGES}
    for page in ("README.md", "getting-started.md", "runtime.md", "tracking.md"):
        assert marked[page] > 0, f"{page}: no block marked <!-- runnable -->"


@pytest.mark.parametrize("page", [p for p in PAGES if _blocks(p)], ids=lambda p: p.name)
def test_runnable_blocks_run(page: Path, checkout: Path) -> None:
    namespace: dict[str, object] = {"__name__": "__snippet__"}
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}"}
    with _working_directory(checkout):
        for n, (lang, code) in enumerate(_blocks(page)):
            where = f"{page.name}, runnable block {n + 1}"
            if lang == "python":
                exec(compile(code, where, "exec"), namespace)
            else:
                done = subprocess.run(
                    ["bash", "-euo", "pipefail", "-c", code], env=env, capture_output=True, text=True, timeout=300
                )
                assert done.returncode == 0, f"{where}:\n{done.stdout[-2000:]}{done.stderr[-2000:]}"
