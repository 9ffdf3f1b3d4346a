"""Which robot camera stands in each of a model's camera slots: by an explicit map or by where it looks.

    order = map_cameras(training_rig, robot_rig)                                 # by heading
    order = map_cameras(training_rig, robot_rig, {"fisheye_camera_front": "cam0", ...})

A model's cameras are slots with a pose (the training rig). A robot's cameras have their own names
and file order, which never decide the mapping: either every slot is named in an explicit map
(``--camera-map slot=robot,...``), or each robot camera goes to the slot whose optical axis points
the same way in the reference frame (within ``MAX_HEADING_GAP_DEG`` degrees of azimuth). A slot
with no candidate, a robot camera claimed by two slots, or two candidates for one slot is refused
with the candidates named.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import RigError

__all__ = ["MAX_HEADING_GAP_DEG", "heading_gap_deg", "map_cameras", "parse_camera_map"]

#: A robot camera stands in a slot found by heading when their optical axes' azimuths differ by less than this.
MAX_HEADING_GAP_DEG = 45.0


def heading_gap_deg(a: float, b: float) -> float:
    """The absolute difference of two azimuths (radians), in degrees within [0, 180].

    Args:
        a: An azimuth in radians.
        b: Another azimuth in radians.

    Returns:
        float: |a - b| wrapped to [0, 180] degrees.
    """
    gap = math.degrees(abs(a - b)) % 360.0
    return min(gap, 360.0 - gap)


def parse_camera_map(text: str) -> dict[str, str]:
    """``slot=robot,slot=robot`` (as ``--camera-map`` takes it) as a mapping slot -> robot camera.

    Args:
        text (str): Comma-separated ``slot=robot`` pairs.

    Returns:
        dict[str, str]: The model's camera name -> the robot's camera name.

    Raises:
        RigError: A pair without ``=``, an empty name, or a slot named twice.
    """
    mapping: dict[str, str] = {}
    for pair in (p.strip() for p in text.split(",")):
        slot, sep, robot = (s.strip() for s in pair.partition("="))
        if not sep or not slot or not robot:
            raise RigError(f"camera map: {pair!r} is not 'model_camera=robot_camera'")
        if slot in mapping:
            raise RigError(f"camera map: '{slot}' is given twice")
        mapping[slot] = robot
    return mapping


def map_cameras(training: Rig, robot: Rig, explicit: Mapping[str, str] | None = None) -> list[str]:
    """The robot camera for each of the training rig's slots, in slot order.

    Args:
        training (Rig): The rig the model was trained with (its slots and their poses).
        robot (Rig): The robot's rig (names and order of its own).
        explicit (Mapping[str, str] | None): Slot name -> robot camera name for every slot; None maps by heading.

    Returns:
        list[str]: One robot camera name per slot of ``training``, in its order.

    Raises:
        RigError: An unknown or missing name in the map, a robot camera used twice, or a slot whose camera
            cannot be found by heading (none, or several, within ``MAX_HEADING_GAP_DEG``, 45 degrees).

    Examples:
        ```python
        from fisheye_infer.cameras.camera_map import map_cameras, parse_camera_map
        from fisheye_infer.cameras.rig import Rig, default_rig

        robot = Rig.load("robot_rig.yaml")
        order = map_cameras(default_rig(), robot)          # by heading
        mapping = parse_camera_map("fisheye_camera_front=cam0,fisheye_camera_left=cam1,"
                                   "fisheye_camera_right=cam2,fisheye_camera_rear=cam3")
        order = map_cameras(default_rig(), robot, mapping)     # explicit
        ```
    """
    if explicit is not None:
        return _explicit(training, robot, explicit)
    order: list[str] = []
    for slot in training.cameras:
        gaps = [(heading_gap_deg(slot.heading, cam.heading), cam.name) for cam in robot.cameras]
        near = sorted((gap, name) for gap, name in gaps if gap < MAX_HEADING_GAP_DEG)
        described = ", ".join(f"{name} ({gap:.0f}°)" for gap, name in sorted(gaps))
        if not near:
            raise RigError(
                f"camera '{slot.name}': no robot camera looks within {MAX_HEADING_GAP_DEG:.0f}° of its heading "
                f"({math.degrees(slot.heading):.0f}°; robot cameras: {described}); give --camera-map"
            )
        if len(near) > 1:
            raise RigError(
                f"camera '{slot.name}': {len(near)} robot cameras look within {MAX_HEADING_GAP_DEG:.0f}° of its "
                f"heading ({', '.join(f'{n} ({g:.0f}°)' for g, n in near)}); give --camera-map"
            )
        order.append(near[0][1])
    _once_each(training.names, order)
    return order


def _explicit(training: Rig, robot: Rig, explicit: Mapping[str, str]) -> list[str]:
    unknown_slots = [s for s in explicit if s not in training.names]
    if unknown_slots:
        raise RigError(
            f"camera map: '{unknown_slots[0]}' is not a camera of the model (its cameras: {', '.join(training.names)})"
        )
    missing = [s for s in training.names if s not in explicit]
    if missing:
        raise RigError(f"camera map: no robot camera given for {', '.join(missing)}")
    order = [explicit[s] for s in training.names]
    unknown = [name for name in order if name not in robot.names]
    if unknown:
        raise RigError(
            f"camera map: '{unknown[0]}' is not a camera of the robot rig (its cameras: {', '.join(robot.names)})"
        )
    _once_each(training.names, order)
    return order


def _once_each(slots: Sequence[str], order: Sequence[str]) -> None:
    for name in dict.fromkeys(order):
        claimed = [s for s, o in zip(slots, order) if o == name]
        if len(claimed) > 1:
            raise RigError(f"camera map: robot camera '{name}' would stand in {', '.join(claimed)}; one slot each")
