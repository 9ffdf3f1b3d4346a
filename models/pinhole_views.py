"""The views the pinhole baselines (BEVDet and PETR alike) run on, and how they are read from an official
test pipeline: the two architectures differ only in the step that names them.

- pinhole cameras: six 1280x720 images, each resized by PIL's bicubic filter and cropped
  (``ImageAug3D`` / ``ResizeCropFlipImage`` in test mode: crop ``int((1 - mean(bot_pct_lim)) * newH) - fH``
  rows from the top, centred horizontally; the scale is ``mean(resize_lim)`` for ``ImageAug3D``,
  ``max(fH / H, fW / W)`` for ``ResizeCropFlipImage``): `ImageAugConfig`;
- perspective views of fisheye cameras: four 800x800 images, each rectified into ``len(yaws)`` views by
  ``MultiViewFisheyePerspectiveProjection``; an ``ImageAug3D`` after it (BEVDet's, same size, scale 1)
  truncates the float views to uint8 (``truncate``), PETR's pipeline has none: `PerspectiveConfig`.

Kept apart from the two configuration modules (``pinhole_config``, ``pinhole_petr_config``) so each
architecture's module holds only what is its own, and a change to the view geometry is made once.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.views import Perspective, ResizeCrop

from .config import ImageConfig, feature_size_of
from .mmconfig import Section

__all__ = [
    "ImageAugConfig",
    "PerspectiveConfig",
    "PERSPECTIVE_STEP",
    "IMAGE_AUG_STEP",
    "RESIZE_CROP_STEP",
    "check_views",
    "check_crop",
    "test_mode_crop",
    "pipeline_steps",
    "range_mean",
    "read_perspective",
]

PERSPECTIVE_STEP = "MultiViewFisheyePerspectiveProjection"
IMAGE_AUG_STEP = "ImageAug3D"
RESIZE_CROP_STEP = "ResizeCropFlipImage"


@dataclass(frozen=True)
class ImageAugConfig:
    """``ImageAug3D`` in test mode: resize by ``scale``, crop a ``final_dim`` (H, W) window at (left, top) ``crop``."""

    scale: float = 0.625
    crop: tuple[int, int] = (0, 50)

    def views(self) -> ResizeCrop:
        return ResizeCrop(scale=self.scale, crop=tuple(self.crop))


@dataclass(frozen=True)
class PerspectiveConfig:
    """``MultiViewFisheyePerspectiveProjection``: views of ``size`` (H, W), ``fov`` degrees, one per yaw (degrees).

    ``truncate``: the views are cast to uint8 (floor) before normalisation, as a following
    ``ImageAug3D`` does; without it the float remap output is normalised.
    """

    size: tuple[int, int] = (400, 400)
    fov: float = 110.0
    yaws: tuple[float, ...] = (-55.0, 55.0)
    truncate: bool = True

    def views(self) -> Perspective:
        return Perspective(size=tuple(self.size), fov=self.fov, yaws=tuple(self.yaws))


def check_views(
    section: str, image_size: tuple[int, int], feature_size: tuple[int, int], view_size: tuple[int, int], backbone: Any
) -> None:
    """The section's image size is the views' size, and its feature map their stride-16 features."""
    if tuple(image_size) != tuple(view_size):
        raise ConfigError(f"{section}.image_size={tuple(image_size)} but the views are {tuple(view_size)} (H, W)")
    expected = feature_size_of(tuple(image_size), backbone)  # type: ignore[arg-type]
    if tuple(feature_size) != expected:
        raise ConfigError(
            f"{section}.feature_size={tuple(feature_size)} but {image_size[0]}x{image_size[1]} views "
            f"give stride-16 features of {expected[0]}x{expected[1]}"
        )


def check_crop(image: ImageConfig, aug: ImageAugConfig, view_size: tuple[int, int]) -> None:
    """The crop lies inside the resized image."""
    (vh, vw), (left, top) = view_size, aug.crop
    rw, rh = ResizeCrop(scale=aug.scale).resized_size(image.width, image.height) if aug.scale > 0 else (0, 0)
    if aug.scale <= 0 or left < 0 or top < 0 or left + vw > rw or top + vh > rh:
        raise ConfigError(
            f"image_aug: a {vw}x{vh} crop at (left, top)={tuple(aug.crop)} does not fit the {rw}x{rh} image that "
            f"scale={aug.scale} makes of the {image.width}x{image.height} input"
        )


def test_mode_crop(scale: float, width: int, height: int, final: tuple[int, int], bot_pct: float) -> ImageAugConfig:
    """The official test-mode crop: the bottom ``final`` rows above ``bot_pct`` of the resized height,
    centred columns."""
    new_w, new_h = ResizeCrop(scale=scale).resized_size(width, height)
    fh, fw = final
    return ImageAugConfig(scale=scale, crop=(int(max(0, new_w - fw) / 2), int((1 - bot_pct) * new_h) - fh))


def pipeline_steps(cfg: Mapping[str, Any], kind: str) -> list[Mapping[str, Any]]:
    """The test pipeline's steps of type ``kind``, in order."""
    return [s for s in cfg.get("test_pipeline") or [] if isinstance(s, Mapping) and s.get("type") == kind]


def range_mean(section: Section, key: str, default: tuple[float, float]) -> float:
    """The middle of a ``(lo, hi)`` range (``resize_lim``, ``bot_pct_lim``): its test-mode value."""
    lo, hi = section.numbers(key, 2) if key in section else default
    return (lo + hi) / 2.0


def read_perspective(cfg: Mapping[str, Any], step: Section) -> PerspectiveConfig:
    """The rectification step and whether an ``ImageAug3D`` after it truncates the views to uint8.

    That ``ImageAug3D`` must leave the views as they are (same ``final_dim``, scale 1): anything
    else would be a resize this configuration does not describe.
    """
    d = PerspectiveConfig()
    w, h = step.numbers("image_size", 2, int) if "image_size" in step else d.size[::-1]
    yaws = tuple(float(y) for y in step.get("camera_orientation", d.yaws))
    count = int(step.get("num_imgs_of_per_view", len(yaws)))
    if count != len(yaws):
        raise ConfigError(
            f"{step.source}: {step.where('num_imgs_of_per_view')}={count} but {step.where('camera_orientation')} "
            f"has {len(yaws)} yaws"
        )
    augs = pipeline_steps(cfg, IMAGE_AUG_STEP)
    for aug in augs:
        s = Section(aug, f"test_pipeline.{IMAGE_AUG_STEP}", step.source)
        if tuple(s.numbers("final_dim", 2, int)) != (h, w) or range_mean(s, "resize_lim", (1.0, 1.0)) != 1.0:
            raise ConfigError(
                f"{step.source}: {s.where('final_dim')}/{s.where('resize_lim')} resize the {h}x{w} perspective views; "
                "only the identity (the uint8 cast) is supported after the rectification"
            )
    return PerspectiveConfig(size=(h, w), fov=float(step.get("perspective_fov", d.fov)), yaws=yaws, truncate=bool(augs))
