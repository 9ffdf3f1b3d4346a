"""Griffe extension: load the subpackages that pyproject.toml maps to other folders.

``[tool.setuptools.package-dir]`` installs ``models/`` as ``fisheye_infer.models``, ``export/`` as
``fisheye_infer.export`` and ``service/`` as ``fisheye_infer.service``. Griffe finds a package's
submodules by walking its folder, so it would not see these three; this extension reads the mapping
from pyproject.toml and attaches each folder, with its submodules, under its mapped name when the
top-level package has been loaded (before mkdocstrings resolves aliases).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Any

import griffe

ROOT = Path(__file__).resolve().parents[2]


def _package_dir_table(text: str) -> dict[str, str]:
    if sys.version_info >= (3, 11):
        import tomllib

        return dict(tomllib.loads(text)["tool"]["setuptools"].get("package-dir", {}))
    # Python 3.10 has no TOML reader: the table's lines are `"name" = "folder"`.
    section = re.search(r"^\[tool\.setuptools\.package-dir\]\n(.*?)(?=^\[|\Z)", text, re.MULTILINE | re.DOTALL)
    return dict(re.findall(r'^"([^"]+)"\s*=\s*"([^"]+)"', section.group(1), re.MULTILINE)) if section else {}


def package_dirs(pyproject: Path = ROOT / "pyproject.toml") -> dict[str, Path]:
    """Dotted subpackage name -> its folder, for every mapping that is not the package's own folder."""
    table = _package_dir_table(pyproject.read_text(encoding="utf-8"))
    return {name: ROOT / folder for name, folder in table.items() if "." in name}


class PackageDirs(griffe.Extension):
    """Attach the mapped folders under their package names (``fisheye_infer.models`` -> ``models/``)."""

    def __init__(self) -> None:
        super().__init__()
        self.mapping = package_dirs()

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        for name, folder in sorted(self.mapping.items(), key=lambda item: item[0].count(".")):
            parent_path, _, child = name.rpartition(".")
            if parent_path.split(".")[0] != pkg.name:
                continue
            parent = pkg if parent_path == pkg.name else pkg.modules_collection.get_member(parent_path)
            if child in parent.members:
                continue
            # GriffeLoader has no public call for "this folder is that submodule"; _load_module is the
            # one it uses for its own submodules (it walks the folder for the rest).
            module = loader._load_module(child, folder / "__init__.py", parent=parent)
            parent.set_member(child, module)
