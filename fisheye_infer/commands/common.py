"""What several subcommands share: the install lines of the extras and argparse value types."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from fisheye_infer.runtime.session import Provider

__all__ = [
    "NEEDS_EXPORT",
    "NEEDS_SERVE",
    "NEEDS_RAY_SERVE",
    "missing_extra",
    "positive_int",
    "positive_ints",
    "int_list",
    "csv_list",
    "int_pair",
    "providers_arg",
    "PROVIDERS_HELP",
    "RIG_HELP",
]

NEEDS_EXPORT = "this command needs the export extra: pip install 'fisheye-infer[export]' (install torch==2.13.0 first)"
NEEDS_SERVE = "fisheye-infer serve needs the serve extra: pip install 'fisheye-infer[serve]'"
NEEDS_RAY_SERVE = "fisheye-infer serve --ray needs the ray extra: pip install 'fisheye-infer[ray]'"
PROVIDERS_HELP = (
    "ONNX Runtime execution providers, comma-separated in order of preference "
    "(CUDAExecutionProvider,CPUExecutionProvider), "
    'a JSON list with provider options (\'[["CUDAExecutionProvider", {"device_id": 1}], "CPUExecutionProvider"]\'), '
    "or 'auto' for the installed accelerated ones, then CPU (default: CPU)"
)
RIG_HELP = "rig file (.json/.yaml), folder with calib_results.txt + lidar2cam.json, or 'default'"


def missing_extra(needs: str, exc: ImportError) -> int:
    """Say which extra a command needs (and what was missing); the exit code 1."""
    print(f"{needs} ({exc})", file=sys.stderr)
    return 1


def positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {value}")
    return value


def positive_ints(text: str) -> list[int]:
    """Comma-separated positive integers: ``1,2,4``."""
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected comma-separated positive integers, got {text!r}")
    return values


def int_list(text: str) -> tuple[int, ...]:
    """Comma-separated integers, possibly none: ``0,1``."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated integers, got {text!r}") from None


def csv_list(text: str) -> list[str]:
    """A non-empty comma-separated list of names."""
    items = [t.strip() for t in text.split(",") if t.strip()]
    if not items:
        raise argparse.ArgumentTypeError(f"expected a comma-separated list, got {text!r}")
    return items


def int_pair(text: str) -> tuple[int, int]:
    """``MIN,MAX`` with 0 <= MIN <= MAX."""
    try:
        lo, hi = (int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN,MAX (two integers), got {text!r}") from None
    if not 0 <= lo <= hi:
        raise argparse.ArgumentTypeError(f"expected 0 <= MIN <= MAX, got {text!r}")
    return lo, hi


class ArchChoices:
    """The ``--arch`` choices: the registered architectures (``fisheye_infer.models.list_models()``), or with
    ``trainable`` those that ``fisheye-infer train`` trains (``fisheye_infer.models.training.trainable.TRAINABLE``).

    Looked up only when a value is checked or the help is printed, so building the parser never
    imports torch; without the export extra every name passes, and the command then says which
    extra it needs.
    """

    def __init__(self, trainable: bool = False) -> None:
        """Choices from the registry, or with ``trainable`` (bool) from the trainable architectures."""
        self.trainable = trainable

    def _names(self) -> list[str] | None:
        try:
            if self.trainable:
                from fisheye_infer.models.training.trainable import TRAINABLE

                return list(TRAINABLE)
            from fisheye_infer.models import list_models
        except ImportError:
            return None
        return list_models()

    def __contains__(self, name: object) -> bool:
        names = self._names()
        return names is None or name in names

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self._names() or ())


def providers_arg(text: str) -> str | list[Provider]:
    """``session.parse_providers``, checked against the installed onnxruntime here, so a typo or a
    CPU-only onnxruntime is a usage error that lists what is available."""
    from fisheye_infer.runtime.session import parse_providers

    try:
        return parse_providers(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("providers: ")) from None
