"""Old import paths of modules that moved into subpackages: importable for one more release, with a
DeprecationWarning naming the new path. Each old name is the same module object as the new one.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings
from types import FrameType, ModuleType

#: old module path -> new module path (submodules of an old package follow it)
MOVED: dict[str, str] = {
    "fisheye_infer.camera": "fisheye_infer.cameras.camera_models",
    "fisheye_infer.camera_fit": "fisheye_infer.cameras.ocam_fit",
    "fisheye_infer.rig": "fisheye_infer.cameras.rig",
    "fisheye_infer.carla": "fisheye_infer.cameras.carla_poses",
    "fisheye_infer.artifact": "fisheye_infer.runtime.artifact",
    "fisheye_infer.session": "fisheye_infer.runtime.session",
    "fisheye_infer.codec": "fisheye_infer.runtime.codec",
    "fisheye_infer.preprocess": "fisheye_infer.runtime.preprocess",
    "fisheye_infer.detector": "fisheye_infer.runtime.detector",
    "fisheye_infer.detections": "fisheye_infer.runtime.detections",
    "fisheye_infer.nms": "fisheye_infer.runtime.nms",
    "fisheye_infer.options": "fisheye_infer.runtime.options",
    "fisheye_infer.records": "fisheye_infer.runtime.records",
    "fisheye_infer.boxes": "fisheye_infer.runtime.box_geometry",
    "fisheye_infer.batch": "fisheye_infer.deploy.ray_batch",
    "fisheye_infer.triton": "fisheye_infer.deploy.triton",
    "fisheye_infer.bench": "fisheye_infer.tools.bench",
    "fisheye_infer.cpu": "fisheye_infer.tools.cpu",
    "fisheye_infer.progress": "fisheye_infer.tools.progress",
    "fisheye_infer.viz": "fisheye_infer.tools.viz",
    "fisheye_infer.synth": "fisheye_infer.scenes.render",
    "fisheye_infer.synth_splits": "fisheye_infer.scenes.streams",
    "fisheye_infer.graph_stages": "fisheye_infer.export.graph_stages",
    "fisheye_infer.eval.boxes": "fisheye_infer.eval.eval_boxes",
    "fisheye_infer.eval.synthetic": "fisheye_infer.eval.random_boxes",
    "fisheye_infer.models.synthetic": "fisheye_infer.models.seeded_checkpoint",
}


def new_name(old: str) -> str | None:
    """The module an old path now names, or None when ``old`` did not move."""
    for before, after in MOVED.items():
        if old == before or old.startswith(before + "."):
            return after + old[len(before) :]
    return None


def _caller_stacklevel() -> int:
    """The stack level of the first frame outside the import machinery and this module, so that the
    warning is attributed to the module that wrote the old import (and shown there by default)."""
    frame: FrameType | None = sys._getframe(1)
    level = 1
    while frame is not None and (
        frame.f_code.co_filename.startswith("<frozen importlib") or frame.f_code.co_filename == __file__
    ):
        frame = frame.f_back
        level += 1
    return level


class MovedModuleFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves an old module path to the module at its new path."""

    def find_spec(
        self, fullname: str, path: object = None, target: object = None
    ) -> importlib.machinery.ModuleSpec | None:
        if new_name(fullname) is None:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType:
        target = new_name(spec.name)
        assert target is not None  # find_spec answered for this name only
        warnings.warn(
            f"{spec.name} is now {target}; the old path will be removed in the next release",
            DeprecationWarning,
            stacklevel=_caller_stacklevel(),
        )
        return importlib.import_module(target)

    def exec_module(self, module: ModuleType) -> None:
        """Nothing to run: the module was executed under its new name."""


def install() -> None:
    """Put the finder last on ``sys.meta_path`` (once), behind every real module."""
    if not any(isinstance(finder, MovedModuleFinder) for finder in sys.meta_path):
        sys.meta_path.append(MovedModuleFinder())
