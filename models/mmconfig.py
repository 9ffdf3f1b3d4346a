"""Read an official mmengine/mmdet3d Python config without executing it.

Official configs are Python files, and running them would execute arbitrary code (``import os``,
``custom_imports`` of project packages, ...). Instead the file is parsed with `ast` and only a
small, pure subset is evaluated:

- literals (numbers, strings, booleans, None), lists, tuples, dicts (``**`` unpacking of dicts);
- arithmetic ``+ - * / // % **``, unary ``-``/``+``, subscripts (``pcr[0]``, ``pcr[:3]``);
- names bound by earlier top-level assignments;
- calls to ``dict``/``list``/``tuple`` and the pure numeric builtins ``int``/``float``/``abs``/``round``/
  ``min``/``max`` (the official schedules use ``int(0.4*max_epochs)``);
- ``math.radians``, ``math.degrees``, ``math.pi``, ``math.e``, ``np.pi``/``numpy.pi``, after
  ``import math`` / ``import numpy as np`` (these imports only bind the whitelisted names).

Anything else raises `ConfigError` naming the file, the line and the construct. Every
value it builds is bounded: a string, list, tuple or dict of more than ``_MAX_LEN`` items (made by
``*``, ``+``, a call or a literal) and more than ``_MAX_TOTAL`` items built over the whole file are
refused before they are built, as are ``%`` formatting of strings, integers of more than
``_MAX_INT_BITS`` bits and expressions nested too deeply, so a hostile file cannot exhaust memory.
``_base_`` is returned as a value; bases are merged only on request (``merge_bases=True``).

`Section` reads the evaluated namespace: one dict of it, every value converted to tuples
and numbers on the way out, every error naming the file and the key's path. All model
configurations read their official files through it.
"""

from __future__ import annotations

import ast
import math
import operator
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fisheye_infer.errors import ConfigError

from .mmconfig_section import Section, as_tuple

__all__ = ["MAX_CONFIG_BYTES", "read_mmdet3d_config", "evaluate_config_source", "Section", "as_tuple"]

_BINOPS: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.FloorDiv: operator.floordiv,
    ast.Mod: operator.mod,
    ast.Pow: operator.pow,
}
_UNARY: dict[type, Callable[[Any], Any]] = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_BUILTINS: dict[str, Callable[..., Any]] = {
    "dict": dict,
    "list": list,
    "tuple": tuple,
    "int": int,
    "float": float,
    "abs": abs,
    "round": round,
    "min": min,
    "max": max,
}
# module -> attribute -> value or pure function
_MODULES: dict[str, dict[str, Any]] = {
    "math": {"radians": math.radians, "degrees": math.degrees, "pi": math.pi, "e": math.e, "inf": math.inf},
    "numpy": {"pi": math.pi},
}
_MAX_POW = 64
_MAX_LEN = 1_000_000  # items (characters) of one string, list, tuple or dict
_MAX_TOTAL = 20_000_000  # items built over the whole file: many bounded values must not add up
MAX_CONFIG_BYTES = 4 * 1024 * 1024  # of one config file; the official ones are a few kB
_MAX_BASE_DEPTH = 16  # files reached through _base_, one inside another
_MAX_INT_BITS = 4096  # chained ``**``/``*`` of integers would otherwise grow without bound
_SIZED = (str, list, tuple, dict)


def _result_len(op: ast.operator, left: Any, right: Any) -> int:
    """The length ``left <op> right`` would have, computed without building it (0: not a sequence)."""
    if isinstance(op, ast.Mult):
        for seq, count in ((left, right), (right, left)):
            if isinstance(seq, (str, list, tuple)) and isinstance(count, int) and not isinstance(count, bool):
                return max(count, 0) * len(seq)
    if isinstance(op, ast.Add) and isinstance(left, (str, list, tuple)) and type(left) is type(right):
        return len(left) + len(right)
    return 0


