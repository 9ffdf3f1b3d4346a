"""Seeded synthetic checkpoints in the official format, for tests and export work without real weights.

``make_checkpoint(arch, seed)`` builds the registered model, gives it fan-in scaled weights and
small biases, then calibrates every BatchNorm's running statistics by running the model with BN
layers in statistics-collection mode on seeded synthetic frames (`calibrate`, per model
family), so activations stay O(1) at inference. The result is an
mmengine-style ``{'state_dict', 'meta'}`` dict with every official key (geometry tables included,
computed from the rig, so they agree with a recomputation) in official order, shape and dtype.

A model taking part implements ``official_state_dict()`` (official names, weights and geometry);
`batchnorm_statistics`, `temper_attention` and `synthetic_images` are the
building blocks of the calibrations.
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fisheye_infer.errors import CheckpointError

from .registry import create_model, read_manifest
from .seeded_calibration import batchnorm_statistics, calibrate, init_weights, synthetic_images

__all__ = [
    "make_checkpoint",
    "calibrated_checkpoint",
    "calibrate",
    "init_weights",
    "batchnorm_statistics",
    "synthetic_images",
    "manifest_specs",
]

_DTYPES = {"float32": torch.float32, "int64": torch.int64}


def manifest_specs(arch: str) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """Certain keys of an architecture's manifest (uncertain ones excluded), with shape and dtype."""
    return {e["key"]: (tuple(e["shape"]), _DTYPES[e["dtype"]]) for e in read_manifest(arch) if not e.get("uncertain")}


def _verify_manifest(arch: str, state_dict: dict[str, torch.Tensor]) -> None:
    specs = manifest_specs(arch)
    problems = [f"missing {k}" for k in specs if k not in state_dict]
    problems += [f"unexpected {k}" for k in state_dict if k not in specs]
    problems += [
        f"{k}: {list(v.shape)}/{v.dtype} vs manifest {list(specs[k][0])}/{specs[k][1]}"
        for k, v in state_dict.items()
        if k in specs and (tuple(v.shape) != specs[k][0] or v.dtype != specs[k][1])
    ]
    if problems:
        raise CheckpointError(f"synthetic {arch} checkpoint disagrees with its manifest: " + "; ".join(problems))


def make_checkpoint(
    arch: str, seed: int = 0, path: str | Path | None = None, *, config: Any = None, rig: Any = None
) -> dict[str, Any]:
    """Seeded synthetic checkpoint ``{'state_dict', 'meta'}`` for a registered architecture.

    With the default configuration the keys, shapes and dtypes are checked against the
    architecture's manifest. If ``path`` is given the checkpoint is also saved there.

    Args:
        arch (str): A name of [`list_models`][fisheye_infer.models.registry.list_models].
        seed (int): The seed of the weights and of the calibration frames; the same seed gives the same weights.
        path (str | Path | None): Where to save it with ``torch.save``; None: not saved.
        config (Any): The architecture's configuration object; None: the official one.
        rig (Any): The [`Rig`][fisheye_infer.cameras.rig.Rig] its geometry tables are computed for; None: the
            default rig.

    Returns:
        dict[str, Any]: ``{"state_dict": official keys -> tensors (geometry tables included), "meta": {"arch",
            "seed", "synthetic": True, "config"}}``.

    Raises:
        ConfigError: An unknown architecture or a configuration of another class.
        CheckpointError: With the official configuration, a key, shape or dtype that disagrees with the
            manifest.

    Examples:
        ```python
        from fisheye_infer.models import load_model, make_checkpoint

        ckpt = make_checkpoint("fisheye-petr", seed=0, path="fisheye_petr_seed0.pth")
        model, report = load_model("fisheye-petr", ckpt)     # loads strictly; tables agree with the rig
        ```
    """
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(seed))
        model = create_model(arch, config, rig)
        init_weights(model, seed)
        calibrate(model, seed)
        model.eval()
        state_dict = {k: v.detach().clone().contiguous() for k, v in model.official_state_dict().items()}
    if config is None:
        _verify_manifest(arch, state_dict)
    meta: dict[str, Any] = {"arch": arch, "seed": int(seed), "synthetic": True, "config": model.config.to_dict()}
    ckpt = {"state_dict": state_dict, "meta": meta}
    if path is not None:
        torch.save(ckpt, Path(path))
    return ckpt


