"""The documentation: the site builds strictly, the README stays short and its links resolve, and
every ``fisheye-infer`` command (subcommand and flags) and repository path the README and the docs
name exists."""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from fisheye_infer.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"
README_MAX_LINES = 250

#: ``fisheye-infer`` as a command in code: at the start, after a space, a backtick, a bracket or a path.
COMMAND = re.compile(r"(?:^|(?<=[\s`(/]))fisheye-infer[ \t]+(?P<rest>[^\n`]*)")
FENCE = re.compile(r"^```[^\n]*\n(.*?)^```", re.MULTILINE | re.DOTALL)
INLINE = re.compile(r"`([^`\n]+)`")
FLAG = re.compile(r"^--[a-z][a-z0-9-]*")
LINK = re.compile(r"\]\(([^)\s]+)\)")
#: reStructuredText that Markdown prints as text: a role (``:func:`x```) or a literal-block marker ending a paragraph.
LITERAL_REST = re.compile(r":(?:func|mod|class|meth|attr|data|exc|obj|ref):`[^`<]*`|[^:\s]::\s*</p>")
#: A path into the repository named in code: ``benchmarks/int8.py``, ``tests/service/probe_service.py``.
REPO_PATH = re.compile(r"(?<![\w./$-])((?:benchmarks|tests|models|export|service|fisheye_infer|docs)/[\w./-]*\w)")


def _pages() -> list[Path]:
    return [README, *sorted(p for p in DOCS.rglob("*.md"))]


def _code(text: str) -> list[str]:
    """The code of a Markdown page: fenced blocks (backslash continuations joined) and inline spans."""
    blocks = [block.replace("\\\n", " ") for block in FENCE.findall(text)]
    prose = FENCE.sub("", text)
    return blocks + INLINE.findall(prose)


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps its subparsers here and nowhere public
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _commands() -> list[tuple[str, list[str]]]:
    """(page, words after ``fisheye-infer``) for every command named in code, up to a comment or shell operator."""
    found = []
    for page in _pages():
        for code in _code(page.read_text(encoding="utf-8")):
            for line in code.splitlines():
                for match in COMMAND.finditer(line):
                    rest = re.split(r"\s#|\s\|\s|&&|;|\s&(?:\s|$)", match["rest"])[0]
                    found.append((str(page.relative_to(ROOT)), rest.split()))
    return found


def test_the_site_builds_strictly(tmp_path: Path) -> None:
    """``mkdocs build --strict``: a broken link, anchor, nav entry, API reference or the CLI hook fails."""
    pytest.importorskip("mkdocs", reason="needs the [dev] extra")
    pytest.importorskip("mkdocstrings_handlers.python", reason="needs the [dev] extra")
    pytest.importorskip("material", reason="needs the [dev] extra")
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "mkdocs",
            "build",
            "--strict",
            "--config-file",
            str(ROOT / "mkdocs.yml"),
            "--site-dir",
            str(site),
        ],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    assert (site / "index.html").is_file()
    cli = (site / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    for name in _subparsers(build_parser()):
        assert f'id="fisheye-infer-{name}"' in cli, f"the generated CLI reference has no section for {name}"
    literal = []
    for page in site.rglob("*.html"):
        text = re.sub(r"<(script|pre|code)\b.*?</\1>", "", page.read_text(encoding="utf-8"), flags=re.DOTALL)
        literal += [f"{page.relative_to(site)}: {m[0]}" for m in LITERAL_REST.finditer(text)]
    assert not literal, "reStructuredText printed literally:\n" + "\n".join(literal[:20])


def test_the_readme_is_short() -> None:
    lines = len(README.read_text(encoding="utf-8").splitlines())
    assert lines < README_MAX_LINES, (
        f"README.md has {lines} lines; keep it under {README_MAX_LINES} and move the rest into docs/"
    )


def test_the_readme_links_resolve() -> None:
    """The README is read on the repository's web page, outside the site build: its relative links
    must name files of the repository."""
    for target in LINK.findall(README.read_text(encoding="utf-8")):
        if re.match(r"^[a-z]+:", target) or target.startswith("#"):
            continue
        path = (ROOT / target.split("#")[0]).resolve()
        assert path.exists(), f"README.md links to {target}, which does not exist"


def test_every_repository_path_named_exists() -> None:
    """Scripts and files the README and the docs tell a reader to run or read are where they say."""
    named = {
        (str(page.relative_to(ROOT)), path)
        for page in _pages()
        for code in _code(page.read_text(encoding="utf-8"))
        for path in REPO_PATH.findall(code)
    }
    assert any(path.startswith("benchmarks/") for _, path in named), (
        "the docs name benchmark scripts; the search found none"
    )
    missing = sorted(f"{page}: {path}" for page, path in named if not (ROOT / path).exists())
    assert not missing, "paths named in the docs that do not exist:\n" + "\n".join(missing)


def test_every_command_named_exists() -> None:
    """Each ``fisheye-infer SUBCOMMAND [ACTION] --flag`` in the README and the docs is one the parser has."""
    parser = build_parser()
    commands = _commands()
    assert len(commands) > 20, "the README and docs name fisheye-infer commands; the search found almost none"
    for page, words in commands:
        if not words or not re.match(r"^[a-z][a-z0-9-]*$", words[0]):
            continue  # `fisheye-infer --version`, `fisheye-infer COMMAND --help`
        subs = _subparsers(parser)
        assert words[0] in subs, f"{page}: `fisheye-infer {words[0]}` is not a subcommand (have {', '.join(subs)})"
        command = subs[words[0]]
        name = f"fisheye-infer {words[0]}"
        actions = _subparsers(command)
        if actions and len(words) > 1 and re.match(r"^[a-z][a-z0-9-]*$", words[1]):
            assert words[1] in actions, (
                f"{page}: `{name} {words[1]}` is not an action of {name} (have {', '.join(actions)})"
            )
            command, name = actions[words[1]], f"{name} {words[1]}"
        known = set(command._option_string_actions)
        for word in words[1:]:
            flag = FLAG.match(word.strip("[]()'\","))
            if flag:
                assert flag.group(0) in known, f"{page}: `{name}` has no flag {flag.group(0)}"