class _Evaluator:
    def __init__(self, source: str, filename: str) -> None:
        self.source, self.filename = source, filename
        self.env: dict[str, Any] = {}
        self.aliases: dict[str, str] = {}  # local name -> module in _MODULES
        self.imported: dict[str, Any] = {}  # names bound by `from math import radians`
        self.built = 0  # items of the strings, lists, tuples and dicts built so far

    def charge(self, node: ast.AST, size: int) -> None:
        """Count ``size`` items about to be built; refuse one value or a file total over the bounds."""
        if size > _MAX_LEN:
            raise self.fail(node, f"building a value of {size:,} items (at most {_MAX_LEN:,})")
        self.built += size
        if self.built > _MAX_TOTAL:
            raise self.fail(node, f"building more than {_MAX_TOTAL:,} items in all")

    def fail(self, node: ast.AST, what: str) -> ConfigError:
        line = getattr(node, "lineno", "?")
        snippet = ast.get_source_segment(self.source, node) or type(node).__name__
        snippet = snippet.splitlines()[0][:80]
        return ConfigError(
            f"{self.filename} line {line}: {what} is not allowed in a configuration "
            f"(found `{snippet}`); only literals, arithmetic, dict/list/tuple and "
            "math.radians/math.pi are evaluated"
        )

    def run(self, tree: ast.Module) -> dict[str, Any]:
        for stmt in tree.body:
            if (
                isinstance(stmt, ast.Expr)
                and isinstance(stmt.value, ast.Constant)
                and isinstance(stmt.value.value, str)
            ):
                continue  # docstring
            if isinstance(stmt, ast.Import):
                for alias in stmt.names:
                    if alias.name not in _MODULES:
                        raise self.fail(stmt, f"import of module '{alias.name}'")
                    self.aliases[alias.asname or alias.name] = alias.name
            elif isinstance(stmt, ast.ImportFrom):
                if stmt.module not in _MODULES or stmt.level:
                    raise self.fail(stmt, f"import from module '{stmt.module}'")
                for alias in stmt.names:
                    if alias.name not in _MODULES[stmt.module]:
                        raise self.fail(stmt, f"import of '{stmt.module}.{alias.name}'")
                    self.imported[alias.asname or alias.name] = _MODULES[stmt.module][alias.name]
            elif isinstance(stmt, (ast.Assign, ast.AnnAssign)):
                targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
                if stmt.value is None:
                    raise self.fail(stmt, "an annotation without a value")
                value = self.eval(stmt.value)
                for target in targets:
                    if not isinstance(target, ast.Name):
                        raise self.fail(target, f"assignment to {type(target).__name__}")
                    self.env[target.id] = value
            else:
                raise self.fail(stmt, f"statement '{type(stmt).__name__}'")
        return dict(self.env)

    def eval(self, node: ast.AST) -> Any:  # noqa: C901 - one branch per allowed construct
        if isinstance(node, ast.Constant):
            if isinstance(node.value, (bytes, complex)) or node.value is Ellipsis:
                raise self.fail(node, f"constant of type {type(node.value).__name__}")
            return node.value
        if isinstance(node, ast.List):
            self.charge(node, len(node.elts))
            return [self.eval(e) for e in self._no_starred(node.elts)]
        if isinstance(node, ast.Tuple):
            self.charge(node, len(node.elts))
            return tuple(self.eval(e) for e in self._no_starred(node.elts))
        if isinstance(node, ast.Dict):
            out: dict[Any, Any] = {}
            for k, v in zip(node.keys, node.values):
                if k is None:
                    extra = self._as_dict(v)
                    self.charge(node, len(out) + len(extra))
                    out.update(extra)
                else:
                    out[self.eval(k)] = self.eval(v)
            self.charge(node, len(out))
            return out
        if isinstance(node, ast.Name):
            if node.id in self.env:
                return self.env[node.id]
            if node.id in self.imported:
                return self.imported[node.id]
            raise self.fail(node, f"name '{node.id}' (not assigned earlier in the file)")
        if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
            left, right = self.eval(node.left), self.eval(node.right)
            if isinstance(node.op, ast.Pow) and isinstance(right, (int, float)) and abs(right) > _MAX_POW:
                raise self.fail(node, f"an exponent of {right}")
            if isinstance(node.op, ast.Mod) and isinstance(left, str):
                raise self.fail(node, "'%' formatting of a string")
            self.charge(node, _result_len(node.op, left, right))
            try:
                result = _BINOPS[type(node.op)](left, right)
            except Exception as exc:  # TypeError, ZeroDivisionError, ...
                raise self.fail(node, f"arithmetic that fails ({exc})") from None
            if isinstance(result, int) and result.bit_length() > _MAX_INT_BITS:
                raise self.fail(node, f"an integer of more than {_MAX_INT_BITS} bits")
            return result
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
            return _UNARY[type(node.op)](self.eval(node.operand))
        if isinstance(node, ast.Attribute):
            return self._attribute(node)
        if isinstance(node, ast.Subscript):
            container = self.eval(node.value)
            index = self._slice(node.slice)
            try:
                return container[index]
            except Exception as exc:
                raise self.fail(node, f"a subscript that fails ({exc})") from None
        if isinstance(node, ast.Call):
            return self._call(node)
        raise self.fail(node, f"expression '{type(node).__name__}'")

    def _no_starred(self, elts: list[ast.expr]) -> list[ast.expr]:
        for e in elts:
            if isinstance(e, ast.Starred):
                raise self.fail(e, "star unpacking")
        return elts

    def _as_dict(self, node: ast.AST) -> dict[Any, Any]:
        value = self.eval(node)
        if not isinstance(value, dict):
            raise self.fail(node, "'**' unpacking of a non-dict")
        return value

    def _slice(self, node: ast.AST) -> Any:
        if isinstance(node, ast.Slice):
            parts = [None if p is None else self.eval(p) for p in (node.lower, node.upper, node.step)]
            return slice(*parts)
        return self.eval(node)

    def _attribute(self, node: ast.Attribute) -> Any:
        if isinstance(node.value, ast.Name) and node.value.id in self.aliases:
            table = _MODULES[self.aliases[node.value.id]]
            if node.attr in table:
                return table[node.attr]
        raise self.fail(node, "attribute access")

    def _call(self, node: ast.Call) -> Any:
        func: Callable[..., Any] | None = None
        if isinstance(node.func, ast.Name) and node.func.id not in self.env:
            func = _BUILTINS.get(node.func.id) or self.imported.get(node.func.id)
        elif (
            isinstance(node.func, ast.Attribute)
            and isinstance(node.func.value, ast.Name)
            and node.func.value.id in self.aliases
        ):
            value = _MODULES[self.aliases[node.func.value.id]].get(node.func.attr)
            func = value if callable(value) else None
        if func is None or not callable(func):
            raise self.fail(node, "function call")
        args = [self.eval(a) for a in self._no_starred(node.args)]
        kwargs: dict[str, Any] = {}
        for kw in node.keywords:
            if kw.arg is None:
                if func is not dict:
                    raise self.fail(kw, "'**' in a call other than dict()")
                kwargs.update(self._as_dict(kw.value))
            else:
                kwargs[kw.arg] = self.eval(kw.value)
        if kwargs and func is not dict:
            raise self.fail(node, "keyword arguments outside dict()")
        if func in (dict, list, tuple):
            self.charge(node, len(kwargs) + sum(len(a) if isinstance(a, _SIZED) else 0 for a in args))
        try:
            result: Any = func(*args, **kwargs)
        except Exception as exc:
            raise self.fail(node, f"a call that fails ({exc})") from None
        if isinstance(result, int) and result.bit_length() > _MAX_INT_BITS:
            raise self.fail(node, f"an integer of more than {_MAX_INT_BITS} bits")
        return result


