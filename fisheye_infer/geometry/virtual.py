"""Virtual cameras: the tables of a front end that turns a robot's raw images into the training cameras' images.

    front = virtual_front(training_rig, robot_rig, order)     # order: the robot camera of each slot
    front.tables                                              # geom.virtual.* for the graph
    front.reports                                             # what each robot camera covers

Each slot's training image is resampled from its robot camera's raw image with cv2.remap's exact taps
(`remap_taps`) of the `VirtualView`
maps, then ``fill`` is added (mid-grey where the robot camera does not see the training ray) and the sum is rounded
to uint8 as cv2.remap rounds it. Robot cameras may differ in size: the graph takes them padded to the largest width
and height, each image in the top-left corner of its slot, and the taps read that layout. Each slot's taps index its
own robot camera's padded image and are stored camera by camera, tap by tap (the camera's pixels' first tap, then
their second, ...), so that the graph gathers each camera's taps as one run (the cameras in parallel) and weighs
long runs:

    geom.virtual.index    (1, N, 4*H*W)  int32    padded robot pixel of each tap in its camera's image (y*Wp + x)
    geom.virtual.weight   (N, 4, H*W)    float32  the taps' weights (products of two k/32 fractions, 0 outside)
    geom.virtual.fill     (N, H*W)       float32  added to each resampled pixel: ``UNSEEN_FILL`` or 0

(N slots of the training cameras' H x W images.)
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.cameras.virtual_view import VirtualView, virtual_view
from fisheye_infer.errors import RigError
from fisheye_infer.geometry.grids import remap_grid, remap_taps

__all__ = [
    "VIRTUAL",
    "VIRTUAL_INDEX",
    "VIRTUAL_WEIGHT",
    "VIRTUAL_FILL",
    "VirtualCameraReport",
    "VirtualFront",
    "virtual_front",
    "padded_size",
]

VIRTUAL = "geom.virtual."
VIRTUAL_INDEX = "geom.virtual.index"
VIRTUAL_WEIGHT = "geom.virtual.weight"
VIRTUAL_FILL = "geom.virtual.fill"


class VirtualCameraReport(BaseModel):
    """What one robot camera gives the model slot it stands in (stored in the file's metadata, printed at re-bake).

    Attributes:
        slot: The training camera's name.
        camera: The robot camera's name.
        image_size: (width, height) of the robot camera's images.
        coverage: Share of the training lens's field the robot camera sees, in [0, 1].
        rotation_deg: Rotation between the two mounts (degrees), compensated.
        translation_mm: Distance between the camera centres (mm), not compensated unless a depth is given.
        sampling_scale: Robot pixels per training pixel (median); below 1 the robot camera resolves less.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    slot: str
    camera: str
    image_size: tuple[int, int]
    coverage: float
    rotation_deg: float
    translation_mm: float
    sampling_scale: float

    def summary(self) -> str:
        """One line for the export's report.

        Returns:
            str: The slot, its robot camera and the figures, with a warning where the robot camera resolves less.
        """
        warn = "  (warning: fewer robot pixels than training pixels)" if self.sampling_scale < 1.0 else ""
        return (
            f"{self.slot} <- {self.camera} ({self.image_size[0]}x{self.image_size[1]}): covers {self.coverage:.1%} of "
            f"the training field, rotation {self.rotation_deg:.2f}° compensated, translation {self.translation_mm:.0f} "
            f"mm left, {self.sampling_scale:.2f} robot px per training px{warn}"
        )


@dataclass(frozen=True)
class VirtualFront:
    """The front end's tables, the padded input size (width, height) and one report per slot."""

    tables: dict[str, np.ndarray]
    padded_size: tuple[int, int]
    reports: tuple[VirtualCameraReport, ...]
    views: tuple[VirtualView, ...]


def padded_size(rig: Rig) -> tuple[int, int]:
    """(width, height) that holds every camera's image of ``rig``.

    Args:
        rig: The robot rig.

    Returns:
        tuple[int, int]: The largest width and the largest height.
    """
    return max(c.model.width for c in rig.cameras), max(c.model.height for c in rig.cameras)


def virtual_front(training: Rig, robot: Rig, order: Sequence[str], depth: float | None = None) -> VirtualFront:
    """The tables that resample ``robot``'s cameras (``order``: one per slot of ``training``) into ``training``'s.

    Args:
        training: The rig the model was trained with.
        robot: The robot's rig.
        order: The robot camera of each slot of ``training``, in its order
            (`map_cameras`).
        depth: None to compensate rotation only; else the distance (m) at which translation is compensated.

    Returns:
        VirtualFront: The ``geom.virtual.*`` tables, the padded input size and each slot's report.

    Raises:
        RigError: ``order`` does not name one robot camera per slot, or the training cameras differ in size.
    """
    if len(order) != len(training):
        raise RigError(f"virtual cameras: {len(order)} robot cameras for {len(training)} model cameras")
    sizes = {(c.model.width, c.model.height) for c in training.cameras}
    if len(sizes) != 1:
        raise RigError(f"virtual cameras: the model's cameras differ in size ({sorted(sizes)})")
    cameras = [robot.camera(name) for name in order]
    pw, ph = padded_size(robot.subset(order))
    index: list[np.ndarray] = []
    weight: list[np.ndarray] = []
    fill: list[np.ndarray] = []
    reports: list[VirtualCameraReport] = []
    views: list[VirtualView] = []
    for slot, cam in zip(training.cameras, cameras):
        view = virtual_view(slot, cam, depth)
        w, h = cam.model.width, cam.model.height
        taps = remap_taps(remap_grid(view.map_x, view.map_y, w, h), h, w)
        flat = taps.index
        local = np.where(taps.weight.reshape(-1) > 0, (flat // w) * pw + flat % w, 0)
        index.append(local.reshape(-1, 4).T)  # (4, H*W): tap by tap
        weight.append(taps.weight.reshape(-1, 4).T)
        fill.append(view.fill().reshape(-1))
        views.append(view)
        reports.append(
            VirtualCameraReport(
                slot=slot.name,
                camera=cam.name,
                image_size=(w, h),
                coverage=round(view.coverage, 6),
                rotation_deg=round(view.rotation_deg, 4),
                translation_mm=round(view.translation_mm, 2),
                sampling_scale=round(view.sampling_scale, 4),
            )
        )
    tables: dict[str, np.ndarray] = {
        VIRTUAL_INDEX: np.stack(index).reshape(1, len(index), -1).astype(np.int32),
        VIRTUAL_WEIGHT: np.stack(weight).astype(np.float32),
        VIRTUAL_FILL: np.stack(fill).astype(np.float32),
    }
    return VirtualFront(tables=tables, padded_size=(pw, ph), reports=tuple(reports), views=tuple(views))
