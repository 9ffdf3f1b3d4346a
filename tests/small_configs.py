"""Reduced detector configurations shared by the tests: every stage of the official graph at a
fraction of the cost. They go with the shipped rig resized by 0.2 (160 x 160 images)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fisheye_infer.cameras.rig import Rig

#: The six-camera pinhole rig of the pinhole baselines (``rig-pinhole6/cameras.json``).
PINHOLE_RIG = Path(__file__).parent / "data" / "rig-pinhole6" / "cameras.json"

#: BEV-side sections (view transform, BEV encoder, TransFusion head) of a reduced FisheyeBEVDet:
#: 24 depth bins, a 48 m BEV square of 80x80 cells, narrower encoder and head.
SMALL_BEV_SECTIONS = {
    "view_transform": {
        "out_channels": 32,
        "xbound": (-24.0, 24.0, 0.6),
        "ybound": (-24.0, 24.0, 0.6),
        "dbound": (0.5, 24.5, 1.0),
    },
    "bev_encoder": {
        "in_channels": 32,
        "out_channels": (32, 64),
        "layer_nums": (1, 1),
        "fpn_in_channels": (32, 64),
        "fpn_out_channels": (32, 32),
    },
    "head": {
        "in_channels": 64,
        "hidden_channel": 32,
        "num_heads": 4,
        "ffn_channels": 64,
        "head_conv": 16,
        "num_proposals": 50,
        "grid_size": (320, 320, 40),
        "pc_range": (-24.0, -24.0),
        "voxel_size": (0.15, 0.15),
        "post_center_range": (-26.0, -26.0, -5.0, 26.0, 26.0, 5.0),
    },
}


def small_bevdet_config():
    """Four 160x160 cameras and an 8x32 angular grid."""
    from fisheye_infer.models import BEVDetConfig

    sections = dict(
        SMALL_BEV_SECTIONS, view_transform={**SMALL_BEV_SECTIONS["view_transform"], "feature_size": (8, 32)}
    )
    return BEVDetConfig().replace(image={"height": 160, "width": 160}, **sections)


def small_configs() -> dict:
    """A reduced configuration and the rig it runs on, by registered architecture: every stage of the
    official graph at a fraction of the cost. An architecture missing here is tested at full size."""
    from fisheye_infer.cameras.rig import default_rig, resolve_rig
    from fisheye_infer.models import (
        BEVDetCylConfig,
        CylPETRConfig,
        PerspBEVDetConfig,
        PerspPETRConfig,
        PETRConfig,
        PinholeBEVDetConfig,
        PinholePETRConfig,
    )
    from fisheye_infer.scenes.render import resized_rig

    small_head = {"num_query": 40, "max_num": 30, "embed_dims": 64, "num_heads": 4, "ffn_dims": 128, "num_layers": 2}
    cyl_sections = dict(
        SMALL_BEV_SECTIONS, view_transform={**SMALL_BEV_SECTIONS["view_transform"], "feature_size": (3, 6)}
    )
    views = lambda size, features: dict(
        SMALL_BEV_SECTIONS,
        view_transform={
            **SMALL_BEV_SECTIONS["view_transform"],
            "image_size": size,  # noqa: E731
            "feature_size": features,
        },
    )
    pinhole_rig = resized_rig(resolve_rig(PINHOLE_RIG), 0.125)  # six 160x90 cameras
    return {
        "fisheye-bevdet": (small_bevdet_config(), resized_rig(default_rig(), 0.2)),
        "fisheye-bevdet-cyl": (
            BEVDetCylConfig().replace(cylinder={"height": 48, "width": 96}, **cyl_sections),
            default_rig(),
        ),
        "fisheye-petr": (
            PETRConfig().replace(image={"height": 64, "width": 64}, head={"feature_size": (5, 21), **small_head}),
            resized_rig(default_rig(), 0.08),
        ),
        "fisheye-petr-cyl": (
            CylPETRConfig().replace(cylinder={"height": 48, "width": 96}, head={"feature_size": (3, 6), **small_head}),
            default_rig(),
        ),
        # 160x90 -> 100x56 (scale 0.625) -> a 96x48 crop, as the official 1280x720 -> 800x450 -> 800x400
        "pinhole-bevdet": (
            PinholeBEVDetConfig().replace(
                image={"height": 90, "width": 160}, image_aug={"crop": (2, 8)}, **views((48, 96), (3, 6))
            ),
            pinhole_rig,
        ),
        "fisheye-bevdet-persp": (
            PerspBEVDetConfig().replace(perspective={"size": (48, 48)}, **views((48, 48), (3, 3))),
            default_rig(),
        ),
        "pinhole-petr": (
            PinholePETRConfig().replace(
                image={"height": 90, "width": 160},
                image_aug={"crop": (2, 8)},
                head={"image_size": (48, 96), "feature_size": (3, 6), **small_head},
            ),
            pinhole_rig,
        ),
        "fisheye-petr-persp": (
            PerspPETRConfig().replace(
                perspective={"size": (48, 48)}, head={"image_size": (48, 48), "feature_size": (3, 3), **small_head}
            ),
            default_rig(),
        ),
    }


def move_rig(rig: Rig) -> Rig:
    """``rig`` with every camera moved 0.2 m forward and turned 1.7 degrees: new extrinsics."""
    c, s = np.cos(0.03), np.sin(0.03)
    move = np.array([[c, -s, 0, 0.2], [s, c, 0, 0.05], [0, 0, 1, 0.1], [0, 0, 0, 1.0]])
    data = rig.model_dump(mode="json")
    for cam in data["cameras"]:
        cam["cam2lidar"] = (move @ np.array(cam["cam2lidar"])).tolist()
    data["name"] = "moved"
    return Rig.from_dict(data)


def own_lenses(rig: Rig) -> Rig:
    """``rig`` with a lens of its own on every camera: each camera's OCam centre moved by a different few per cent
    of the image and its affine stretch changed, as four real cameras calibrate."""
    data = rig.model_dump(mode="json")
    for n, cam in enumerate(data["cameras"]):
        model = cam["model"]
        model["center_row"] += (n - 1.5) * 0.02 * model["height"]
        model["center_col"] += (1 - n) * 0.015 * model["width"]
        model["c"] += 0.004 * (n + 1)
    data["name"] = "own-lenses"
    return Rig.from_dict(data)