def evaluate_config_source(source: str, filename: str = "<config>") -> dict[str, Any]:
    """Evaluate config text with the restricted evaluator; returns the top-level variables in order."""
    try:
        tree = ast.parse(source, filename=filename)
    except SyntaxError as exc:
        where = f" line {exc.lineno}" if exc.lineno else ""
        raise ConfigError(f"{filename}{where}: not valid Python ({exc.msg})") from None
    except ValueError as exc:  # Python 3.10: "source code string cannot contain null bytes"
        raise ConfigError(f"{filename}: not valid Python ({exc})") from None
    except (RecursionError, MemoryError):
        raise ConfigError(f"{filename}: expressions nested too deeply to read") from None
    try:
        return _Evaluator(source, filename).run(tree)
    except RecursionError:
        raise ConfigError(f"{filename}: expressions nested too deeply to evaluate") from None


def _merge(base: dict[str, Any], child: dict[str, Any]) -> dict[str, Any]:
    """mmengine merge: child dicts update base dicts recursively unless they set ``_delete_=True``."""
    out = dict(base)
    for key, value in child.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and not value.get("_delete_", False):
            out[key] = _merge(out[key], value)
        elif isinstance(value, dict):
            out[key] = {k: v for k, v in value.items() if k != "_delete_"}
        else:
            out[key] = value
    return out


