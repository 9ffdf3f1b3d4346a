"""The compact configurations that train on a CPU: the paper's two detectors and the baselines it compares
them with.

Same architecture as the official ``fisheye_bevdet.py`` (ResNet-18 + FPN, fisheye LSS, SECOND +
SECONDFPN, TransFusion head) with sizes cut where the measured cost of a training step says so
(README, "Training"): four 320 x 320 cameras (the shipped rig resized by 0.4, so the backbone sees
0.16 of the official pixels), ResNet-18 at half width (``base_channels=32``, which also keeps the
checkpoint under 15 MB), a 10 x 40 angular grid, 48 one-metre depth bins, the official 96 m BEV
square at 0.6 m cells (160 x 160, 80 x 80 at the head), narrower neck, BEV encoder and head, and
100 proposals. The compact FisheyePETR has the same rig and image backbone (so it can start from
the compact FisheyeBEVDet's, ``--init-backbone``), the same 10 x 40 angular key grid, and a
decoder of the official depth (6 layers) at half width (128 channels, 4 heads, 512 in the FFN)
with 300 queries.

The BEVDet baselines of the paper's Table 2 are the official ``nusc_bevdet.py``,
``fisheye_to_pinhole_bevdet.py`` and ``fisheye_to_cyl_bevdet.py`` cut the same way: the compact
FisheyeBEVDet's backbone, depth bins, BEV grid, encoder and head, with each input scaled by 0.4
of the official one, so every model keeps the official ratio of feature cells to the others'.
The PETR baselines (``nusc_petr.py``, ``fisheye_to_pinhole_petr.py``, ``fisheye_to_cyl_petr.py``)
take the same inputs with the compact FisheyePETR's backbone and decoder (their keys are the feature cells):

============================ =============================================== ==============
architecture                 input (official x 0.4)                          feature cells
============================ =============================================== ==============
``fisheye-bevdet``           4 fisheye 320 x 320, 10 x 40 angular grid       4 x 400
``pinhole-bevdet``           6 pinhole 512 x 288, resized to 320 x 180,      6 x 200
                             rows 20..179 (160 x 320)
``fisheye-bevdet-persp``     4 fisheye 320 x 320, 2 perspective 160 x 160    8 x 100
                             views each (110 deg, yaws -55 and 55 deg)
``fisheye-bevdet-cyl``       4 fisheye 320 x 320, a 160 x 320 cylinder each  4 x 200
============================ =============================================== ==============

``fisheye-petr``, ``pinhole-petr``, ``fisheye-petr-persp`` and ``fisheye-petr-cyl`` take the inputs of
the BEVDet row of the same cameras.

The cylinder spans the intended +-110 deg by +-45 deg (written in radians): the released
``fisheye_to_cyl_bevdet.py`` writes degrees that its code reads as radians (``cyl_config``).
The official full-size configurations stay the default everywhere else.

A trained checkpoint is exported like any other by passing the config file the trainer writes
(``config_file.py``):

    fisheye-infer export --ckpt runs/compact/model.pth --config runs/compact/config.py \\
        --rig runs/compact/rig.json --out model.onnx
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig, default_rig, pinhole_rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.scenes.render import resized_rig

__all__ = [
    "COMPACT_SCALE",
    "COMPACT_SECTIONS",
    "COMPACT_PETR_SECTIONS",
    "COMPACT",
    "compact_bevdet_config",
    "compact_petr_config",
    "compact_pinhole_bevdet_config",
    "compact_persp_bevdet_config",
    "compact_cyl_bevdet_config",
    "compact_pinhole_petr_config",
    "compact_persp_petr_config",
    "compact_cyl_petr_config",
    "compact_rig",
    "compact_pinhole_rig",
    "compact_setup",
]

#: Image scale of the compact models' rigs and views (fisheye 800 x 800 -> 320 x 320).
COMPACT_SCALE = 0.4
#: The compact cylinders' span (radians): the +-110 by +-45 degrees the released files intend.
CYLINDER_AZIMUTH = (-math.radians(110), math.radians(110))
CYLINDER_ELEVATION = (-math.radians(45), math.radians(45))

COMPACT_SECTIONS: dict[str, dict[str, Any]] = {
    "image": {"height": 320, "width": 320},
    "backbone": {"base_channels": 32, "neck_in_channels": (128, 256), "neck_out_channels": 64},
    "view_transform": {
        "in_channels": 64,
        "out_channels": 48,
        "feature_size": (10, 40),
        "dbound": (0.5, 48.5, 1.0),
        "xbound": (-48.0, 48.0, 0.6),
        "ybound": (-48.0, 48.0, 0.6),
    },
    "bev_encoder": {
        "in_channels": 48,
        "out_channels": (64, 128),
        "layer_nums": (2, 2),
        "fpn_in_channels": (64, 128),
        "fpn_out_channels": (64, 64),
    },
    "head": {
        "in_channels": 128,
        "hidden_channel": 64,
        "num_heads": 4,
        "ffn_channels": 128,
        "head_conv": 32,
        "num_proposals": 100,
        "grid_size": (640, 640, 40),
        "voxel_size": (0.15, 0.15),
    },
}


COMPACT_PETR_SECTIONS: dict[str, dict[str, Any]] = {
    "image": COMPACT_SECTIONS["image"],
    "backbone": COMPACT_SECTIONS["backbone"],
    "head": {
        "feature_size": (10, 40),
        "dbound": (0.5, 48.5, 1.0),
        "embed_dims": 128,
        "num_heads": 4,
        "ffn_dims": 512,
        "num_query": 300,
    },
}


def compact_petr_config() -> Any:
    """The compact FisheyePETR configuration (a ``PETRConfig``)."""
    from fisheye_infer.models import PETRConfig

    return PETRConfig().replace(**COMPACT_PETR_SECTIONS)


def compact_bevdet_config() -> Any:
    """The compact configuration (a ``BEVDetConfig``)."""
    from fisheye_infer.models import BEVDetConfig

    return BEVDetConfig().replace(**COMPACT_SECTIONS)


def compact_rig(rig: Rig | None = None) -> Rig:
    """The rig the compact model sees: ``rig`` (default: the shipped one) with its images scaled by
    ``COMPACT_SCALE``."""
    return resized_rig(rig or default_rig(), COMPACT_SCALE)


def compact_pinhole_rig() -> Rig:
    """The rig the compact pinhole baseline sees: the shipped six-camera pinhole rig at 512 x 288
    (``COMPACT_SCALE``), each camera the converter's ideal 90-degree pinhole of that size, as a held-out
    set in the Fisheye3DOD layout gives it back (the layout stores no pinhole intrinsics)."""
    from fisheye_infer.eval.dataset import converter_pinhole

    rig = pinhole_rig()
    model = rig.cameras[0].model
    scaled = converter_pinhole(round(model.width * COMPACT_SCALE), round(model.height * COMPACT_SCALE))
    return Rig.from_cameras(
        {c.name: scaled for c in rig.cameras},
        {c.name: c.matrix for c in rig.cameras},
        rig.names,
        name=f"{rig.name}@x{COMPACT_SCALE:g}",
    )


def _lift(feature_size: tuple[int, int], **fields: Any) -> dict[str, Any]:
    """The compact FisheyeBEVDet's view transform fields with ``feature_size`` features and ``fields`` on top."""
    return {**COMPACT_SECTIONS["view_transform"], "feature_size": feature_size, **fields}


