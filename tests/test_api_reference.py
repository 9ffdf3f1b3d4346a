"""The API reference teaches: every object its pages render documents each of its parameters.

The reference pages (``docs/reference/api/*.md``) name what they document with ``::: dotted.path`` directives:
the public API, chosen page by page; the modules they do not name are internal and left out on purpose. Each
named function, each named class (its constructor and its public methods) and each public member of a named
module must say what every parameter is in its Google-style ``Args:`` section (the class docstring or its
``__init__``'s for a constructor; a dataclass's or pydantic model's ``Attributes:`` for its fields). The built site's check for literal reST roles is in ``test_docs.py``.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

griffe = pytest.importorskip("griffe", reason="needs the [dev] extra (mkdocstrings)")

ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "docs" / "reference" / "api"
DIRECTIVE = re.compile(r"^::: ([\w.]+)\s*\n((?:[ \t]+.*\n)*)", re.MULTILINE)
ARGS_SECTIONS = {"parameters", "other parameters"}
#: A dataclass or pydantic model documents its constructor's parameters as its fields.
FIELD_SECTIONS = ARGS_SECTIONS | {"attributes"}


def _targets() -> list[tuple[str, str]]:
    """(page, dotted path) of every ``:::`` directive of the reference that renders members (not ``members: false``)."""
    return [
        (page.name, m[1])
        for page in sorted(PAGES.glob("*.md"))
        for m in DIRECTIVE.finditer(page.read_text() + "\n")
        if not re.search(r"^\s+members:\s*false\s*$", m[2], re.MULTILINE)
    ]


@pytest.fixture(scope="module")
def package() -> object:
    sys.path.insert(0, str(ROOT / "docs" / "hooks"))
    try:
        from package_dirs import PackageDirs
    finally:
        sys.path.pop(0)
    extensions = griffe.load_extensions(PackageDirs)
    return griffe.load("fisheye_infer", extensions=extensions, docstring_parser="google", search_paths=[str(ROOT)])


def _documented(*docstrings: object, sections: set[str] = ARGS_SECTIONS) -> set[str]:
    names: set[str] = set()
    for docstring in docstrings:
        if docstring is None:
            continue
        for section in docstring.parsed:  # type: ignore[attr-defined]
            if section.kind.value in sections:
                names |= {p.name.lstrip("*") for p in section.value}
    return names


def _parameters(function: object) -> list[str]:
    return [p.name for p in function.parameters if p.name not in ("self", "cls")]  # type: ignore[attr-defined]


def _public(obj: object) -> Iterator[object]:
    for name, member in obj.members.items():  # type: ignore[attr-defined]
        if name.startswith("_") or member.is_alias:
            continue
        if member.is_function or member.is_class:
            yield member


def _problems(obj: object) -> Iterator[str]:
    """What ``obj`` (a function, class or module) leaves undocumented."""
    if obj.is_module:  # type: ignore[attr-defined]
        for member in _public(obj):
            yield from _problems(member)
        return
    path = obj.path  # type: ignore[attr-defined]
    if obj.is_class:  # type: ignore[attr-defined]
        init = obj.members.get("__init__")  # type: ignore[attr-defined]
        if init is not None and not init.is_alias:
            documented = _documented(obj.docstring, init.docstring, sections=FIELD_SECTIONS)  # type: ignore[attr-defined]
            missing = [p for p in _parameters(init) if p not in documented]
            if missing:
                yield f"{path}: constructor parameters without an Args entry: {', '.join(missing)}"
        else:  # a pydantic model: its annotated fields are its constructor's parameters
            if obj.docstring is None:  # type: ignore[attr-defined]
                yield f"{path}: no docstring"
            documented = _documented(obj.docstring, sections=FIELD_SECTIONS)  # type: ignore[attr-defined]
            fields = [
                name
                for name, member in obj.members.items()  # type: ignore[attr-defined]
                if member.is_attribute
                and member.annotation is not None
                and not name.startswith("_")
                and name != "model_config"
                and member.docstring is None
                and name not in documented
            ]
            if fields:
                yield f"{path}: fields without a docstring or an Attributes entry: {', '.join(fields)}"
        for member in _public(obj):
            if member.is_function:
                yield from _problems(member)
        return
    if obj.docstring is None:  # type: ignore[attr-defined]
        yield f"{path}: no docstring"
        return
    missing = [p for p in _parameters(obj) if p not in _documented(obj.docstring)]  # type: ignore[attr-defined]
    if missing:
        yield f"{path}: parameters without an Args entry: {', '.join(missing)}"


@pytest.mark.parametrize("page, target", _targets(), ids=lambda v: v)
def test_every_rendered_name_documents_its_parameters(package: object, page: str, target: str) -> None:
    obj = package[target.removeprefix("fisheye_infer.")] if target != "fisheye_infer" else package  # type: ignore[index]
    while obj.is_alias:
        obj = obj.final_target
    problems = list(_problems(obj))
    assert not problems, f"{page}, ::: {target}:\n" + "\n".join(problems)


def test_the_reference_names_the_public_api() -> None:
    """The top-level names and each page's central entries are rendered."""
    named = {target for _, target in _targets()}
    for central in (
        "fisheye_infer.runtime.detector.Detector",
        "fisheye_infer.runtime.detections.Detections",
        "fisheye_infer.tracking.tracker.Tracker",
        "fisheye_infer.export.exporter.export",
        "fisheye_infer.export.rebake.rebake",
        "fisheye_infer.deploy.triton.client.TritonDetector",
    ):
        assert central in named or central.rsplit(".", 1)[0] in named, f"the reference does not render {central}"
