"""Reading official checkpoints and loading them strictly, with geometry checked, never silently.

- `load_checkpoint` reads a ``.pth`` with ``torch.load(weights_only=True)``; mmengine files
  (``{'state_dict', 'meta', ...}``) and bare state dicts are both accepted. Files whose metadata
  holds arbitrary Python objects need ``allow_pickle=True``, which can execute code from the file
  and therefore warns.
- `check_keys` compares a state dict with what a model expects and reports *every* missing,
  unexpected, mis-shaped or wrongly typed key in one `CheckpointError`.
- `TableCheck` / `decide_geometry` implement the geometry policy:
  ``"verify"`` (default) uses the stored tables when they agree with the recomputation within
  float rounding and raises otherwise; ``"checkpoint"`` and ``"rig"`` force a source and warn
  when the two differ.
"""

from __future__ import annotations

import pickle
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from fisheye_infer.errors import CheckpointError

__all__ = [
    "GeometryPolicy",
    "GEOMETRY_POLICIES",
    "KeySpec",
    "load_checkpoint",
    "check_keys",
    "TableCheck",
    "decide_geometry",
    "warn_of_other_lenses",
    "GeometryReport",
]

GeometryPolicy = Literal["verify", "checkpoint", "rig"]
GEOMETRY_POLICIES: tuple[str, ...] = ("verify", "checkpoint", "rig")
KeySpec = tuple[tuple[int, ...], torch.dtype]


def _unsafe_globals(path: Path) -> list[str]:
    getter = getattr(torch.serialization, "get_unsafe_globals_in_checkpoint", None)
    if getter is None:
        return []
    try:
        return list(getter(str(path)))
    except Exception:  # the file may be legacy or corrupt; the caller reports the load error
        return []


