"""Configurations of the cylindrical baselines, ``fisheye_to_cyl_bevdet.py`` and ``fisheye_to_cyl_petr.py``.

Both rectify the raw fisheye images onto a cylinder (400 x 800 by default, the ``cylinder``
section) before the backbone, then lift the stride-16 features without a feature warp. Each
extends its parent configuration: ``image`` stays the raw fisheye input (what the model takes),
the view transform or head section gains the cylinder's ranges, and the readers override only
the hook that reads that section. The cylinder is described by the official
``horizontal_range`` (azimuth) and ``vertical_range`` (elevation; the cylinder's heights are
their tangents), stored as ``azimuth_range`` / ``elevation_range``.

Degrees as radians: the released configs write ``horizontal_range=[-110, 110]`` and
``vertical_range=[-45, 45]``, in degrees, and the official code applies ``sin``/``tan`` to them as
radians. The numbers are taken exactly as written, so the defaults here and
``from_mmdet3d_config`` of a released file give the geometry the released checkpoints were trained
with (azimuth over +-110 rad, 0.2753 rad per image column, heights +-tan(45 rad) = +-1.6197752).
A config that writes ``math.radians(110)`` / ``math.radians(45)`` gets the intended geometry.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.cyl_lss import CylLSSParams
from fisheye_infer.geometry.cyl_petr import CylPETRParams

from .bevdet_config import BEVDetConfig, ViewTransformConfig, view_transform_fields
from .config import BackboneConfig, CylinderConfig, feature_size_of, written_image_size
from .mmconfig import Section
from .petr_config import PETRConfig, PETRHeadConfig, head_fields

__all__ = [
    "RELEASED_HORIZONTAL_RANGE",
    "RELEASED_VERTICAL_RANGE",
    "CYLINDER_STEP",
    "CylViewTransformConfig",
    "BEVDetCylConfig",
    "CylPETRHeadConfig",
    "CylPETRConfig",
]

#: The released configs' ranges, which their code uses as radians (see the module docstring).
RELEASED_HORIZONTAL_RANGE = (-110.0, 110.0)
RELEASED_VERTICAL_RANGE = (-45.0, 45.0)
#: The official test pipeline's step that rectifies each fisheye image onto its cylinder.
CYLINDER_STEP = "MultiViewFisheyeCylindricalProjection"
# The constructors' own defaults, used when a config leaves a range out.
_DEFAULT_HORIZONTAL = (-math.radians(110.0), math.radians(110.0))
_DEFAULT_VERTICAL = (-math.radians(45.0), math.radians(45.0))


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
class BEVDetCylConfig(BEVDetConfig):
    """FisheyeBEVDet on cylindrical images: ``image`` is the raw fisheye input (what the model takes),
    ``cylinder`` the rectified images the backbone sees; the other sections are FisheyeBEVDet's."""

    view_transform: CylViewTransformConfig = field(default_factory=CylViewTransformConfig)
    cylinder: CylinderConfig = field(default_factory=CylinderConfig)

    def validate(self) -> None:
        """FisheyeBEVDet's cross-field checks, plus the cylinder, feature map and depth bins agreeing."""
        if not isinstance(self.view_transform, CylViewTransformConfig):
            raise ConfigError(
                f"view_transform: expected a CylViewTransformConfig, got {type(self.view_transform).__name__}"
            )
        check_cylinder((self.cylinder.height, self.cylinder.width), "cylinder.height/width")
        super().validate()
        expected = feature_size_of((self.cylinder.height, self.cylinder.width), self.backbone)
        if tuple(self.view_transform.feature_size) != expected:
            raise ConfigError(
                f"view_transform.feature_size={tuple(self.view_transform.feature_size)} but a "
                f"{self.cylinder.height}x{self.cylinder.width} cylinder (cylinder.height/width) gives "
                f"stride-16 features of {expected[0]}x{expected[1]}"
            )
        if self.view_transform.num_depth_bins < 1:
            raise ConfigError(f"view_transform.dbound={self.view_transform.dbound} gives no depth bin")
        check_ranges(
            self.view_transform.azimuth_range,
            self.view_transform.elevation_range,
            "view_transform.azimuth_range",
            "view_transform.elevation_range",
        )

    def geometry_params(self) -> Any:
        vt = self.view_transform
        return CylLSSParams(
            feature_size=tuple(vt.feature_size),
            azimuth_range=tuple(vt.azimuth_range),
            elevation_range=tuple(vt.elevation_range),
            image_size=(self.cylinder.height, self.cylinder.width),
            source_size=(self.image.height, self.image.width),
            dbound=tuple(vt.dbound),
            xbound=tuple(vt.xbound),
            ybound=tuple(vt.ybound),
            zbound=tuple(vt.zbound),
        )

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig, cfg: Mapping[str, Any]) -> tuple[int, int]:
        """The raw fisheye size: the top-level ``image_size`` of a file ``fisheye-infer train`` wrote; official
        files do not state it (Fisheye3DOD: 800 x 800; the model refuses a rig whose camera differs)."""
        return written_image_size(cfg, d.image, vt.source)

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """``view_transform`` (a ``CylindricalLSSTransform``) and ``cylinder``; ranges are taken as
        radians exactly as written.

        The pipeline's rectification and the view transform each carry the ranges and the image
        size; they must agree (the frustum has to describe the rays the images were resampled on).
        """
        vt.type_is("CylindricalLSSTransform", required=True)
        size = vt.numbers("image_size", 2, int) if "image_size" in vt else None
        size, hr, vr = _agree_with_pipeline(cfg, size, *_ranges(vt), vt)
        view = CylViewTransformConfig(
            **view_transform_fields(vt, d.view_transform), azimuth_range=hr, elevation_range=vr
        )
        return {"view_transform": view, "cylinder": CylinderConfig(*size) if size is not None else CylinderConfig()}


