"""Text files from outside (calibration files, rig files) read with bounds: size, encoding, YAML aliases.

A calibration or rig file is a few kilobytes of UTF-8 text. Whatever else arrives under that name is
refused before it is parsed, by the file and the reason: a file over ``MAX_TEXT_BYTES``, bytes that
are not UTF-8 text (a binary file), or YAML that uses anchors and aliases (``&a`` / ``*a``), which no
calibration tool writes and which would let a few lines expand into gigabytes. Values quoted in
error messages go through ``short``, so no message grows with its input.
"""

from __future__ import annotations

import reprlib
from pathlib import Path
from typing import Any, Final

import yaml
from yaml.events import AliasEvent, NodeEvent

from fisheye_infer.errors import RigError

__all__ = ["MAX_TEXT_BYTES", "AliasRefused", "read_text", "load_yaml", "short"]

#: The largest calibration or rig file read (bytes); real ones are a few kilobytes.
MAX_TEXT_BYTES: Final = 4 << 20

_SHORT = reprlib.Repr()
_SHORT.maxstring = _SHORT.maxother = 60
_SHORT.maxlist = _SHORT.maxtuple = _SHORT.maxdict = 8
_SHORT.maxlevel = 3


def short(value: Any) -> str:
    """``repr(value)`` bounded to a few dozen characters per element, for error messages."""
    text = _SHORT.repr(value)
    return text if len(text) <= 200 else text[:197] + "..."


def read_text(path: Path, what: str) -> str:
    """The UTF-8 text of ``path``; ``what`` names the kind of file expected in the refusal ("a calibration
    file", "a rig file") when it is missing, too large or not text."""
    try:
        with path.open("rb") as stream:
            data = stream.read(MAX_TEXT_BYTES + 1)
    except OSError as exc:
        raise RigError(f"{path}: cannot be read ({exc.strerror})") from exc
    if len(data) > MAX_TEXT_BYTES:
        raise RigError(f"{path}: not {what} (larger than {MAX_TEXT_BYTES >> 20} MiB)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise RigError(
            f"{path}: not {what} (byte 0x{data[exc.start]:02x} at offset {exc.start} is not UTF-8 text)"
        ) from None
    if "\x00" in text:
        raise RigError(f"{path}: not {what} (NUL byte at offset {text.index(chr(0))}: binary data)")
    return text


class AliasRefused(RigError):
    """A YAML file uses anchors or aliases (``&name``, ``*name``), which are refused; raised by ``load_yaml``."""


class _NoAliasLoader(yaml.SafeLoader):
    """PyYAML's safe loader refusing anchors and aliases where they appear."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, AliasEvent) or (isinstance(event, NodeEvent) and event.anchor is not None):
            mark = event.start_mark
            raise _AliasMet(f"line {mark.line + 1}, column {mark.column + 1}" if mark else "")
        return super().compose_node(parent, index)


class _AliasMet(Exception):
    """An anchor or alias met while composing; carries where."""


def load_yaml(text: str, source: Path | str) -> Any:
    """The YAML document in ``text``, anchors and aliases refused; ``source`` names the file in the refusal."""
    try:
        return yaml.load(text, Loader=_NoAliasLoader)
    except _AliasMet as exc:
        raise AliasRefused(f"{source}: YAML anchors and aliases (&name, *name) are refused ({exc})") from None
    except yaml.YAMLError as exc:
        raise RigError(f"{source}: not valid YAML ({_bounded(exc)})") from None
    except RecursionError:
        raise RigError(f"{source}: not valid YAML (nested too deeply)") from None


def _bounded(exc: Exception) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= 300 else text[:297] + "..."