def read_mmdet3d_config(path: str | Path, *, merge_bases: bool = False) -> dict[str, Any]:
    """Return the top-level variables of an official config file, evaluated without executing it.

    With ``merge_bases`` the files in ``_base_`` (relative to ``path``) are read the same way and
    merged first, child values winning; otherwise ``_base_`` is kept as a plain value. A file of more
    than ``MAX_CONFIG_BYTES``, one that is not UTF-8 text, a ``_base_`` entry that is not a file name,
    bases nested more than ``_MAX_BASE_DEPTH`` deep and a file that is its own base are refused.

    Args:
        path (str | Path): The official config file (``.py``).
        merge_bases (bool): Read and merge the ``_base_`` files first.

    Returns:
        dict[str, Any]: The top-level names and their values (dicts, lists, tuples, numbers, strings).

    Raises:
        ConfigError: A file that is missing, too large or not UTF-8, a construct outside the evaluated subset
            (named with its line), a value too large, or a bad ``_base_``.

    Examples:
        ```python
        from fisheye_infer.models import read_mmdet3d_config

        cfg = read_mmdet3d_config("configs/fisheye_bevdet.py")
        cfg["model"]["type"]         # "BEVDet"
        ```
    """
    return _read(Path(path), merge_bases, ())


def _read(path: Path, merge_bases: bool, chain: tuple[Path, ...]) -> dict[str, Any]:
    """``read_mmdet3d_config`` of ``path``, reached through the bases of ``chain`` (outermost first)."""
    try:
        with path.open("rb") as stream:  # a bounded read: a FIFO or /dev/zero has no size to check first
            data = stream.read(MAX_CONFIG_BYTES + 1)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(
                f"configuration {path}: more than {MAX_CONFIG_BYTES:,} bytes (official configs are a few kB)"
            )
        source = data.decode("utf-8")
    except OSError as exc:
        raise ConfigError(f"cannot read configuration {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ConfigError(f"configuration {path}: not a Python config file (not UTF-8: byte {exc.start})") from None
    cfg = evaluate_config_source(source, str(path))
    if not merge_bases or "_base_" not in cfg:
        return cfg
    bases = cfg.pop("_base_")
    chain = (*chain, path.resolve())
    merged: dict[str, Any] = {}
    for base in [bases] if isinstance(bases, str) else list(bases) if isinstance(bases, list | tuple) else [bases]:
        if not isinstance(base, str):
            raise ConfigError(f"configuration {path}: _base_: expected file names, got {type(base).__name__}")
        target = path.parent / base
        if target.resolve() in chain or len(chain) > _MAX_BASE_DEPTH:
            why = "refers back to a file it is based on" if target.resolve() in chain else "nested too deep"
            trail = " -> ".join(str(p) for p in (*chain, target))
            raise ConfigError(f"configuration {path}: _base_ {why} ({trail[-600:]})")
        merged = _merge(merged, _read(target, True, chain))
    return _merge(merged, cfg)