@dataclass(frozen=True)
class CylPETRHeadConfig(PETRHeadConfig):
    """``CylindricalPETRHead``: ``feature_size`` is the stride-16 features of the rectified images (the
    keys); ``azimuth_range`` / ``elevation_range`` the official ``horizontal_range`` / ``vertical_range`` as
    the code reads them (radians; the defaults are the released numbers). ``dbound`` and ``cam_fov``
    play no part: this head stores no frustum and has no lens mask."""

    feature_size: tuple[int, int] = (25, 50)
    azimuth_range: tuple[float, float] = RELEASED_HORIZONTAL_RANGE
    elevation_range: tuple[float, float] = RELEASED_VERTICAL_RANGE


@dataclass(frozen=True)
class CylPETRConfig(PETRConfig):
    """FisheyePETR hyper-parameters for ``CylindricalPETRHead`` on rectified images: ``image`` is the raw
    fisheye input, ``cylinder`` the rectified images, ``head.feature_size`` their stride-16 features."""

    head: CylPETRHeadConfig = field(default_factory=CylPETRHeadConfig)
    cylinder: CylinderConfig = field(default_factory=CylinderConfig)

    def validate(self) -> None:
        super().validate()
        size = (self.cylinder.height, self.cylinder.width)
        check_cylinder(size, "cylinder.height/width")
        expected = feature_size_of(size, self.backbone)
        if tuple(self.head.feature_size) != expected:
            raise ConfigError(
                f"head.feature_size={tuple(self.head.feature_size)} but cylinder.height/width={size} "
                f"gives stride-16 features of {expected[0]}x{expected[1]}"
            )
        check_ranges(self.head.azimuth_range, self.head.elevation_range, "head.azimuth_range", "head.elevation_range")

    def geometry_params(self) -> Any:
        h = self.head
        return CylPETRParams(
            feature_size=tuple(h.feature_size),
            azimuth_range=tuple(h.azimuth_range),
            elevation_range=tuple(h.elevation_range),
            image_size=(self.cylinder.height, self.cylinder.width),
            source_size=(self.image.height, self.image.width),
            depth_num=h.depth_num,
            depth_start=h.depth_start,
            position_range=tuple(h.position_range),
            num_feats=h.embed_dims // 2,
            temperature=h.pe_temperature,
        )

    @classmethod
    def _read_head(cls, head: Section, cfg: Mapping[str, Any], d: PETRConfig) -> dict[str, Any]:
        """``head`` (a ``CylindricalPETRHead``) and ``cylinder``; ranges are taken as radians exactly as written.

        The head's ranges and the pipeline's must agree (the keys' rays have to be those the images
        were resampled on; the head's swapped unpacking is part of the head, not of the ranges).
        """
        head.type_is("CylindricalPETRHead", required=True)
        size, hr, vr = _agree_with_pipeline(cfg, None, *_ranges(head), head)
        cylinder = CylinderConfig(*size) if size is not None else CylinderConfig()
        model = Section(cfg.get("model"), "model", head.source)
        bb = model.sub("img_backbone", required=False)
        backbone = BackboneConfig(
            strides=bb.numbers("strides", 4, int) if "strides" in bb else d.backbone.strides,
            out_indices=tuple(int(i) for i in bb.get("out_indices", d.backbone.out_indices)),
        )
        fields = head_fields(head, d.head)
        fields.update(
            azimuth_range=hr,
            elevation_range=vr,
            feature_size=feature_size_of((cylinder.height, cylinder.width), backbone),
        )
        return {"head": CylPETRHeadConfig(**fields), "cylinder": cylinder}


