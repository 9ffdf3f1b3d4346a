"""A module's ``geom.*`` tables as non-persistent buffers: installed by name, read back by name.

The tables are calibration constants, not checkpoint keys, so they never enter a state dict;
a buffer's name is the table's with dots replaced (``geom.warp.index`` -> ``geom_warp_index``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import numpy as np
import torch
from torch import nn

__all__ = ["install_tables", "installed_tables"]


def _buffer_name(table: str) -> str:
    return table.replace(".", "_")


def install_tables(
    module: nn.Module,
    tables: Mapping[str, np.ndarray],
    replacing: Iterable[str] = (),
    device: torch.device | None = None,
) -> tuple[str, ...]:
    """Register ``tables`` as buffers of ``module`` (dropping the ``replacing`` ones first); returns their names."""
    for name in replacing:
        delattr(module, _buffer_name(name))
    for name, value in tables.items():
        module.register_buffer(
            _buffer_name(name), torch.from_numpy(np.ascontiguousarray(value)).to(device), persistent=False
        )
    return tuple(tables)


def installed_tables(module: nn.Module, names: Iterable[str]) -> dict[str, torch.Tensor]:
    """The buffers of the tables ``names``, by table name."""
    return {name: getattr(module, _buffer_name(name)) for name in names}
