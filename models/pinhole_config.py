"""Configurations of the BEVDet pinhole baselines: ``nusc_bevdet.py`` and ``fisheye_to_pinhole_bevdet.py``.

BEVDet with the standard ``LSSTransform``, on pinhole views; the two differ in where the views
come from, read from the official test pipeline (``pinhole_views``, shared with the PETR baselines
of ``pinhole_petr_config``):

- pinhole cameras (``PinholeBEVDetConfig``): six 1280x720 images, resized and cropped by the test
  pipeline's ``ImageAug3D``;
- perspective views of fisheye cameras (``PerspBEVDetConfig``): four 800x800 images, each
  rectified into ``len(yaws)`` views by ``MultiViewFisheyePerspectiveProjection``; an ``ImageAug3D``
  after it (same size, scale 1) truncates the float views to uint8 (``truncate``).

``image`` is the raw input the graph takes; ``view_transform.image_size`` is the views' size.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.cameras.rig import PINHOLE_CAMERAS
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.pinhole_lss import PinholeLSSParams
from fisheye_infer.geometry.views import Perspective, ResizeCrop

from .bevdet_config import BEVDetConfig, ViewTransformConfig, view_transform_fields
from .config import ImageConfig, written_image_size
from .mmconfig import Section
from .pinhole_views import (
    IMAGE_AUG_STEP,
    PERSPECTIVE_STEP,
    ImageAugConfig,
    PerspectiveConfig,
    check_crop,
    check_views,
    pipeline_steps,
    range_mean,
    read_perspective,
    test_mode_crop,
)

__all__ = [
    "PinholeViewTransformConfig",
    "PinholeBEVDetConfig",
    "PerspBEVDetConfig",
]


@dataclass(frozen=True)
class PinholeViewTransformConfig(ViewTransformConfig):
    """``LSSTransform``: depthnet on the stride-16 features of each view, the image-plane frustum.

    ``image_size`` (H, W) is the views' size (the frustum's pixel range), ``feature_size`` their
    stride-16 features; the angular fields of `ViewTransformConfig` play no part.
    """

    image_size: tuple[int, int] = (400, 800)
    feature_size: tuple[int, int] = (25, 50)


def _pinhole_view_transform(vt: Section, d: PinholeViewTransformConfig) -> PinholeViewTransformConfig:
    vt.type_is("LSSTransform", required=True)
    size = vt.numbers("image_size", 2, int) if "image_size" in vt else d.image_size
    return PinholeViewTransformConfig(**view_transform_fields(vt, d), image_size=size)


def _lss_params(config: PinholeBEVDetConfig | PerspBEVDetConfig) -> PinholeLSSParams:
    """The lift's geometry parameters of a BEVDet whose views are pinhole images (resized and cropped, or
    perspective views cut from fisheye images)."""
    vt = config.view_transform
    return PinholeLSSParams(
        feature_size=tuple(vt.feature_size),
        image_size=tuple(vt.image_size),
        source_size=(config.image.height, config.image.width),
        views=config.views(),
        dbound=tuple(vt.dbound),
        xbound=tuple(vt.xbound),
        ybound=tuple(vt.ybound),
        zbound=tuple(vt.zbound),
    )


@dataclass(frozen=True)
class PinholeBEVDetConfig(BEVDetConfig):
    """BEVDet on six pinhole cameras: ``image`` the raw 1280x720 input, ``image_aug`` the resize and crop."""

    image: ImageConfig = field(
        default_factory=lambda: ImageConfig(height=720, width=1280, camera_names=PINHOLE_CAMERAS)
    )
    view_transform: PinholeViewTransformConfig = field(default_factory=PinholeViewTransformConfig)
    image_aug: ImageAugConfig = field(default_factory=ImageAugConfig)

    def validate(self) -> None:
        super().validate()
        vt = self.view_transform
        check_views("view_transform", vt.image_size, vt.feature_size, vt.image_size, self.backbone)
        check_crop(self.image, self.image_aug, vt.image_size)

    def views(self) -> ResizeCrop:
        return self.image_aug.views()

    def geometry_params(self) -> Any:
        return _lss_params(self)

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig, cfg: Mapping[str, Any]) -> tuple[int, int]:
        """The raw camera size: the top-level ``image_size`` of a file ``fisheye-infer train`` wrote; official
        files do not state it (the official converter's 1280x720)."""
        return written_image_size(cfg, d.image, vt.source)

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """``view_transform`` (an ``LSSTransform``) and ``image_aug`` from the test pipeline's ``ImageAug3D``."""
        if pipeline_steps(cfg, PERSPECTIVE_STEP):
            raise ConfigError(
                f"{vt.source}: the test pipeline rectifies fisheye images ({PERSPECTIVE_STEP}): a fisheye-bevdet-persp "
                "configuration, not a pinhole-camera one"
            )
        view = _pinhole_view_transform(vt, d.view_transform)  # type: ignore[arg-type]
        steps = pipeline_steps(cfg, IMAGE_AUG_STEP)
        if not steps:
            return {"view_transform": view, "image_aug": d.image_aug}  # type: ignore[attr-defined]
        step = Section(steps[0], f"test_pipeline.{IMAGE_AUG_STEP}", vt.source)
        if step.get("is_train", False):
            raise step.refuse(
                "is_train", False, True, "; the test pipeline's augmentation must be the deterministic one"
            )
        fh, fw = step.numbers("final_dim", 2, int)
        if (fh, fw) != tuple(view.image_size):
            raise ConfigError(
                f"{vt.source}: {step.where('final_dim')}={(fh, fw)} differs from "
                f"{vt.where('image_size')}={view.image_size}"
            )
        height, width = cls._image_size(vt, d, cfg)
        aug = test_mode_crop(
            range_mean(step, "resize_lim", (1.0, 1.0)),
            width,
            height,
            (fh, fw),
            range_mean(step, "bot_pct_lim", (0.0, 0.0)),
        )
        return {"view_transform": view, "image_aug": aug}


@dataclass(frozen=True)
class PerspBEVDetConfig(BEVDetConfig):
    """BEVDet on perspective views rectified from four fisheye cameras: ``image`` the raw 800x800 fisheye input."""

    view_transform: PinholeViewTransformConfig = field(
        default_factory=lambda: PinholeViewTransformConfig(image_size=(400, 400), feature_size=(25, 25))
    )
    perspective: PerspectiveConfig = field(default_factory=PerspectiveConfig)

    def validate(self) -> None:
        super().validate()
        vt = self.view_transform
        check_views("view_transform", vt.image_size, vt.feature_size, self.perspective.size, self.backbone)
        if not self.perspective.yaws:
            raise ConfigError("perspective.yaws: expected at least one view per camera")

    @property
    def num_views(self) -> int:
        return self.num_cameras * len(self.perspective.yaws)

    def views(self) -> Perspective:
        return self.perspective.views()

    def geometry_params(self) -> Any:
        return _lss_params(self)

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig, cfg: Mapping[str, Any]) -> tuple[int, int]:
        """The raw fisheye size: the top-level ``image_size`` of a file ``fisheye-infer train`` wrote; official
        files do not state it (Fisheye3DOD: 800 x 800; the model refuses a rig whose camera differs)."""
        return written_image_size(cfg, d.image, vt.source)

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """``view_transform`` (an ``LSSTransform``) and ``perspective`` from the test pipeline's rectification step."""
        steps = pipeline_steps(cfg, PERSPECTIVE_STEP)
        if not steps:
            raise ConfigError(
                f"{vt.source}: the test pipeline has no {PERSPECTIVE_STEP} step: not a perspective-rectified "
                "fisheye configuration"
            )
        view = _pinhole_view_transform(vt, d.view_transform)  # type: ignore[arg-type]
        return {
            "view_transform": view,
            "perspective": read_perspective(cfg, Section(steps[0], f"test_pipeline.{PERSPECTIVE_STEP}", vt.source)),
        }