# -- checks and the official namespace ----------------------------------------------------------


def check_cylinder(size: tuple[int, int], name: str) -> None:
    if len(size) != 2 or min(size) < 2:
        raise ConfigError(f"{name}: expected two sizes of at least 2 pixels, got {tuple(size)}")


def check_ranges(az: tuple[float, float], el: tuple[float, float], az_name: str, el_name: str) -> None:
    values = (*az, *el)
    if len(az) != 2 or len(el) != 2 or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{az_name}, {el_name}: expected two finite numbers each, got {tuple(az)}, {tuple(el)}")
    if az[0] == az[1] or math.tan(el[0]) == math.tan(el[1]):
        raise ConfigError(f"{az_name}={tuple(az)}, {el_name}={tuple(el)}: the cylinder has no width or height")


def _ranges(section: Section) -> tuple[tuple[float, float], tuple[float, float]]:
    """A section's (horizontal_range, vertical_range); absent ones take the constructors' defaults."""
    hr = section.numbers("horizontal_range", 2) if "horizontal_range" in section else _DEFAULT_HORIZONTAL
    vr = section.numbers("vertical_range", 2) if "vertical_range" in section else _DEFAULT_VERTICAL
    return hr, vr


def _agree_with_pipeline(
    cfg: Mapping[str, Any],
    size: tuple[int, ...] | None,
    hr: tuple[float, float],
    vr: tuple[float, float],
    model_section: Section,
) -> tuple[tuple[int, int] | None, tuple[float, float], tuple[float, float]]:
    """Check the test pipeline's rectification step against the model's values; returns (H, W), ranges."""
    steps = [s for s in cfg.get("test_pipeline") or [] if isinstance(s, Mapping) and s.get("type") == CYLINDER_STEP]
    if not steps:
        return size, hr, vr  # type: ignore[return-value]
    step = Section(steps[0], f"test_pipeline.{CYLINDER_STEP}", model_section.source)
    p_hr, p_vr = _ranges(step)
    for name, ours, theirs in (("horizontal_range", hr, p_hr), ("vertical_range", vr, p_vr)):
        if not all(math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12) for a, b in zip(ours, theirs)):
            raise ConfigError(
                f"{step.source}: {step.where(name)}={theirs} differs from {model_section.where(name)}={ours}; the "
                "images and the 3D rays would describe different cylinders"
            )
    if "image_size" in step:
        w, h = step.numbers("image_size", 2, int)  # the pipeline writes (W, H)
        if size is not None and tuple(size) != (h, w):
            raise ConfigError(
                f"{step.source}: {step.where('image_size')}=(W={w}, H={h}) differs from "
                f"{model_section.where('image_size')}={tuple(size)} (H, W)"
            )
        size = (h, w)
    return size, hr, vr  # type: ignore[return-value]
