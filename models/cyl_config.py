"""Configurations of the cylindrical baselines, ``fisheye_to_cyl_bevdet.py`` and ``fisheye_to_cyl_petr.py``.

Both rectify the raw fisheye images onto a cylinder (400 x 800 by default) before the backbone,
then lift the stride-16 features without a feature warp. The cylinder is described by the
official ``horizontal_range`` (azimuth) and ``vertical_range`` (elevation; the cylinder's heights
are their tangents), stored here as ``azimuth_range`` / ``elevation_range``.

Degrees as radians: the released configs write ``horizontal_range=[-110, 110]`` and
``vertical_range=[-45, 45]``, in degrees, and the official code applies ``sin``/``tan`` to them as
radians. The numbers are taken exactly as written, so the defaults here and
``from_mmdet3d_config`` of a released file give the geometry the released checkpoints were trained
with (azimuth over +-110 rad, 0.2753 rad per image column, heights +-tan(45 rad) = +-1.6197752).
A config that writes ``math.radians(110)`` / ``math.radians(45)`` gets the intended geometry.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from fisheye_infer.errors import ConfigError

from .config import (FISHEYE3DOD_CLASSES, BackboneConfig, BEVDetConfig, BEVEncoderConfig, HeadConfig, ImageConfig,
                     ViewTransformConfig, _build)
from .mmconfig import read_mmdet3d_config
from .petr_config import PETRConfig

__all__ = ["RELEASED_HORIZONTAL_RANGE", "RELEASED_VERTICAL_RANGE", "CylinderConfig", "CylViewTransformConfig",
           "BEVDetCylConfig", "CylPETRConfig", "feature_size_of"]

#: The released configs' ranges, which their code uses as radians (see the module docstring).
RELEASED_HORIZONTAL_RANGE = (-110.0, 110.0)
RELEASED_VERTICAL_RANGE = (-45.0, 45.0)
_PIPELINE_STEP = "MultiViewFisheyeCylindricalProjection"
# The constructors' own defaults, used when a config leaves a range out.
_DEFAULT_HORIZONTAL = (-math.radians(110.0), math.radians(110.0))
_DEFAULT_VERTICAL = (-math.radians(45.0), math.radians(45.0))


def feature_size_of(image_hw: tuple[int, int], backbone: BackboneConfig | None = None) -> tuple[int, int]:
    """(H, W) of FPN level 0 for an (H, W) image: every stride-2 stage maps n to ceil(n / 2).

    The stem conv, the max pool and each stage's first conv all have padding (k - 1) / 2 (times the
    dilation), so a stride s maps n to (n - 1) // s + 1.
    """
    bb = backbone or BackboneConfig()
    strides = (2, 2, *bb.strides[: bb.out_indices[0] + 1])
    out = []
    for n in image_hw:
        for s in strides:
            n = (n - 1) // s + 1
        out.append(n)
    return (out[0], out[1])


@dataclass(frozen=True)
class CylinderConfig:
    """Size of the rectified cylindrical images (the pipeline's ``image_size=(W, H)``, here H x W)."""

    height: int = 400
    width: int = 800


@dataclass(frozen=True)
class CylViewTransformConfig(ViewTransformConfig):
    """``CylindricalLSSTransform``: depthnet directly on P3, cylindrical frustum, the same BEV mean pool.

    ``azimuth_range`` / ``elevation_range`` are the official ``horizontal_range`` / ``vertical_range``
    as the code reads them (radians; the defaults are the released configs' numbers). They define
    both the image rectification and the frustum, whose depth is the cylinder radius over
    ``linspace(dbound[0], dbound[1], int((dbound[1] - dbound[0]) / dbound[2]))``.
    """

    feature_size: tuple[int, int] = (25, 50)
    azimuth_range: tuple[float, float] = RELEASED_HORIZONTAL_RANGE
    elevation_range: tuple[float, float] = RELEASED_VERTICAL_RANGE

    @property
    def num_depth_bins(self) -> int:
        start, stop, step = self.dbound
        return int((stop - start) / step) if step > 0 else 0


@dataclass(frozen=True)
class BEVDetCylConfig:
    """FisheyeBEVDet on cylindrical images: ``image`` is the raw fisheye input (what the model takes),
    ``cylinder`` the rectified images the backbone sees; the other sections are FisheyeBEVDet's."""

    image: ImageConfig = field(default_factory=ImageConfig)
    cylinder: CylinderConfig = field(default_factory=CylinderConfig)
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    view_transform: CylViewTransformConfig = field(default_factory=CylViewTransformConfig)
    bev_encoder: BEVEncoderConfig = field(default_factory=BEVEncoderConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    class_names: tuple[str, ...] = FISHEYE3DOD_CLASSES

    def __post_init__(self) -> None:
        self.validate()

    @property
    def network(self) -> BEVDetConfig:
        """The FisheyeBEVDet configuration of the network after rectification (validated on creation)."""
        image = dataclasses.replace(self.image, height=self.cylinder.height, width=self.cylinder.width)
        return BEVDetConfig(image=image, backbone=self.backbone, view_transform=self.view_transform,
                            bev_encoder=self.bev_encoder, head=self.head, class_names=self.class_names)

    def validate(self) -> None:
        """FisheyeBEVDet's cross-field checks, plus the cylinder, feature map and depth bins agreeing."""
        if not isinstance(self.view_transform, CylViewTransformConfig):
            raise ConfigError(f"view_transform: expected a CylViewTransformConfig, got {type(self.view_transform).__name__}")
        _check_cylinder((self.cylinder.height, self.cylinder.width), "cylinder.height/width")
        network = self.network  # BEVDetConfig validates the shared sections, naming the fields
        expected = feature_size_of((network.image.height, network.image.width), self.backbone)
        if tuple(self.view_transform.feature_size) != expected:
            raise ConfigError(f"view_transform.feature_size={tuple(self.view_transform.feature_size)} but a "
                              f"{self.cylinder.height}x{self.cylinder.width} cylinder (cylinder.height/width) gives "
                              f"stride-16 features of {expected[0]}x{expected[1]}")
        if self.view_transform.num_depth_bins < 1:
            raise ConfigError(f"view_transform.dbound={self.view_transform.dbound} gives no depth bin")
        _check_ranges(self.view_transform.azimuth_range, self.view_transform.elevation_range,
                      "view_transform.azimuth_range", "view_transform.elevation_range")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "BEVDetCylConfig":
        """Inverse of ``to_dict``; unknown fields are refused by name."""
        sections = {"image": ImageConfig, "cylinder": CylinderConfig, "backbone": BackboneConfig,
                    "view_transform": CylViewTransformConfig, "bev_encoder": BEVEncoderConfig, "head": HeadConfig}
        parts: dict[str, Any] = {}
        for key, value in data.items():
            if key in sections:
                parts[key] = _build(sections[key], value, key)
            elif key == "class_names":
                parts[key] = tuple(value)
            else:
                raise ConfigError(f"BEVDetCylConfig: unknown field '{key}'")
        return cls(**parts)

    def replace(self, **sections: Any) -> "BEVDetCylConfig":
        """Copy with whole sections or per-section field dicts replaced: ``cfg.replace(cylinder={'height': 64})``."""
        updates: dict[str, Any] = {}
        for name, value in sections.items():
            if name not in {f.name for f in dataclasses.fields(self)}:
                raise ConfigError(f"BEVDetCylConfig: unknown section '{name}'")
            current = getattr(self, name)
            updates[name] = dataclasses.replace(current, **value) if isinstance(value, Mapping) else value
        return dataclasses.replace(self, **updates)

    @classmethod
    def from_mmdet3d_config(cls, path: str | Path) -> "BEVDetCylConfig":
        """Read an official ``fisheye_to_cyl_bevdet.py``-style config (parsed, never executed)."""
        return cls.from_mmdet3d_dict(read_mmdet3d_config(path), source=str(path))

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<config>") -> "BEVDetCylConfig":
        """The official namespace -> configuration; ranges are taken as radians exactly as written.

        The pipeline's rectification and the view transform each carry the ranges and the image
        size; they must agree (the frustum has to describe the rays the images were resampled on).
        """
        model = _mapping(cfg.get("model"), "model", source)
        vt = _mapping(model.get("view_transform"), "model.view_transform", source)
        if vt.get("type") != "CylindricalLSSTransform":
            raise ConfigError(f"{source}: model.view_transform.type is {vt.get('type')!r}; "
                              "fisheye-bevdet-cyl needs 'CylindricalLSSTransform'")
        size_vt = _pair(vt["image_size"], "model.view_transform.image_size", source, int) if "image_size" in vt else None
        hr, vr = _ranges(vt, "model.view_transform", source)
        size, hr, vr = _agree_with_pipeline(cfg, size_vt, hr, vr, "model.view_transform", source)
        # The shared sections are FisheyeBEVDet's: read them with its reader, the view transform
        # restated in its terms. The raw fisheye size is not in the file (Fisheye3DOD: 800 x 800;
        # the model refuses a rig whose camera differs).
        as_fisheye = {k: v for k, v in vt.items() if k not in ("horizontal_range", "vertical_range")}
        as_fisheye.update(type="FisheyeLSSTransform", azimuth_range=hr, elevation_range=vr)
        base = BEVDetConfig.from_mmdet3d_dict({**cfg, "model": {**model, "view_transform": as_fisheye}}, source)
        raw = dataclasses.replace(base.image, height=ImageConfig.height, width=ImageConfig.width)
        view = CylViewTransformConfig(**dataclasses.asdict(base.view_transform))
        cylinder = CylinderConfig(*size) if size is not None else CylinderConfig()
        return cls(image=raw, cylinder=cylinder, backbone=base.backbone, view_transform=view,
                   bev_encoder=base.bev_encoder, head=base.head, class_names=base.class_names)


@dataclass(frozen=True)
class CylPETRConfig(PETRConfig):
    """FisheyePETR hyper-parameters for ``CylindricalPETRHead`` on rectified images.

    ``image_size`` is the raw fisheye input, ``cylinder_size`` (H, W) the rectified images and
    ``feature_size`` their stride-16 features (the keys). ``azimuth_range`` / ``elevation_range`` are
    the official ``horizontal_range`` / ``vertical_range`` as the code reads them (radians; the
    defaults are the released numbers). ``dbound`` and ``cam_fov`` play no part: this head stores
    no frustum and has no lens mask.
    """

    feature_size: tuple[int, int] = (25, 50)
    azimuth_range: tuple[float, float] = RELEASED_HORIZONTAL_RANGE
    elevation_range: tuple[float, float] = RELEASED_VERTICAL_RANGE
    cylinder_size: tuple[int, int] = (400, 800)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_cylinder(self.cylinder_size, "cylinder_size")
        expected = feature_size_of(self.cylinder_size, BackboneConfig(strides=self.strides, out_indices=self.out_indices))
        if tuple(self.feature_size) != expected:
            raise ConfigError(f"feature_size={tuple(self.feature_size)} but cylinder_size={tuple(self.cylinder_size)} "
                              f"gives stride-16 features of {expected[0]}x{expected[1]}")
        _check_ranges(self.azimuth_range, self.elevation_range, "azimuth_range", "elevation_range")

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<dict>") -> "CylPETRConfig":
        """The official namespace -> configuration; ranges are taken as radians exactly as written.

        The head's ranges and the pipeline's must agree (the keys' rays have to be those the images
        were resampled on; the head's swapped unpacking is part of the head, not of the ranges).
        """
        model = _mapping(cfg.get("model"), "model", source)
        head = _mapping(model.get("pts_bbox_head"), "model.pts_bbox_head", source)
        if head.get("type") != "CylindricalPETRHead":
            raise ConfigError(f"{source}: model.pts_bbox_head.type is {head.get('type')!r}; "
                              "fisheye-petr-cyl needs 'CylindricalPETRHead'")
        hr, vr = _ranges(head, "model.pts_bbox_head", source)
        size, hr, vr = _agree_with_pipeline(cfg, None, hr, vr, "model.pts_bbox_head", source)
        # Everything else is FisheyePETR's: read it with its reader, the head restated in its terms.
        as_fisheye = {k: v for k, v in head.items() if k not in ("horizontal_range", "vertical_range")}
        as_fisheye.update(type="FisheyePETRHead", azimuth_range=hr, elevation_range=vr)
        size = size or cls.cylinder_size
        base = PETRConfig.from_mmdet3d_dict({**cfg, "model": {**model, "pts_bbox_head": as_fisheye}}, source)
        values = {f.name: getattr(base, f.name) for f in dataclasses.fields(PETRConfig)}
        values.update(cylinder_size=size, feature_size=feature_size_of(size, BackboneConfig(
            strides=base.strides, out_indices=base.out_indices)))
        return cls(**values)


# -- reading the official namespace -----------------------------------------------------------


def _mapping(value: Any, where: str, source: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ConfigError(f"{source}: expected a dict at '{where}', got {type(value).__name__}")
    return value


def _pair(value: Any, where: str, source: str, kind: type = float) -> tuple[Any, Any]:
    try:
        a, b = (kind(v) for v in value)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: '{where}' must be two numbers, got {value!r}") from None
    return (a, b)


def _ranges(section: Mapping[str, Any], where: str, source: str) -> tuple[tuple[float, float], tuple[float, float]]:
    """A section's (horizontal_range, vertical_range); absent ones take the constructors' defaults."""
    hr = _pair(section["horizontal_range"], f"{where}.horizontal_range", source) if "horizontal_range" in section else _DEFAULT_HORIZONTAL
    vr = _pair(section["vertical_range"], f"{where}.vertical_range", source) if "vertical_range" in section else _DEFAULT_VERTICAL
    return hr, vr


def _agree_with_pipeline(cfg: Mapping[str, Any], size: tuple[int, int] | None, hr: tuple[float, float],
                         vr: tuple[float, float], where: str, source: str
                         ) -> tuple[tuple[int, int] | None, tuple[float, float], tuple[float, float]]:
    """Check the test pipeline's rectification step against the model's values; returns (H, W), ranges."""
    steps = [s for s in cfg.get("test_pipeline") or [] if isinstance(s, Mapping) and s.get("type") == _PIPELINE_STEP]
    if not steps:
        return size, hr, vr
    step, at = steps[0], f"test_pipeline.{_PIPELINE_STEP}"
    p_hr, p_vr = _ranges(step, at, source)
    for name, ours, theirs in (("horizontal_range", hr, p_hr), ("vertical_range", vr, p_vr)):
        if not all(math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12) for a, b in zip(ours, theirs)):
            raise ConfigError(f"{source}: {at}.{name}={theirs} differs from {where}.{name}={ours}; the images "
                              "and the 3D rays would describe different cylinders")
    if "image_size" in step:
        w, h = _pair(step["image_size"], f"{at}.image_size", source, int)  # the pipeline writes (W, H)
        if size is not None and size != (h, w):
            raise ConfigError(f"{source}: {at}.image_size=(W={w}, H={h}) differs from {where}.image_size={size} (H, W)")
        size = (h, w)
    return size, hr, vr


def _check_cylinder(size: tuple[int, int], name: str) -> None:
    if len(size) != 2 or min(size) < 2:
        raise ConfigError(f"{name}: expected two sizes of at least 2 pixels, got {tuple(size)}")


def _check_ranges(az: tuple[float, float], el: tuple[float, float], az_name: str, el_name: str) -> None:
    values = (*az, *el)
    if len(az) != 2 or len(el) != 2 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{az_name}, {el_name}: expected two finite numbers each, got {tuple(az)}, {tuple(el)}")
    if az[0] == az[1] or math.tan(el[0]) == math.tan(el[1]):
        raise ConfigError(f"{az_name}={tuple(az)}, {el_name}={tuple(el)}: the cylinder has no width or height")
