"""Model registry: architecture name -> builder, configuration class, key manifest and hooks.

Each detector module registers itself with :func:`register_model`; :func:`create_model` builds an
eval-mode model for a configuration and a rig. The registry also carries what the synthetic
checkpoint generator needs per architecture (the manifest file and an optional calibration hook),
so a new architecture only has to register to get strict loading and synthetic checkpoints.
"""

from __future__ import annotations

import importlib
import json
from dataclasses import dataclass, field
from importlib import resources
from typing import Any, Callable

from torch import nn

from fisheye_infer.errors import ConfigError

__all__ = ["ModelEntry", "register_model", "set_calibration", "create_model", "list_models", "get_model_entry",
           "read_manifest"]

# Detector modules imported on first use of the registry; a missing one is skipped.
_BUILTIN_MODULES = ("fisheye_bevdet", "fisheye_petr", "fisheye_bevdet_cyl", "fisheye_petr_cyl")


@dataclass(frozen=True)
class ModelEntry:
    """One registered architecture.

    ``builder(config, rig, **kwargs)`` returns the model. ``calibrate(model, seed)`` (optional)
    runs seeded forward passes with BatchNorm layers collecting statistics; the synthetic
    checkpoint generator calls it. ``ignored_keys`` are official keys that loading drops with a warning.
    """

    name: str
    builder: Callable[..., nn.Module]
    config_cls: type
    manifest: str
    calibrate: Callable[[nn.Module, int], None] | None = None
    ignored_keys: tuple[str, ...] = ()
    extras: dict[str, Any] = field(default_factory=dict)


_REGISTRY: dict[str, ModelEntry] = {}
_loaded = False


def register_model(name: str, *, config_cls: type, manifest: str, calibrate: Callable[[nn.Module, int], None] | None = None,
                   ignored_keys: tuple[str, ...] = (), **extras: Any) -> Callable[[Callable[..., nn.Module]], Callable[..., nn.Module]]:
    """Decorator registering a model class or factory under ``name``."""

    def wrap(builder: Callable[..., nn.Module]) -> Callable[..., nn.Module]:
        existing = _REGISTRY.get(name)
        if existing is not None and existing.builder is not builder and getattr(existing.builder, "__qualname__", None) != getattr(builder, "__qualname__", None):
            raise ConfigError(f"model '{name}' is already registered by {existing.builder!r}")
        _REGISTRY[name] = ModelEntry(name, builder, config_cls, manifest, calibrate, tuple(ignored_keys), dict(extras))
        return builder

    return wrap


def set_calibration(name: str, calibrate: Callable[[nn.Module, int], None]) -> None:
    """Attach a calibration hook to an already registered model (e.g. from a separate module)."""
    entry = get_model_entry(name)
    _REGISTRY[name] = ModelEntry(entry.name, entry.builder, entry.config_cls, entry.manifest, calibrate,
                                 entry.ignored_keys, entry.extras)


def _load_builtin() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    for module in _BUILTIN_MODULES:
        qualified = f"{__package__}.{module}"
        try:
            importlib.import_module(qualified)
        except ModuleNotFoundError as exc:
            if exc.name != qualified:
                raise


def list_models() -> list[str]:
    """Registered architecture names, sorted."""
    _load_builtin()
    return sorted(_REGISTRY)


def get_model_entry(name: str) -> ModelEntry:
    _load_builtin()
    if name not in _REGISTRY:
        raise ConfigError(f"unknown model '{name}' (registered: {', '.join(sorted(_REGISTRY)) or 'none'})")
    return _REGISTRY[name]


def create_model(name: str, config: Any = None, rig: Any = None, **kwargs: Any) -> nn.Module:
    """Build ``name`` for ``config`` (default: the official configuration) and ``rig`` (default rig), in eval mode."""
    entry = get_model_entry(name)
    if config is not None and not isinstance(config, entry.config_cls):
        raise ConfigError(f"model '{name}' needs a {entry.config_cls.__name__}, got {type(config).__name__}")
    model = entry.builder(config, rig, **kwargs)
    return model.eval()


def read_manifest(name_or_file: str) -> list[dict[str, Any]]:
    """Key manifest entries (key, shape, dtype, note, uncertain?) of an architecture or manifest file."""
    filename = name_or_file if name_or_file.endswith(".json") else get_model_entry(name_or_file).manifest
    text = (resources.files(__package__) / "manifests" / filename).read_text(encoding="utf-8")
    return list(json.loads(text)["keys"])
