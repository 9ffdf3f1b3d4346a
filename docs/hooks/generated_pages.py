"""MkDocs hook: pages generated at build time, never written by hand.

- ``reference/cli.md``: the command-line reference, walked from ``fisheye_infer.cli.build_parser()``
  and every (nested) subparser: usage, description, and each argument group's flags with their help.
- ``shipped/<name>.md``: each shipped model's card (``fisheye_infer.models.pretrained.PRETRAINED``: its
  ``MODEL_CARD.md``, figures written by ``benchmarks/report.py``), as it is.

and the nav's "Performance" section, from the pages the benchmark report wrote under ``docs/performance/``.
"""

from __future__ import annotations

import argparse
import os
import re
from pathlib import Path

from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

CLI_PAGE = "reference/cli.md"


def _subparsers(parser: argparse.ArgumentParser) -> list[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each subcommand, in the order ``--help`` lists them."""
    found = []
    for action in parser._actions:  # argparse keeps its actions here and nowhere public
        if isinstance(action, argparse._SubParsersAction):
            helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
            found += [(name, helps.get(name, ""), sub) for name, sub in action.choices.items()]
    return found


_ESCAPE = re.compile(r"([\\`*_\[\]|<>])")


def _cell(text: str) -> str:
    """Help text for a Markdown table cell: one line, Markdown characters escaped but `code` kept."""
    text = " ".join(text.split())
    parts = text.split("`")
    out = []
    for i, part in enumerate(parts):
        if i % 2 and i < len(parts) - 1:  # between a pair of backticks: already code
            out.append(f"`{part}`")
        else:
            out.append(_ESCAPE.sub(r"\\\1", part))
    return "".join(out)


def _expand(text: str | None, action: argparse.Action, prog: str) -> str:
    if not text:
        return ""
    params = {**vars(action), "prog": prog}
    if action.choices is not None:
        params["choices"] = ", ".join(map(str, action.choices))
    try:
        return text % params
    except (KeyError, TypeError, ValueError):
        return text


def _flags(action: argparse.Action, formatter: argparse.HelpFormatter) -> str:
    if not action.option_strings:
        return f"`{formatter._metavar_formatter(action, action.dest)(1)[0]}`"
    if action.nargs == 0:
        return ", ".join(f"`{s}`" for s in action.option_strings)
    metavar = formatter._format_args(action, action.dest.upper())
    return ", ".join(f"`{s} {metavar}`" for s in action.option_strings)


def _command_section(name: str, summary: str, parser: argparse.ArgumentParser, level: int) -> list[str]:
    formatter = parser._get_formatter()
    lines = [f"{'#' * level} {name}", ""]
    if summary or parser.description:
        lines += [_cell(parser.description or summary), ""]
    lines += ["```text", parser.format_usage().strip(), "```", ""]
    for group in parser._action_groups:
        actions = [
            a
            for a in group._group_actions
            if a.help is not argparse.SUPPRESS
            and not isinstance(a, argparse._SubParsersAction)
            and not isinstance(a, argparse._HelpAction)
        ]
        if not actions:
            continue
        title = group.title or "options"
        lines += [f"**{_cell(title)}**", ""]
        if group.description:
            lines += [_cell(group.description), ""]
        lines += ["| argument | help |", "|---|---|"]
        for action in actions:
            required = " (required)" if action.option_strings and action.required else ""
            help_text = _expand(action.help, action, parser.prog)
            if action.default not in (None, False, argparse.SUPPRESS) and "default" not in help_text:
                help_text = f"{help_text} (default: {action.default})".strip()
            lines.append(f"| {_flags(action, formatter)}{required} | {_cell(help_text)} |")
        lines.append("")
    subs = _subparsers(parser)
    if subs:
        lines += ["| subcommand | what it does |", "|---|---|"]
        lines += [f"| `{name} {sub_name}` | {_cell(help_text)} |" for sub_name, help_text, _ in subs]
        lines.append("")
        for sub_name, help_text, sub in subs:
            lines += _command_section(f"{name} {sub_name}", help_text, sub, min(level + 1, 6))
    return lines


def cli_reference() -> str:
    """The command-line reference page, from the parser the ``fisheye-infer`` command builds."""
    from fisheye_infer.cli import build_parser

    parser = build_parser()
    columns = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"  # argparse wraps usage lines at the terminal's width: the same width on every machine
    try:
        return _reference(parser)
    finally:
        if columns is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = columns


def _reference(parser: argparse.ArgumentParser) -> str:
    lines = [
        "# Command line",
        "",
        "Generated from `fisheye_infer.cli.build_parser()` when the documentation is built: every subcommand, "
        "its usage and its flags, as `fisheye-infer COMMAND --help` prints them.",
        "",
        "```text",
        parser.format_usage().strip(),
        "```",
        "",
        "| command | what it does |",
        "|---|---|",
    ]
    subs = _subparsers(parser)
    lines += [
        f"| [`fisheye-infer {name}`](#fisheye-infer-{name}) | {_cell(help_text)} |" for name, help_text, _ in subs
    ]
    lines += [
        "",
        "`fisheye-infer --version` prints the version; without a command, `fisheye-infer` prints its help and exits "
        "with status 1. A usage error (an unknown flag, a missing argument) prints the usage and exits with status 2. "
        "A command that fails with one of the package's errors (`FisheyeInferError`) prints "
        "`fisheye-infer COMMAND: error: MESSAGE` and exits with status 1.",
        "",
    ]
    for name, help_text, sub in subs:
        lines += _command_section(f"fisheye-infer {name}", help_text, sub, 2)
    return "\n".join(lines) + "\n"


def model_cards() -> dict[str, Path]:
    """Each generated card page (``shipped/<name>.md``) and the shipped model's card it shows."""
    from fisheye_infer.models.pretrained import PRETRAINED

    return {f"shipped/{model.name}.md": model.card for model in PRETRAINED}


def on_config(config: MkDocsConfig) -> MkDocsConfig:
    """The "Performance" entry of the nav becomes a section: its index, then every other page the
    benchmark report generated under ``docs/performance/`` (their set changes with the results)."""
    folder = Path(config.docs_dir) / "performance"
    pages = sorted(p.relative_to(config.docs_dir).as_posix() for p in folder.rglob("*.md") if p.name != "index.md")
    for i, entry in enumerate(config.nav or []):
        if isinstance(entry, dict) and entry.get("Performance") == "performance/index.md" and pages:
            config.nav[i] = {"Performance": ["performance/index.md", *pages]}
    return config


def on_files(files: Files, config: MkDocsConfig) -> Files:
    files.append(File.generated(config, CLI_PAGE, content=cli_reference()))
    for page, card in model_cards().items():
        files.append(File.generated(config, page, content=card.read_text(encoding="utf-8")))
    return files