def _keyed_tensor(key: str, shape: tuple[int, ...], dtype: str, seed: int) -> np.ndarray:
    """One learnable tensor from a generator seeded by (seed, crc32(key)): it depends only on the
    key, its shape and the seed, not on key order, machine or torch version. LeCun-scaled normals
    (variance 1 / fan_in) keep activations of order one; 1-D weights near 1, 1-D biases near 0."""
    rng = np.random.default_rng([seed, zlib.crc32(key.encode())])
    leaf = key.rsplit(".", 1)[-1]
    if "int" in dtype or leaf == "running_mean":
        x = np.zeros(shape)
    elif leaf == "running_var":
        x = np.ones(shape)
    elif key.endswith("reference_points.weight"):
        x = rng.uniform(0.0, 1.0, shape)
    elif len(shape) == 1 and leaf == "weight":
        x = 1.0 + rng.normal(0.0, 0.1, shape)
    elif len(shape) == 1:
        x = rng.normal(0.0, 0.05, shape)
    else:
        fan_in = int(np.prod(shape[1:])) if len(shape) > 1 else 1
        x = rng.normal(0.0, 1.0, shape) * np.sqrt(1.0 / max(fan_in, 1))
    return x.astype(np.int64 if "int" in dtype else np.float32)


def calibrated_checkpoint(
    arch: str,
    statistics: Mapping[str, np.ndarray],
    geometry: Mapping[str, np.ndarray],
    seed: int = 0,
    path: str | Path | None = None,
) -> dict[str, Any]:
    """An official-format checkpoint whose BatchNorm statistics were measured elsewhere.

    Learnable tensors come from per-key seeded generators (``_keyed_tensor``); BatchNorm running
    statistics from ``statistics`` (calibrated by running the official model on these very
    weights, so features and heads spread as a trained network's do, with no saturated or
    collapsed head); geometry buffers from ``geometry`` (official key names). Every manifest key
    must be covered. PETR's per-layer cls/reg branch copies are made equal, as the official head
    shares one module across its decoder layers.

    Args:
        arch (str): A name of [`list_models`][fisheye_infer.models.registry.list_models].
        statistics (Mapping[str, np.ndarray]): BatchNorm ``running_mean``/``running_var`` by official key.
        geometry (Mapping[str, np.ndarray]): Geometry buffers by official key.
        seed (int): The seed of the learnable tensors (per key: independent of key order and machine).
        path (str | Path | None): Where to save it with ``torch.save``; None: not saved.

    Returns:
        dict[str, Any]: ``{"state_dict", "meta": {"arch", "seed", "synthetic": True, "statistics":
            "calibrated"}}``, every manifest key in official shape and dtype.

    Raises:
        ConfigError: An unknown architecture.
        CheckpointError: The state dict disagrees with the manifest.
        ValueError: A given array that cannot be reshaped to its key's shape.
    """
    entries = [e for e in read_manifest(arch) if not e.get("uncertain")]
    state: dict[str, torch.Tensor] = {}
    for e in entries:
        key, shape, dtype = e["key"], tuple(int(n) for n in e["shape"]), e.get("dtype", "float32")
        source = geometry if key in geometry else statistics if key in statistics else None
        array = _keyed_tensor(key, shape, dtype, seed) if source is None else np.asarray(source[key]).reshape(shape)
        state[key] = torch.from_numpy(np.array(array, order="C")).to(_DTYPES[dtype])  # np.array keeps 0-D
    for key in list(state):
        m = re.match(r"(pts_bbox_head\.(?:cls|reg)_branches\.)(\d+)(\..*)", key)
        if m:
            last = max(int(k.split(".")[2]) for k in state if k.startswith(m.group(1)))
            state[key] = state[f"{m.group(1)}{last}{m.group(3)}"].clone()
    _verify_manifest(arch, state)
    ckpt = {
        "state_dict": state,
        "meta": {"arch": arch, "seed": int(seed), "synthetic": True, "statistics": "calibrated"},
    }
    if path is not None:
        torch.save(ckpt, Path(path))
    return ckpt
