"""Loading an official checkpoint into a registered model: every key checked, weights loaded strictly, geometry
reconciled.

`load_official_state_dict` is the whole procedure (see `OfficialCheckpointModel`): check keys
(``checkpoint.check_keys``), map them with the architecture's registered ``checkpoint_filter``, load weights
strictly, then reconcile the geometry tables stored in the checkpoint (frustum, sampling grids) with the ones
recomputed from the rig (``checkpoint.decide_geometry``'s policies).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Protocol, runtime_checkable

import torch

from fisheye_infer.errors import CheckpointError

from .checkpoint import GEOMETRY_POLICIES, GeometryReport, KeySpec, check_keys
from .registry import entry_of

__all__ = ["OfficialCheckpointModel", "load_official_state_dict"]


@runtime_checkable
class OfficialCheckpointModel(Protocol):
    """What a model provides to be loaded from an official checkpoint."""

    def official_keys(self) -> dict[str, KeySpec]:
        """Every key of the official checkpoint, with shape and dtype, in official names."""

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare stored geometry with the recomputation and adopt one of them per ``policy``."""


def load_official_state_dict(
    model: OfficialCheckpointModel,
    state_dict: Mapping[str, torch.Tensor],
    *,
    geometry: str = "verify",
    ignore: Sequence[str] = (),
    context: str = "checkpoint",
) -> GeometryReport:
    """Check every key, load weights strictly and reconcile geometry. ``ignore`` keys are dropped with a warning.

    Args:
        model (OfficialCheckpointModel): a model of a registered architecture.
        state_dict (Mapping[str, torch.Tensor]): the checkpoint's weights and tables, in official names.
        geometry (str): the geometry policy, one of ``GEOMETRY_POLICIES``.
        ignore (Sequence[str]): keys that the inference graph never uses, dropped with a warning.
        context (str): what the messages name the checkpoint.

    Returns:
        GeometryReport: where the geometry tables came from and how they compared.

    Raises:
        CheckpointError: an unknown policy, a missing, unexpected or mis-shaped key, or stored tables that
            disagree with the rig's under ``"verify"``.
    """
    if geometry not in GEOMETRY_POLICIES:
        raise CheckpointError(
            f"geometry={geometry!r} is not a geometry policy (use one of {', '.join(GEOMETRY_POLICIES)})"
        )
    present = [k for k in ignore if k in state_dict]
    if present:
        warnings.warn(
            f"{context}: ignoring keys that the inference graph never uses: {', '.join(present)}",
            UserWarning,
            stacklevel=2,
        )
    expected = model.official_keys()
    sd = {
        k: _as_scalar(v) if k in expected and len(expected[k][0]) == 0 else v
        for k, v in state_dict.items()
        if k not in present
    }
    check_keys(expected, sd, context=context)
    weights = entry_of(model).checkpoint_filter(sd)  # type: ignore[arg-type]
    result = model.load_state_dict(weights, strict=True)  # type: ignore[attr-defined]
    if getattr(result, "missing_keys", None) or getattr(result, "unexpected_keys", None):
        raise CheckpointError(f"{context}: internal key map incomplete: {result}")
    return model.apply_checkpoint_geometry(sd, geometry)


def _as_scalar(value: torch.Tensor) -> torch.Tensor:
    """A one-element 1-D tensor stored for a 0-D buffer (older checkpoints store ``num_batches_tracked``
    as shape [1]) as the 0-D tensor it stands for, as ``torch.nn.Module.load_state_dict`` accepts it;
    anything else unchanged, for ``check_keys`` to name."""
    return value.reshape(()) if torch.is_tensor(value) and tuple(value.shape) == (1,) else value
