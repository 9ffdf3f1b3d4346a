"""fisheye_infer.models: the PyTorch detectors, official checkpoint loading and synthetic checkpoints."""

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from .base import FisheyeDetector
from .bevdet_config import BEVDetConfig
from .checkpoint import GeometryReport, check_keys, load_checkpoint
from .config import ModelConfig, Preprocessing
from .cyl_config import BEVDetCylConfig, CylPETRConfig
from .mmconfig import read_mmdet3d_config
from .official_loading import load_official_state_dict
from .petr_config import PETRConfig
from .pinhole_config import PerspBEVDetConfig, PinholeBEVDetConfig
from .pinhole_petr_config import PerspPETRConfig, PinholePETRConfig
from .registry import ModelEntry, create_model, get_model_entry, list_models, matching_architectures, register_model
from .seeded_checkpoint import calibrated_checkpoint, make_checkpoint

__all__ = [
    "BEVDetConfig",
    "BEVDetCylConfig",
    "CylPETRConfig",
    "GeometryReport",
    "ModelConfig",
    "ModelEntry",
    "PETRConfig",
    "PerspBEVDetConfig",
    "PerspPETRConfig",
    "PinholeBEVDetConfig",
    "PinholePETRConfig",
    "Preprocessing",
    "check_keys",
    "calibrated_checkpoint",
    "create_model",
    "get_model_entry",
    "list_models",
    "matching_architectures",
    "load_checkpoint",
    "load_model",
    "load_official_state_dict",
    "make_checkpoint",
    "read_mmdet3d_config",
    "register_model",
]


def load_model(
    name: str,
    checkpoint: str | Path | Mapping[str, Any],
    config: Any = None,
    rig: Any = None,
    *,
    geometry: str = "verify",
    allow_pickle: bool = False,
) -> tuple[FisheyeDetector, GeometryReport]:
    """Build ``name`` and load an official checkpoint (path or state dict) strictly; returns (model, report).

    Args:
        name (str): A name of [`list_models`][fisheye_infer.models.registry.list_models].
        checkpoint (str | Path | Mapping[str, Any]): A ``.pth`` file, or a checkpoint already in memory (an
            mmengine ``{"state_dict", "meta"}`` dict or a bare state dict).
        config (Any): The architecture's configuration object; None: the official one.
        rig (Any): The [`Rig`][fisheye_infer.cameras.rig.Rig] the geometry tables are computed for; None: the
            default rig.
        geometry (str): The policy for the geometry tables stored in the checkpoint: ``"verify"`` (use them
            when they agree with the rig's recomputation within float rounding, refuse otherwise),
            ``"checkpoint"`` or ``"rig"`` (force that source, warning when the two differ).
        allow_pickle (bool): Read a file whose metadata holds Python objects (unpickling can run code from the
            file; warns).

    Returns:
        tuple[FisheyeDetector, GeometryReport]: The model in eval mode, and where its geometry tables came from.

    Raises:
        ConfigError: An unknown architecture or a configuration of another class.
        CheckpointError: An unreadable file, an unknown policy, a missing, unexpected or mis-shaped key, or
            stored tables that disagree with the rig's under ``"verify"``.

    Examples:
        ```python
        from fisheye_infer.models import load_model

        model, report = load_model("fisheye-bevdet", "fisheye_bevdet.pth", rig=None, geometry="verify")
        print(report.summary())
        ```
    """
    model = create_model(name, config, rig)
    if isinstance(checkpoint, Mapping):
        state_dict: Mapping[str, torch.Tensor] = checkpoint.get("state_dict", checkpoint)
    else:
        state_dict, _ = load_checkpoint(checkpoint, allow_pickle=allow_pickle)
    report = load_official_state_dict(
        model, state_dict, geometry=geometry, ignore=get_model_entry(name).ignored_keys, context=f"{name} checkpoint"
    )
    return model.eval(), report
