"""What every model configuration shares: one shape, one way to read, copy and describe it.

A configuration is a frozen dataclass of sections (frozen dataclasses too) plus ``class_names``,
so a model, an exported artifact and a checkpoint can be compared field by field:

    cfg = BEVDetConfig()                                         # the official defaults
    cfg = BEVDetConfig.from_mmdet3d_config("fisheye_bevdet.py")  # an official file, read, never executed
    small = cfg.replace(image={"height": 160, "width": 160}, head={"num_proposals": 50})
    cfg.preprocess                                               # Preprocessing: what the model takes
    cfg.geometry_params()                                        # the parameters of its geom.* tables
    BEVDetConfig.from_dict(cfg.to_dict()) == cfg

Every configuration has the sections ``image`` (`ImageConfig`) and ``backbone``
(`BackboneConfig`); the rest are the architecture's. The readers of official files use
[`Section`][fisheye_infer.models.mmconfig_section.Section].
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from fisheye_infer.errors import ConfigError
from fisheye_infer.runtime.records import CLASSES

from .config_sections import BackboneConfig, CylinderConfig, ImageConfig, Preprocessing, feature_size_of
from .mmconfig import Section, as_tuple, read_mmdet3d_config

if TYPE_CHECKING:
    from fisheye_infer.geometry.kinds import GeometryParams

__all__ = [
    "Preprocessing",
    "ImageConfig",
    "BackboneConfig",
    "CylinderConfig",
    "ModelConfig",
    "feature_size_of",
    "build_section",
    "read_image",
    "read_backbone",
    "read_classes",
]

C = TypeVar("C", bound="ModelConfig")


def build_section(kind: type, values: Mapping[str, Any], where: str) -> Any:
    """A section dataclass from a dict of its fields (lists as tuples); unknown fields are named."""
    names = {f.name for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {', '.join(unknown)}")
    converted = {}
    for key, value in values.items():
        if isinstance(value, Mapping):  # a mapping field (TransFusion's common_heads) is stored as pairs
            value = tuple((k, as_tuple(v)) for k, v in value.items())
        converted[key] = as_tuple(value)
    try:
        return kind(**converted)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


def _section_types(cls: type) -> dict[str, type]:
    """Field name -> section class, for the fields whose default is a section dataclass (a class, or a
    factory such as ``lambda: ImageConfig(height=720)`` that builds one)."""
    out = {}
    for f in dataclasses.fields(cls):
        factory = f.default_factory
        if factory is dataclasses.MISSING:
            continue
        kind = factory if isinstance(factory, type) else type(factory())
        if dataclasses.is_dataclass(kind):
            out[f.name] = kind
    return out


class ModelConfig:
    """Base of the model configurations (each a frozen dataclass of sections and ``class_names``).

    Subclasses define their sections, ``validate``, ``num_boxes``, ``geometry_params`` and
    ``from_mmdet3d_dict``; reading, copying and the preprocessing record are shared. A configuration is
    validated when it is made: an inconsistent one raises `ConfigError` naming the fields.

    Attributes:
        image (ImageConfig): Input images and normalisation.
        backbone (BackboneConfig): The image backbone and neck.
        class_names (tuple[str, ...]): The label names, in class-index order.

    Examples:
        ```python
        from fisheye_infer.models import BEVDetConfig

        cfg = BEVDetConfig()                                          # the official defaults
        cfg = BEVDetConfig.from_mmdet3d_config("fisheye_bevdet.py")   # an official file, read, never executed
        small = cfg.replace(image={"height": 160, "width": 160}, head={"num_proposals": 50})
        assert BEVDetConfig.from_dict(small.to_dict()) == small
        ```
    """

    image: ImageConfig
    backbone: BackboneConfig
    class_names: tuple[str, ...] = CLASSES

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Check cross-field consistency (called when the configuration is made).

        Raises:
            ConfigError: Inconsistent fields, each message naming them.
        """

    @property
    def num_boxes(self) -> int:
        """Boxes per frame the model outputs."""
        raise NotImplementedError

    def geometry_params(self) -> GeometryParams:
        """The parameters of the model's ``geom.*`` tables (what an exported file records and re-baking reads)."""
        raise NotImplementedError

    @property
    def num_cameras(self) -> int:
        """Cameras per frame (``image.camera_names``)."""
        return len(self.image.camera_names)

    @property
    def num_views(self) -> int:
        """Images the backbone sees per frame: one per camera, unless a front end makes several of each."""
        return self.num_cameras

    @property
    def num_classes(self) -> int:
        """Number of classes (``class_names``)."""
        return len(self.class_names)

    @property
    def preprocess(self) -> Preprocessing:
        """What the model takes (raw camera images) and how it normalises them."""
        img = self.image
        return Preprocessing(
            image_size=(img.width, img.height),
            colour_order="BGR",
            mean=tuple(img.mean),
            std=tuple(img.std),
            cameras=tuple(img.camera_names),
            classes=tuple(self.class_names),
        )

    # -- conversion ----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        """The configuration as plain data (what an exported file and a synthetic checkpoint's meta record).

        Returns:
            dict[str, Any]: Section name -> dict of its fields, and ``class_names``.
        """
        return dataclasses.asdict(self)  # type: ignore[call-overload]  # every subclass is a dataclass; this base is not

    @classmethod
    def from_dict(cls: type[C], data: Mapping[str, Any]) -> C:
        """Inverse of ``to_dict``; unknown fields are refused by name.

        Args:
            data (Mapping[str, Any]): Section name -> dict of fields (lists are read as tuples); sections left out
                keep their defaults.

        Returns:
            C: The configuration.

        Raises:
            ConfigError: An unknown section or field, or an inconsistent configuration.
        """
        sections = _section_types(cls)
        names = {f.name for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
        parts: dict[str, Any] = {}
        for key, value in data.items():
            if key in sections:
                parts[key] = build_section(sections[key], value, key)
            elif key in names:
                parts[key] = as_tuple(value)
            else:
                raise ConfigError(f"{cls.__name__}: unknown field '{key}'")
        return cls(**parts)

    def replace(self: C, **sections: Any) -> C:
        """Copy with whole sections or per-section field dicts replaced: ``cfg.replace(head={'num_proposals': 50})``.

        Args:
            **sections (Any): Section name -> a section object, or a dict of the fields to change in it.

        Returns:
            C: The new configuration (validated).

        Raises:
            ConfigError: An unknown section, or an inconsistent result.
            TypeError: An unknown field in a section's dict.
        """
        names = {f.name for f in dataclasses.fields(self)}  # type: ignore[arg-type]
        updates: dict[str, Any] = {}
        for name, value in sections.items():
            if name not in names:
                raise ConfigError(f"{type(self).__name__}: unknown section '{name}'")
            current = getattr(self, name)
            updates[name] = dataclasses.replace(current, **value) if isinstance(value, Mapping) else value
        return dataclasses.replace(self, **updates)  # type: ignore[type-var]

    @classmethod
    def from_mmdet3d_config(cls: type[C], path: str | Path) -> C:
        """Read an official mmdet3d config file (parsed, never executed); see ``from_mmdet3d_dict``.

        Args:
            path (str | Path): The config file, e.g. the official ``configs/fisheye_bevdet.py``.

        Returns:
            C: The configuration.

        Raises:
            ConfigError: A file [`read_mmdet3d_config`][fisheye_infer.models.mmconfig.read_mmdet3d_config]
                refuses, another model type, or a value this implementation does not support (named with its
                key).
        """
        return cls.from_mmdet3d_dict(read_mmdet3d_config(path), source=str(path))

    @classmethod
    def from_mmdet3d_dict(cls: type[C], cfg: Mapping[str, Any], source: str = "<config>") -> C:
        """Build from the top-level namespace of an official config.

        Args:
            cfg (Mapping[str, Any]): The namespace, as
                [`read_mmdet3d_config`][fisheye_infer.models.mmconfig.read_mmdet3d_config] returns it.
            source (str): What error messages call it (the file name).

        Returns:
            C: The configuration.

        Raises:
            ConfigError: Another model type, or a value this implementation does not support.
        """
        raise NotImplementedError


def read_image(model: Section, cfg: Mapping[str, Any], height: int, width: int, default: ImageConfig) -> ImageConfig:
    """The ``image`` section: the data preprocessor's statistics, the test pipeline's camera order."""
    pre = model.sub("data_preprocessor", required=False)
    cams = next(
        (
            p.get("load_cam_names")
            for p in cfg.get("test_pipeline") or []
            if isinstance(p, Mapping) and "load_cam_names" in p
        ),
        None,
    )
    mean = pre.numbers("mean", 3) if "mean" in pre else default.mean
    std = pre.numbers("std", 3) if "std" in pre else default.std
    return ImageConfig(
        height=int(height),
        width=int(width),
        mean=mean,
        std=std,
        bgr_to_rgb=bool(pre.get("bgr_to_rgb", False) or pre.get("rgb_to_bgr", False)),
        camera_names=tuple(str(c) for c in cams) if cams else default.camera_names,
    )


def written_image_size(cfg: Mapping[str, Any], default: ImageConfig, source: str) -> tuple[int, int]:
    """(H, W) of the raw camera images: the top-level ``image_size`` of a file ``fisheye-infer train`` wrote.

    Official files of models whose raw input is not the view transform's (the fisheye PETR, the
    pinhole and rectified baselines) do not state it: it is the camera's (Fisheye3DOD: 800 x 800,
    the OCam calibration's; the pinhole converter's 1280 x 720), ``default``'s size here."""
    size = cfg.get("image_size")
    if size is None:
        return default.height, default.width
    if not isinstance(size, (list, tuple)) or len(size) != 2 or not all(isinstance(v, int) and v > 0 for v in size):
        raise ConfigError(f"{source}: image_size: expected [height, width] in pixels, got {size!r}")
    return int(size[0]), int(size[1])