def load_checkpoint(path: str | Path, *, allow_pickle: bool = False) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """Return ``(state_dict, meta)`` from an mmengine checkpoint or a bare state dict.

    The weights are read with ``weights_only=True``. ``allow_pickle=True`` lifts that restriction
    (needed for mmengine files whose ``meta``/``message_hub`` hold Python objects) and warns,
    because unpickling can run code from the file.

    Args:
        path (str | Path): The ``.pth`` file.
        allow_pickle (bool): Unpickle arbitrary objects (only for files from a trusted source).

    Returns:
        tuple[dict[str, torch.Tensor], dict[str, Any]]: The state dict (a ``module.`` prefix of a DataParallel
            save removed) and the file's ``meta`` (empty for a bare state dict).

    Raises:
        CheckpointError: No such file, a file ``torch.load`` cannot read (naming the Python objects it stores
            when ``weights_only`` refuses them), or content that is neither form.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path}: no such file")
    if allow_pickle:
        warnings.warn(
            f"loading {path} with allow_pickle=True: unpickling can execute code stored in the file; "
            "use it only for checkpoints from a trusted source",
            UserWarning,
            stacklevel=2,
        )
    try:
        obj = torch.load(path, map_location="cpu", weights_only=not allow_pickle)
    except (pickle.UnpicklingError, RuntimeError, AttributeError, ModuleNotFoundError, EOFError) as exc:
        if allow_pickle:
            raise CheckpointError(f"checkpoint {path}: cannot be read ({exc})") from None
        blocked = _unsafe_globals(path)
        detail = f" It stores Python objects: {', '.join(blocked[:8])}." if blocked else ""
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(
            f"checkpoint {path}: cannot be read with torch.load(weights_only=True) ({first}).{detail} "
            "If the file comes from a trusted source (e.g. an mmengine training run whose metadata "
            "holds Python objects), load it with allow_pickle=True; that unpickles arbitrary objects "
            "and can execute code, and a warning is issued."
        ) from None
    state_dict, meta = _unwrap(obj, path)
    return state_dict, meta


def _unwrap(obj: Any, path: Path) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    if isinstance(obj, Mapping) and "state_dict" in obj and isinstance(obj["state_dict"], Mapping):
        sd, meta = dict(obj["state_dict"]), obj.get("meta") or {}
    elif isinstance(obj, Mapping) and obj and all(isinstance(v, torch.Tensor) for v in obj.values()):
        sd, meta = dict(obj), {}
    else:
        kind = f"dict with keys {sorted(map(str, obj))[:10]}" if isinstance(obj, Mapping) else type(obj).__name__
        raise CheckpointError(
            f"checkpoint {path}: expected an mmengine checkpoint with 'state_dict' or a "
            f"state dict of tensors, got a {kind}"
        )
    bad = [k for k, v in sd.items() if not isinstance(v, torch.Tensor)]
    if bad:
        raise CheckpointError(f"checkpoint {path}: state_dict entries that are not tensors: {', '.join(map(str, bad))}")
    if sd and all(k.startswith("module.") for k in sd):  # saved from a DataParallel wrapper
        sd = {k[len("module.") :]: v for k, v in sd.items()}
    return sd, dict(meta) if isinstance(meta, Mapping) else {"meta": meta}


def check_keys(
    expected: Mapping[str, KeySpec], state_dict: Mapping[str, torch.Tensor], *, context: str = "checkpoint"
) -> None:
    """Raise one CheckpointError naming every missing, unexpected, mis-shaped or mistyped key."""
    missing = [k for k in expected if k not in state_dict]
    unexpected = [k for k in state_dict if k not in expected]
    shapes, dtypes = [], []
    for key, (shape, dtype) in expected.items():
        if key not in state_dict:
            continue
        value = state_dict[key]
        if tuple(value.shape) != tuple(shape):
            shapes.append(f"{key}: checkpoint {list(value.shape)}, model {list(shape)}")
        elif value.is_floating_point() != dtype.is_floating_point:
            dtypes.append(f"{key}: checkpoint {value.dtype}, model {dtype}")
    if not (missing or unexpected or shapes or dtypes):
        return
    lines = [f"{context} does not fit the model:"]
    for title, items in (
        ("missing keys", missing),
        ("unexpected keys", unexpected),
        ("shape mismatches", shapes),
        ("dtype mismatches", dtypes),
    ):
        if items:
            lines.append(f"  {len(items)} {title}:")
            lines += [f"    {item}" for item in items]
    raise CheckpointError("\n".join(lines))


@dataclass(frozen=True)
class TableCheck:
    """A geometry table stored in a checkpoint next to the same table recomputed from the rig."""

    key: str
    stored: np.ndarray
    recomputed: np.ndarray
    atol: float = 0.0
    rtol: float = 0.0

    @property
    def max_abs_error(self) -> float:
        diff = np.abs(np.asarray(self.stored, np.float64) - np.asarray(self.recomputed, np.float64))
        return float(diff.max(initial=0.0))

    @property
    def agrees(self) -> bool:
        s = np.asarray(self.stored, np.float64)
        r = np.asarray(self.recomputed, np.float64)
        return s.shape == r.shape and bool(np.all(np.abs(s - r) <= self.atol + self.rtol * np.abs(r)))

    def describe(self) -> str:
        tol = f"atol {self.atol:g}" + (f" + rtol {self.rtol:g}" if self.rtol else "")
        return f"{self.key}: max |stored - recomputed| = {self.max_abs_error:.3g} (tolerance {tol})"


def decide_geometry(checks: Sequence[TableCheck], policy: str, *, context: str = "checkpoint") -> str:
    """Return which geometry to use, ``'checkpoint'`` or ``'rig'``, according to ``policy``."""
    if policy not in GEOMETRY_POLICIES:
        raise CheckpointError(
            f"geometry={policy!r} is not a geometry policy (use one of {', '.join(GEOMETRY_POLICIES)})"
        )
    differing = [c for c in checks if not c.agrees]
    if policy == "verify":
        if differing:
            details = "\n".join(f"  {c.describe()}" for c in differing)
            raise CheckpointError(
                f"{context}: the geometry stored in the checkpoint differs from the one recomputed for this rig "
                f"and configuration, so the rig (camera intrinsics or view-transform ranges) differs from the one "
                f"the checkpoint was trained with:\n{details}\n"
                "Pass geometry='checkpoint' to use the stored tables or geometry='rig' to use the recomputed ones."
            )
        return "checkpoint"
    if differing:
        details = "; ".join(c.describe() for c in differing)
        warnings.warn(
            f"{context}: stored and recomputed geometry differ ({details}); using the "
            f"{'stored' if policy == 'checkpoint' else 'recomputed'} tables as geometry={policy!r} asks",
            UserWarning,
            stacklevel=3,
        )
    return policy


def warn_of_other_lenses(context: str, camera_names: Sequence[str], tables: np.ndarray, policy: str) -> None:
    """An official checkpoint stores one lens's tables, compared with the first camera's (``tables``, the rig's
    per camera); name the cameras with lenses of their own, whose tables the rig gives unchecked."""
    others = [name for name, table in zip(camera_names, tables) if not np.array_equal(table, tables[0])]
    if others and policy != "rig":
        warnings.warn(
            f"{context}: the checkpoint stores the tables of one lens, compared with camera '{camera_names[0]}'; "
            f"cameras {', '.join(others)} have lenses of their own, whose tables come from the rig unchecked",
            UserWarning,
            stacklevel=3,
        )


@dataclass(frozen=True)
class GeometryReport:
    """What the loader did with the geometry tables.

    Attributes:
        source (str): Where the model's tables came from: ``"checkpoint"`` or ``"rig"``.
        checks (tuple[TableCheck, ...]): Each stored table next to its recomputation from the rig (``key``,
            ``max_abs_error``, ``agrees``).
    """

    source: str
    checks: tuple[TableCheck, ...]

    def summary(self) -> str:
        """One line: the source, and each table's largest difference and tolerance.

        Returns:
            str: ``geometry from <source>: <key>: max |stored - recomputed| = ... (tolerance ...); ...``.
        """
        rows = "; ".join(c.describe() for c in self.checks)
        return f"geometry from {self.source}: {rows}"


def as_numpy(t: torch.Tensor) -> np.ndarray:
    """Detached CPU numpy copy of a tensor."""
    return t.detach().cpu().numpy().copy()
