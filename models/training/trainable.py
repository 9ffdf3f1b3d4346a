"""The architectures ``Trainer`` trains, and which of them a configuration or a config file is.

They are the architectures of the compact table (``compact.COMPACT``): the paper's two detectors and the
baselines of its Table 2, each with an objective in ``objectives.py``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fisheye_infer.errors import ConfigError

from .compact import COMPACT

__all__ = ["TRAINABLE", "arch_of", "read_config_file"]

#: The trainable architectures, in the order of the compact table.
TRAINABLE: tuple[str, ...] = tuple(COMPACT)


def arch_of(config: Any) -> str:
    """The trainable architecture whose configuration class ``config`` is.

    Args:
        config (Any): a model configuration (a ``ModelConfig`` subclass instance).

    Returns:
        str: the architecture's name, one of ``TRAINABLE``.

    Raises:
        ConfigError: no trainable architecture takes a configuration of that class.
    """
    from fisheye_infer.models import get_model_entry

    for name in TRAINABLE:
        if type(config) is get_model_entry(name).config_cls:
            return name
    raise ConfigError(f"no trainable architecture takes a {type(config).__name__} (trainable: {', '.join(TRAINABLE)})")


def read_config_file(path: str | Path) -> Any:
    """The configuration of an mmdet3d-style file of a trainable architecture: the one whose reader takes it.

    Args:
        path (str | Path): the config file.

    Returns:
        Any: the configuration (a ``ModelConfig`` subclass instance).

    Raises:
        ConfigError: no trainable architecture's reader takes the file, or several do.
    """
    from fisheye_infer.models import get_model_entry

    read, refusals = [], []
    for name in TRAINABLE:
        try:
            read.append(get_model_entry(name).config_cls.from_mmdet3d_config(path))
        except ConfigError as exc:
            refusals.append(f"{name}: {exc}")
    if len(read) == 1:
        return read[0]
    if not read:
        raise ConfigError(f"{path} is no configuration of a trainable architecture:\n  " + "\n  ".join(refusals))
    raise ConfigError(f"{path} reads as several architectures ({', '.join(arch_of(c) for c in read)})")
