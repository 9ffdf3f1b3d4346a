"""The architecture table: one entry per registered detector, everything the package knows about it.

    @register_model("fisheye-bevdet", manifest="fisheye_bevdet_keys.json", checkpoint_filter=checkpoint_filter_fn,
                    signature_keys=(...), score_semantics=SCORE_SEMANTICS)
    class FisheyeBEVDet(FisheyeDetector):
        config_cls = BEVDetConfig

An entry holds the model class and its configuration class (whose ``preprocess`` record, box count
and geometry parameters describe a built model), the official key manifest, the keys that identify a
checkpoint of it (``signature_keys`` present, ``absent_keys`` absent), the function that maps
official keys to the model's (``checkpoint_filter``), the keys loading drops, and what its scores
mean, and which of its modules stay float32 in an int8 file. `create_model` builds an
eval-mode model, `list_models` names the registered architectures (the CLI's ``--arch``
choices), `matching_architectures` tells them apart by a checkpoint's keys. An architecture
lives in one module ``fisheye_<name>.py`` of this package (imported on first use of the registry)
with its key manifest in ``manifests/``; registering it signs it up for strict loading, synthetic
checkpoints, export, the CLI's ``--arch`` and the tests parametrized over ``list_models()``.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any, TypeVar

from torch import nn

from fisheye_infer.errors import ConfigError

from .base import FisheyeDetector
from .config import ModelConfig

__all__ = [
    "ModelEntry",
    "register_model",
    "create_model",
    "list_models",
    "get_model_entry",
    "entry_of",
    "matching_architectures",
    "read_manifest",
]

#: The package's architecture modules, one per registered detector, are named ``fisheye_*.py`` (fisheye
#: input) or ``pinhole_*.py`` (pinhole input); they are imported on first use of the registry, so a new
#: one needs no entry anywhere else.
_ARCHITECTURE_MODULES = ("fisheye_", "pinhole_")

M = TypeVar("M", bound=type[FisheyeDetector])
StateDict = Mapping[str, Any]


@dataclass(frozen=True)
class ModelEntry:
    """One registered architecture: everything the package knows about it.

    Made by [`register_model`][fisheye_infer.models.registry.register_model]; read with
    [`get_model_entry`][fisheye_infer.models.registry.get_model_entry].

    Attributes:
        name (str): The architecture's name (the CLI's ``--arch``).
        builder (type[FisheyeDetector]): The model class; ``builder(config, rig)`` builds it.
        config_cls (type[ModelConfig]): Its configuration class.
        manifest (str): File name of its official key manifest in ``models/manifests/``.
        signature_keys (tuple[str, ...]): Keys a checkpoint of it holds.
        absent_keys (tuple[str, ...]): Keys a checkpoint of it does not hold.
        checkpoint_filter (Callable[[StateDict], dict[str, Any]]): Maps an official state dict to the model's
            own keys.
        ignored_keys (tuple[str, ...]): Official keys the inference graph never uses, dropped on loading with a
            warning.
        score_semantics (str): What its scores mean (recorded in an exported file).
        int8_float (tuple[str, ...]): Modules (state-dict prefixes) whose layers stay float32 in the int8 file
            at the start of the int8 search, and in a file of ``--int8-scope network``.
        predicate (Callable[[StateDict], bool] | None): What tells a checkpoint of this architecture from
            others with the same keys (a stored table's form); None: the keys alone.
    """

    name: str
    builder: type[FisheyeDetector]
    config_cls: type[ModelConfig]
    manifest: str
    signature_keys: tuple[str, ...]
    absent_keys: tuple[str, ...]
    checkpoint_filter: Callable[[StateDict], dict[str, Any]]
    ignored_keys: tuple[str, ...]
    score_semantics: str
    int8_float: tuple[str, ...] = ()
    predicate: Callable[[StateDict], bool] | None = None

    def matches(self, state_dict: StateDict) -> bool:
        """Whether a checkpoint's keys (and ``predicate``) are this architecture's.

        Args:
            state_dict (StateDict): A checkpoint's state dict, official key names.

        Returns:
            bool: Every signature key present, no absent key present, and ``predicate`` true where set.
        """
        keys = all(k in state_dict for k in self.signature_keys) and not any(k in state_dict for k in self.absent_keys)
        return keys and (self.predicate is None or self.predicate(state_dict))


_REGISTRY: dict[str, ModelEntry] = {}
_loaded = False


def register_model(
    name: str,
    *,
    manifest: str,
    signature_keys: tuple[str, ...],
    checkpoint_filter: Callable[[StateDict], dict[str, Any]],
    score_semantics: str,
    absent_keys: tuple[str, ...] = (),
    ignored_keys: tuple[str, ...] = (),
    int8_float: tuple[str, ...] = (),
    predicate: Callable[[StateDict], bool] | None = None,
) -> Callable[[M], M]:
    """Class decorator registering a detector (a class with a ``config_cls``) under ``name``.

    The module that defines the class must be named ``fisheye_*.py`` or ``pinhole_*.py`` in this package to be
    imported on first use of the registry.

    Args:
        name (str): The architecture's name.
        manifest (str): File name of its key manifest in ``models/manifests/``.
        signature_keys (tuple[str, ...]): Keys that identify a checkpoint of it.
        checkpoint_filter (Callable[[StateDict], dict[str, Any]]): Maps official keys to the model's.
        score_semantics (str): What its scores mean.
        absent_keys (tuple[str, ...]): Keys a checkpoint of it never holds.
        ignored_keys (tuple[str, ...]): Official keys dropped on loading with a warning.
        int8_float (tuple[str, ...]): Module prefixes kept float32 in an int8 file.
        predicate (Callable[[StateDict], bool] | None): A further test of a checkpoint where keys are shared.

    Returns:
        Callable[[M], M]: The decorator; it returns the class unchanged.

    Raises:
        ConfigError: When decorating: ``name`` is registered by another class, or the class has no
            ``config_cls`` that subclasses ``ModelConfig``.
    """

    def wrap(builder: M) -> M:
        existing = _REGISTRY.get(name)
        if (
            existing is not None
            and existing.builder is not builder
            and existing.builder.__qualname__ != builder.__qualname__
        ):
            raise ConfigError(f"model '{name}' is already registered by {existing.builder!r}")
        config_cls = getattr(builder, "config_cls", None)
        if not (isinstance(config_cls, type) and issubclass(config_cls, ModelConfig)):
            raise ConfigError(f"model '{name}': {builder.__qualname__} has no config_cls (a ModelConfig subclass)")
        _REGISTRY[name] = ModelEntry(
            name,
            builder,
            config_cls,
            manifest,
            tuple(signature_keys),
            tuple(absent_keys),
            checkpoint_filter,
            tuple(ignored_keys),
            score_semantics,
            tuple(int8_float),
            predicate,
        )
        return builder

    return wrap


def _load_builtin() -> None:
    global _loaded
    if _loaded:
        return
    _loaded = True
    package = importlib.import_module(__package__ or "fisheye_infer.models")
    for module in sorted(
        m.name for m in pkgutil.iter_modules(package.__path__) if m.name.startswith(_ARCHITECTURE_MODULES)
    ):
        importlib.import_module(f"{package.__name__}.{module}")


def list_models() -> list[str]:
    """Registered architecture names, sorted (the CLI's ``--arch`` choices).

    Returns:
        list[str]: The names, e.g. ``fisheye-bevdet``, ``fisheye-petr``, ``pinhole-bevdet``.

    Examples:
        ```python
        from fisheye_infer.models import create_model, list_models

        for name in list_models():
            model = create_model(name)       # official configuration, shipped rig, eval mode
        ```
    """
    _load_builtin()
    return sorted(_REGISTRY)


def get_model_entry(name: str) -> ModelEntry:
    """The registry entry of an architecture.

    Args:
        name (str): A name of [`list_models`][fisheye_infer.models.registry.list_models].

    Returns:
        ModelEntry: Its entry.

    Raises:
        ConfigError: No architecture of that name (the registered ones are listed).
    """
    _load_builtin()
    if name not in _REGISTRY:
        raise ConfigError(f"unknown model '{name}' (registered: {', '.join(sorted(_REGISTRY)) or 'none'})")
    return _REGISTRY[name]


def entry_of(model: nn.Module) -> ModelEntry:
    """The entry a model instance was built from (by its class)."""
    _load_builtin()
    for entry in _REGISTRY.values():
        if type(model) is entry.builder:
            return entry
    raise ConfigError(f"{type(model).__name__} is not a registered model (registered: {', '.join(sorted(_REGISTRY))})")


def create_model(name: str, config: Any = None, rig: Any = None, **kwargs: Any) -> FisheyeDetector:
    """Build ``name`` for ``config`` (default: the official configuration) and ``rig`` (default rig), in eval mode.

    Args:
        name (str): A name of [`list_models`][fisheye_infer.models.registry.list_models].
        config (Any): An instance of the architecture's configuration class (``get_model_entry(name).config_cls``,
            e.g. [`BEVDetConfig`][fisheye_infer.models.bevdet_config.BEVDetConfig]); None: the official one.
        rig (Any): A [`Rig`][fisheye_infer.cameras.rig.Rig] whose cameras the geometry tables are computed for;
            None: the architecture's default (the shipped Fisheye3DOD rig for the fisheye models).
        **kwargs (Any): Passed to the model class (e.g. ``geometry``: precomputed tables).

    Returns:
        FisheyeDetector: The model (a ``torch.nn.Module``) in eval mode, with random weights.

    Raises:
        ConfigError: An unknown name, a configuration of another class, or an inconsistent configuration.
        RigError: A rig the architecture cannot take (other cameras, image size).

    Examples:
        ```python
        from fisheye_infer.cameras.rig import Rig
        from fisheye_infer.models import BEVDetConfig, create_model

        small = BEVDetConfig().replace(image={"height": 400, "width": 400})
        model = create_model("fisheye-bevdet", small, Rig.load("rig.yaml"))
        ```
    """
    entry = get_model_entry(name)
    if config is not None and type(config) is not entry.config_cls:
        raise ConfigError(f"model '{name}' needs a {entry.config_cls.__name__}, got {type(config).__name__}")
    model = entry.builder(config, rig, **kwargs)
    return model.eval()


def matching_architectures(state_dict: StateDict, config: Any = None) -> list[str]:
    """The registered architectures whose signature keys a checkpoint holds (and none of whose absent keys).

    ``config`` narrows them down where the keys do not (the pinhole and the perspective BEVDet store
    the same keys): a configuration object keeps the architectures of its class, a path to an
    official config file those whose reader accepts it.

    Args:
        state_dict (StateDict): A checkpoint's state dict, official key names.
        config (Any): None, a configuration object, or the path of an official config file.

    Returns:
        list[str]: The matching names, sorted; empty when none matches.
    """
    names = [name for name in list_models() if _REGISTRY[name].matches(state_dict)]
    if config is None or len(names) < 2:
        return names
    if not isinstance(config, (str, Path)):
        return [n for n in names if type(config) is _REGISTRY[n].config_cls]
    fitting = []
    for name in names:
        try:
            _REGISTRY[name].config_cls.from_mmdet3d_config(config)
        except ConfigError:
            continue
        fitting.append(name)
    return fitting


def read_manifest(name_or_file: str) -> list[dict[str, Any]]:
    """Key manifest entries (key, shape, dtype, note, uncertain?) of an architecture or manifest file."""
    filename = name_or_file if name_or_file.endswith(".json") else get_model_entry(name_or_file).manifest
    text = (resources.files(__package__) / "manifests" / filename).read_text(encoding="utf-8")
    return list(json.loads(text)["keys"])
