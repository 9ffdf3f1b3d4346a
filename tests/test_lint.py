"""The tree stays clean: ruff over everything, mypy over the whole library, and imports that point down.

ruff and mypy come with the ``[dev]`` extra; their settings are in ``pyproject.toml``. mypy checks the
runtime (``fisheye_infer/``) and the models, export and service packages, which setuptools installs
under ``fisheye_infer`` from top-level folders (``typecheck/`` gives mypy that layout).
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _tool(name: str) -> list[str]:
    """The tool next to this interpreter (a virtual environment's), else on PATH; skip when missing."""
    here = Path(sys.executable).with_name(name)
    found = str(here) if here.exists() else shutil.which(name)
    if found is None:
        pytest.skip(f"{name} is not installed (pip install 'fisheye-infer[dev]')")
    return [found]


def test_ruff_finds_nothing() -> None:
    result = subprocess.run(
        [*_tool("ruff"), "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True, timeout=600
    )
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_mypy_finds_nothing_in_the_library() -> None:
    result = subprocess.run([*_tool("mypy")], cwd=ROOT, capture_output=True, text=True, timeout=1200)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def _imports(path: Path) -> set[str]:
    """Absolute modules a file imports, at any depth (lazy imports inside functions included)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    return names


@pytest.mark.parametrize(
    "folder, forbidden",
    [
        ("fisheye_infer", ("fisheye_infer.models", "fisheye_infer.export", "fisheye_infer.service")),
        ("models", ("fisheye_infer.export", "fisheye_infer.service")),
        ("service", ("fisheye_infer.models", "fisheye_infer.export")),
    ],
)
def test_imports_point_down(folder: str, forbidden: tuple[str, ...]) -> None:
    """The runtime needs none of the extras (only its command modules reach them, lazily); the models
    and the service do not know the exporter; the service does not know the models."""
    wrong = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        if folder == "fisheye_infer" and (path.parent.name == "commands" or path.name == "cli.py"):
            continue
        wrong += [f"{path.relative_to(ROOT)}: {name}" for name in sorted(_imports(path)) if name.startswith(forbidden)]
    assert not wrong, "\n".join(wrong)