def read_backbone(model: Section, default: BackboneConfig, *, required: bool = True) -> BackboneConfig:
    """The ``backbone`` section from ``img_backbone`` (mmdet ResNet) and ``img_neck`` (FPN)."""
    bb, neck = model.sub("img_backbone", required=required), model.sub("img_neck", required=required)
    bb.type_is("mmdet.ResNet", "ResNet")
    neck.type_is("mmdet.FPN", "FPN")
    for key, want in (("in_channels", 3), ("num_stages", 4)):
        if bb.get(key, want) != want:
            raise bb.refuse(key, want, bb.get(key))
    ints = lambda sec, key, value: tuple(int(v) for v in sec.get(key, value))  # noqa: E731
    # one stride and one dilation per stage (num_stages is 4, checked above)
    strides = bb.numbers("strides", 4, int) if "strides" in bb else default.strides
    dilations = bb.numbers("dilations", 4, int) if "dilations" in bb else default.dilations
    return BackboneConfig(
        depth=int(bb.get("depth", default.depth)),
        base_channels=int(bb.get("base_channels", default.base_channels)),
        strides=strides,
        dilations=dilations,
        out_indices=ints(bb, "out_indices", default.out_indices),
        neck_in_channels=ints(neck, "in_channels", default.neck_in_channels),
        neck_out_channels=int(neck.get("out_channels", default.neck_out_channels)),
        neck_num_outs=int(neck.get("num_outs", default.neck_num_outs)),
    )


def read_classes(cfg: Mapping[str, Any], default: tuple[str, ...]) -> tuple[str, ...]:
    """The top-level ``classes`` (or ``class_names``) list."""
    classes = cfg.get("classes") or cfg.get("class_names")
    return tuple(str(c) for c in classes) if classes else default
