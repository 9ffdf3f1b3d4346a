"""FisheyePETR on cylindrical images (``configs/fisheye_to_cyl_petr.py``) in plain PyTorch.

    model = create_model("fisheye-petr-cyl")                   # released geometry (see below)
    model, report = load_model("fisheye-petr-cyl", "cyl_petr.pth")
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official pipeline rectifies each raw fisheye image onto a 400 x 800 cylinder with cv2.remap
before normalisation; here that is the first op of the graph (``geom.image_grid``), so an exported
model takes raw uint8 fisheye frames like FisheyePETR. After it: the same ResNet-18 + FPN (P3
25 x 50) and :class:`~.cyl_petr_head.CylindricalPETRHead`. The checkpoint holds no geometry
tensor: its keys are FisheyePETR's minus ``frustum``, ``sphere_grid_3d``, ``sphere_grid_2d`` and
``unvalid_area``, and every geometry table comes from the rig.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import CheckpointError, ConfigError
from fisheye_infer.geometry.tables import CylPETRParams

from .backbone import FPN, ResNet
from .checkpoint import GEOMETRY_POLICIES, GeometryReport, KeySpec
from .cyl_config import CylPETRConfig
from .cyl_petr_head import CylindricalPETRHead, CylPETRGeometry
from .cylindrical import check_rig_image_size, rectify
from .fisheye_petr import FisheyePETR, calibrate
from .registry import register_model

__all__ = ["FisheyePETRCyl"]


@register_model("fisheye-petr-cyl", config_cls=CylPETRConfig, manifest="fisheye_petr_cyl_keys.json", calibrate=calibrate)
class FisheyePETRCyl(FisheyePETR):
    """Rectification -> normalisation -> ResNet-18 -> FPN (P3 only) -> CylindricalPETRHead -> NMS-free decoding.

    Degrees as radians: the released config passes ``horizontal_range=(-110, 110)`` and
    ``vertical_range=(-45, 45)`` (degrees) to the pipeline and to the head, whose code uses them as
    radians. ``CylPETRConfig.azimuth_range`` / ``elevation_range`` are taken as radians exactly as
    written, so the default configuration and ``CylPETRConfig.from_mmdet3d_config`` of the released
    file reproduce that geometry (azimuth over +-110 rad, 0.2753 rad per image column, heights
    +-tan(45 rad) = +-1.6197752); ``math.radians(110)`` / ``math.radians(45)`` in the config give the
    intended one. Unlike FisheyeBEVDet-cyl, the checkpoint stores no geometry that would tell the
    two apart, so the configuration decides.

    The head unpacks its ranges swapped (both position-embedding axes reversed with respect to the
    image), in either case: that is the head's code, which the checkpoint was trained with.
    Missing cameras behave as in FisheyePETR.
    """

    def __init__(self, config: CylPETRConfig | None = None, rig: Any = None,
                 geometry: CylPETRGeometry | None = None) -> None:
        # FisheyePETR.__init__ builds the spherical head; the same layers are built here, in the
        # official order (head first), with the cylindrical head instead.
        nn.Module.__init__(self)
        self.config = cfg = config or CylPETRConfig()
        if geometry is None:
            if rig is None:
                from fisheye_infer.rig import default_rig

                rig = default_rig()
            if len(rig) != cfg.num_cameras:
                raise ConfigError(f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                                  f"expects {cfg.num_cameras} ({', '.join(cfg.camera_names)})")
            check_rig_image_size(rig, *cfg.image_size, "image_size")
            geometry = CylPETRGeometry.from_rig(rig, cfg)
        self.camera_names = tuple(rig.names) if rig is not None else cfg.camera_names
        self.rig_geometry = geometry  # type: ignore[assignment]
        self.pts_bbox_head = CylindricalPETRHead(cfg, geometry)
        self.img_backbone = ResNet(cfg.depth, cfg.strides, cfg.dilations, cfg.out_indices)
        self.img_neck = FPN(cfg.neck_in_channels, cfg.neck_out_channels, cfg.neck_num_outs)
        self.register_buffer("pixel_mean", torch.tensor(cfg.mean).reshape(1, 1, 3, 1, 1), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(cfg.std).reshape(1, 1, 3, 1, 1), persistent=False)
        self.eval()

    # -- forward --------------------------------------------------------------------------

    def normalize(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float B x N x 3 x Hc x Wc normalised cylinder images.

        Rectification runs on raw pixel values, normalisation after it, as in the official pipeline.
        """
        x = rectify(images, (tables or self.geometry_tables())["geom.image_grid"])
        if self.config.channel_order == "RGB":
            x = x[:, :, [2, 1, 0]]
        return (x - self.pixel_mean) / self.pixel_std

    def forward_features(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Raw images (any size: they are rectified to the configured cylinder) -> P3 B x N x C x H x W."""
        b, n = images.shape[:2]
        x = self.normalize(images, tables)
        p3 = self.img_neck(self.img_backbone(x.reshape(b * n, *x.shape[2:])))[0]
        return p3.reshape(b, n, *p3.shape[1:])

    def forward(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                cam2lidar: Any = None, tables: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """As :meth:`FisheyePETR.forward`; ``tables`` also supplies the rectification grid."""
        self._check_inputs(images, camera_valid)
        tables = tables or self.geometry_tables()
        return self.pts_bbox_head(self.forward_features(images, tables), camera_valid, cam2lidar, tables)

    def geometry_params(self) -> CylPETRParams:
        """The parameters of this model's ``geom.*`` tables."""
        return self.pts_bbox_head.params()

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        """None: the cylindrical head stores no geometry tensor."""
        return {}

    def _official_tables(self, geometry: Any) -> dict[str, np.ndarray]:
        return {}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Nothing to compare: the tables always come from the rig, whatever the (valid) policy."""
        if policy not in GEOMETRY_POLICIES:
            raise CheckpointError(f"geometry={policy!r} is not a geometry policy (use one of {', '.join(GEOMETRY_POLICIES)})")
        self.set_geometry(self.rig_geometry)  # type: ignore[arg-type]
        return GeometryReport("rig", ())
