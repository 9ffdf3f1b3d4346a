"""What the [`Rig`][fisheye_infer.cameras.rig.Rig] methods that read a rig's layout do.

Taking a subset of the cameras, the checks of a rig against the cameras (and image size) a model
expects or one camera model shared by all, the rig's content hash, and its human-readable table.
Each function takes the rig; the methods stay the public face, with their documentation.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from fisheye_infer.cameras.field_of_view import reported_fov
from fisheye_infer.errors import RigError

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig

__all__ = ["describe", "require", "content_hash", "shared_model", "subset"]


def subset(rig: Rig, names: Sequence[str]) -> Rig:
    """``Rig.subset``: the rig of ``names`` alone, in that order."""
    if not names:
        raise RigError(f"cameras: expected at least one of {', '.join(rig.names)}")
    repeated = sorted({n for n in names if list(names).count(n) > 1})
    if repeated:
        raise RigError(f"cameras: {', '.join(repeated)} named more than once")
    cameras = tuple(rig.camera(name) for name in names)
    return rig.model_copy(update={"cameras": cameras, "name": f"{rig.name}[{'+'.join(names)}]"})


def shared_model(rig: Rig) -> Any:
    """``Rig.shared_model``: the one camera model all of the rig's cameras share."""
    first = rig.cameras[0].model
    for cam in rig.cameras[1:]:
        if cam.model != first:
            raise RigError(
                f"camera '{cam.name}': its camera model differs from '{rig.cameras[0].name}'; "
                "expected one model shared by all cameras"
            )
    return first


def require(rig: Rig, names: Sequence[str], image_size: tuple[int, int] | None) -> None:
    """``Rig.require``: refuse a rig without exactly ``names``, in order, and images of ``image_size``."""
    for name in names:
        if name not in rig.names:
            raise RigError(f"camera '{name}': missing from the rig (rig has: {', '.join(rig.names)})")
    if list(names) != rig.names:
        raise RigError(f"camera order: expected {', '.join(names)}; the rig has {', '.join(rig.names)}")
    if image_size is not None:
        for cam in rig.cameras:
            size = (cam.model.width, cam.model.height)
            if size != tuple(image_size):
                raise RigError(
                    f"camera '{cam.name}': image is {size[0]}x{size[1]}, model expects {image_size[0]}x{image_size[1]}"
                )


def content_hash(rig: Rig) -> str:
    """``Rig.hash``: sha256 (hex, first 16 digits) of the cameras' canonical JSON."""
    doc = json.dumps(
        _canonical([c.model_dump(mode="json") for c in rig.cameras]), sort_keys=True, separators=(",", ":")
    )
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def describe(rig: Rig) -> str:
    """``Rig.describe``: the rig's table, one line per camera after a header."""
    width = max(24, *(len(n) for n in rig.names))
    calibrations = list(dict.fromkeys(cam.model for cam in rig.cameras))
    lines = [f"rig {rig.name!r}  hash {rig.hash}  frame: lidar (x forward, y left, z up)"]
    lines.append(
        f"  {'camera':<{width}} {'model':<17} {'lens':>4} {'image':>9} {'fov':>7}   {'position x, y, z (m)':<26} "
        f"{'heading':>8}"
    )
    for cam in rig.cameras:
        x, y, z = np.round(cam.position, 3) + 0.0  # no "-0.000"
        fov = reported_fov(cam.model)
        lines.append(
            f"  {cam.name:<{width}} {cam.model.type:<17} {calibrations.index(cam.model) + 1:>4} "
            f"{cam.model.width:>4}x{cam.model.height:<4} {fov if fov is not None else '-':>7}"
            f"   {x:>7.3f}, {y:>7.3f}, {z:>7.3f}     {round(math.degrees(cam.heading), 1) + 0.0:>7.1f}°"
        )
    return "\n".join(lines)


def _canonical(value: Any) -> Any:
    """JSON data with every float rounded to 10 decimals and signed zeros made positive."""
    if isinstance(value, float):
        return round(value, 10) + 0.0
    if isinstance(value, dict):
        return {k: _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    return value
