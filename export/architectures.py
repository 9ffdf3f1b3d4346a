"""What the exporter needs to know about each architecture, in one table.

Each entry says how to read its config file, which checkpoint keys identify it, and how to
describe a built model for the artifact metadata (classes, cameras, image size, box count,
score semantics, and the weights re-baking needs); the parameters of its geometry tables come
from the model itself (``geometry_params()``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np
from torch import nn

from fisheye_infer.errors import ExportError

__all__ = ["ArchSpec", "ARCHITECTURES", "infer_architecture", "get_arch"]


@dataclass(frozen=True)
class ArchSpec:
    name: str
    signature_keys: tuple[str, ...]  # checkpoint keys this architecture has
    absent_keys: tuple[str, ...]  # keys it does not have (the cylindrical variants lack the sphere grids)
    read_config: Callable[[Path], Any]
    classes: Callable[[nn.Module], tuple[str, ...]]
    image_size: Callable[[nn.Module], tuple[int, int]]  # (width, height)
    normalisation: Callable[[nn.Module], tuple[tuple[float, ...], tuple[float, ...]]]
    num_boxes: Callable[[nn.Module], int]
    num_points: Callable[[nn.Module], int]  # zero slot of the pooling buckets (0 if none)
    rebake_weights: Callable[[nn.Module], dict[str, np.ndarray] | None]
    score_semantics: str


def _bevdet_config(path: Path) -> Any:
    from fisheye_infer.models import BEVDetConfig

    return BEVDetConfig.from_mmdet3d_config(path)


def _petr_config(path: Path) -> Any:
    from fisheye_infer.models import PETRConfig

    return PETRConfig.from_mmdet3d_config(path)


def _bevdet_cyl_config(path: Path) -> Any:
    from fisheye_infer.models import BEVDetCylConfig

    return BEVDetCylConfig.from_mmdet3d_config(path)


def _petr_cyl_config(path: Path) -> Any:
    from fisheye_infer.models import CylPETRConfig

    return CylPETRConfig.from_mmdet3d_config(path)


def _bevdet_classes(model: nn.Module) -> tuple[str, ...]:
    from fisheye_infer.models.config import FISHEYE3DOD_CLASSES

    return tuple(FISHEYE3DOD_CLASSES[: model.config.head.num_classes])


_BEVDET_SCORES = "sigmoid(class logit) x the proposal's heatmap peak (TransFusion); no threshold, no NMS, as the official test time"
_PETR_SCORES = "sigmoid(class logit); top boxes over queries x classes (NMS-free); no threshold, as the official test time"


def _bevdet_family(name: str, read_config: Callable[[Path], Any], *, cylindrical: bool) -> ArchSpec:
    grid = "view_transform.sphere_grid_2d"
    return ArchSpec(
        name=name,
        signature_keys=("view_transform.depthnet.weight", "bbox_head.heatmap_head.1.weight") + (() if cylindrical else (grid,)),
        absent_keys=(grid,) if cylindrical else (),
        read_config=read_config,
        classes=_bevdet_classes,
        image_size=lambda m: (m.config.image.width, m.config.image.height),
        normalisation=lambda m: (tuple(m.config.image.mean), tuple(m.config.image.std)),
        num_boxes=lambda m: m.config.head.num_proposals,
        num_points=lambda m: m.view_transform.geometry.plan.num_points,
        rebake_weights=lambda m: None,
        score_semantics=_BEVDET_SCORES,
    )


def _petr_family(name: str, read_config: Callable[[Path], Any], *, cylindrical: bool) -> ArchSpec:
    grid = "pts_bbox_head.sphere_grid_2d"
    return ArchSpec(
        name=name,
        signature_keys=("pts_bbox_head.position_encoder.0.weight", "pts_bbox_head.query_embedding.0.weight") + (() if cylindrical else (grid,)),
        absent_keys=(grid,) if cylindrical else (),
        read_config=read_config,
        classes=lambda m: tuple(m.config.classes),
        image_size=lambda m: (m.config.image_size[1], m.config.image_size[0]),
        normalisation=lambda m: (tuple(m.config.mean), tuple(m.config.std)),
        num_boxes=lambda m: m.config.max_num,
        num_points=lambda m: 0,
        rebake_weights=lambda m: m.pts_bbox_head.embedding_weights(),
        score_semantics=_PETR_SCORES,
    )


ARCHITECTURES: dict[str, ArchSpec] = {
    "fisheye-bevdet": _bevdet_family("fisheye-bevdet", _bevdet_config, cylindrical=False),
    "fisheye-bevdet-cyl": _bevdet_family("fisheye-bevdet-cyl", _bevdet_cyl_config, cylindrical=True),
    "fisheye-petr": _petr_family("fisheye-petr", _petr_config, cylindrical=False),
    "fisheye-petr-cyl": _petr_family("fisheye-petr-cyl", _petr_cyl_config, cylindrical=True),
}


def get_arch(name: str) -> ArchSpec:
    if name not in ARCHITECTURES:
        raise ExportError(f"architecture {name!r} cannot be exported (known: {', '.join(ARCHITECTURES)})")
    return ARCHITECTURES[name]


def infer_architecture(state_dict: Mapping[str, Any]) -> str:
    """The architecture whose signature keys the checkpoint holds; refuse ambiguity."""
    matches = [name for name, spec in ARCHITECTURES.items()
               if all(k in state_dict for k in spec.signature_keys) and not any(k in state_dict for k in spec.absent_keys)]
    if len(matches) == 1:
        return matches[0]
    if not matches:
        sample = ", ".join(list(state_dict)[:5])
        raise ExportError(f"cannot tell the architecture from the checkpoint's keys (first keys: {sample}); pass --arch ({', '.join(ARCHITECTURES)})")
    raise ExportError(f"the checkpoint fits several architectures ({', '.join(matches)}); pass --arch")