def _baseline_sections() -> dict[str, Any]:
    return {k: v for k, v in COMPACT_SECTIONS.items() if k not in ("image", "view_transform")}


def compact_pinhole_bevdet_config() -> Any:
    """BEVDet on six pinhole cameras (``nusc_bevdet.py``) at compact sizes (a ``PinholeBEVDetConfig``)."""
    from fisheye_infer.models import PinholeBEVDetConfig

    rig = compact_pinhole_rig()
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    return PinholeBEVDetConfig().replace(
        image={"height": height, "width": width},
        image_aug={"scale": 0.625, "crop": (0, 20)},  # 512 x 288 -> 320 x 180, rows 20..179
        view_transform=_lift((10, 20), image_size=(160, 320)),
        **_baseline_sections(),
    )


def compact_persp_bevdet_config() -> Any:
    """BEVDet on perspective views of the four fisheye cameras (``fisheye_to_pinhole_bevdet.py``) at compact
    sizes (a ``PerspBEVDetConfig``)."""
    from fisheye_infer.models import PerspBEVDetConfig

    return PerspBEVDetConfig().replace(
        image=COMPACT_SECTIONS["image"],
        perspective={"size": (160, 160)},
        view_transform=_lift((10, 10), image_size=(160, 160)),
        **_baseline_sections(),
    )


def compact_cyl_bevdet_config() -> Any:
    """BEVDet on cylindrical images of the four fisheye cameras (``fisheye_to_cyl_bevdet.py``) at compact sizes,
    with the intended cylinder (a ``BEVDetCylConfig``)."""
    from fisheye_infer.models import BEVDetCylConfig

    return BEVDetCylConfig().replace(
        image=COMPACT_SECTIONS["image"],
        cylinder={"height": 160, "width": 320},
        view_transform=_lift(
            (10, 20),
            azimuth_range=CYLINDER_AZIMUTH,
            elevation_range=CYLINDER_ELEVATION,
        ),
        **_baseline_sections(),
    )


def _petr_head(**fields: Any) -> dict[str, Any]:
    """The compact FisheyePETR's decoder (width, heads, queries) with the key grid of ``fields``; the spherical
    head's own fields (its angular grid and depth bins) stay out."""
    decoder = {k: v for k, v in COMPACT_PETR_SECTIONS["head"].items() if k not in ("feature_size", "dbound")}
    return {**decoder, **fields}


def compact_pinhole_petr_config() -> Any:
    """PETR on six pinhole cameras (``nusc_petr.py``) at compact sizes (a ``PinholePETRConfig``): the compact
    pinhole BEVDet's input and the compact FisheyePETR's backbone and decoder."""
    from fisheye_infer.models import PinholePETRConfig

    rig = compact_pinhole_rig()
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    return PinholePETRConfig().replace(
        image={"height": height, "width": width},
        image_aug={"scale": 0.625, "crop": (0, 20)},  # 512 x 288 -> 320 x 180, rows 20..179
        backbone=COMPACT_SECTIONS["backbone"],
        head=_petr_head(image_size=(160, 320), feature_size=(10, 20)),
    )


def compact_persp_petr_config() -> Any:
    """PETR on perspective views of the four fisheye cameras (``fisheye_to_pinhole_petr.py``) at compact sizes
    (a ``PerspPETRConfig``)."""
    from fisheye_infer.models import PerspPETRConfig

    return PerspPETRConfig().replace(
        image=COMPACT_SECTIONS["image"],
        backbone=COMPACT_SECTIONS["backbone"],
        perspective={"size": (160, 160)},
        head=_petr_head(image_size=(160, 160), feature_size=(10, 10)),
    )


def compact_cyl_petr_config() -> Any:
    """PETR on cylindrical images of the four fisheye cameras (``fisheye_to_cyl_petr.py``) at compact sizes, with
    the intended cylinder (a ``CylPETRConfig``)."""
    from fisheye_infer.models import CylPETRConfig

    return CylPETRConfig().replace(
        image=COMPACT_SECTIONS["image"],
        backbone=COMPACT_SECTIONS["backbone"],
        cylinder={"height": 160, "width": 320},
        head=_petr_head(feature_size=(10, 20), azimuth_range=CYLINDER_AZIMUTH, elevation_range=CYLINDER_ELEVATION),
    )


#: The trainable architectures (``trainable.TRAINABLE``, ``fisheye-infer train --arch``) -> each one's compact
#: configuration and the rig it trains on.
COMPACT: dict[str, tuple[Callable[[], Any], Callable[[], Rig]]] = {
    "fisheye-bevdet": (compact_bevdet_config, compact_rig),
    "fisheye-petr": (compact_petr_config, compact_rig),
    "pinhole-bevdet": (compact_pinhole_bevdet_config, compact_pinhole_rig),
    "fisheye-bevdet-persp": (compact_persp_bevdet_config, compact_rig),
    "fisheye-bevdet-cyl": (compact_cyl_bevdet_config, compact_rig),
    "pinhole-petr": (compact_pinhole_petr_config, compact_pinhole_rig),
    "fisheye-petr-persp": (compact_persp_petr_config, compact_rig),
    "fisheye-petr-cyl": (compact_cyl_petr_config, compact_rig),
}


def compact_setup(arch: str, rig: Rig | None = None) -> tuple[Any, Rig]:
    """The compact configuration of ``arch`` and the rig it trains on: by default the shipped rig's, or, for a
    fisheye architecture, ``rig`` (a user's own: its cameras, their poses and lens models) with
    its images scaled by ``COMPACT_SCALE`` as the shipped rig's are, the configuration's images and cameras
    taken from it. The compact pinhole baselines take the shipped pinhole rig only: their resize and crop are
    those of its 512 x 288 images, and a held-out set in the Fisheye3DOD layout keeps no pinhole intrinsics
    to score another rig on."""
    make_config, make_rig = COMPACT[arch]
    if rig is None:
        return make_config(), make_rig()
    if make_rig is compact_pinhole_rig:
        raise ConfigError(
            f"--rig: the compact {arch} takes the shipped six-camera pinhole rig only (its resize and crop are "
            "those of 512x288 images); train another pinhole rig with --config and --rig"
        )
    for cam in rig.cameras:
        if not isinstance(cam.model, OCamModel):
            raise ConfigError(
                f"--rig: the compact {arch} takes fisheye cameras of an OCam model (`fisheye-infer rig import "
                f"--ocam` fits one); camera '{cam.name}' has a {cam.model.type} model"
            )
        if (cam.model.width, cam.model.height) != (rig.cameras[0].model.width, rig.cameras[0].model.height):
            raise ConfigError(
                f"--rig: camera '{cam.name}' takes {cam.model.width}x{cam.model.height} images, camera "
                f"'{rig.names[0]}' {rig.cameras[0].model.width}x{rig.cameras[0].model.height}; the model's input "
                "holds one image size for all cameras"
            )
    try:
        seen = compact_rig(rig)
    except ValueError as exc:  # a size that 0.4 does not scale to whole pixels at the same aspect
        raise ConfigError(
            f"--rig: the compact {arch} sees the rig's images scaled by {COMPACT_SCALE:g}: {exc}"
        ) from exc
    width, height = seen.cameras[0].model.width, seen.cameras[0].model.height
    image = {"height": height, "width": width, "camera_names": tuple(seen.names)}
    return make_config().replace(image=image), seen
