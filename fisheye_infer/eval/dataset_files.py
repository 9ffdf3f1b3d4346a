"""The Fisheye3DOD layout's split and label files, and its camera naming and pinhole model.

``read_split`` reads ``ROOT/ImageSets-2hz/<split>.json`` into ``SplitEntry`` objects, ``read_labels`` a
``label_3d/<frame>.json`` into arrays; ``camera_name`` expands a short camera name to its sensor folder
and ``converter_pinhole`` builds a pinhole camera's model as the official converter does. The reader
built on them is [`Fisheye3DOD`][fisheye_infer.eval.dataset.Fisheye3DOD].

    entries = read_split("data/Fisheye3DODdataset", "val")       # [SplitEntry, ...] in file order
    boxes, labels, ids = read_labels("data/.../label_3d/00000001.json")
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fisheye_infer.cameras.camera_models import Pinhole
from fisheye_infer.errors import DatasetError
from fisheye_infer.runtime.records import CLASSES

__all__ = [
    "SplitEntry",
    "PINHOLE_MODEL",
    "converter_pinhole",
    "read_split",
    "read_labels",
    "camera_name",
    "IMAGESETS",
]

IMAGESETS = "ImageSets-2hz"


def converter_pinhole(width: int, height: int) -> Pinhole:
    """A pinhole camera's model as the official converter builds it: 90 degree hfov, centre at W/2, H/2."""
    return Pinhole(fx=width / 2, fy=width / 2, cx=width / 2, cy=height / 2, width=width, height=height)


#: The dataset's pinhole cameras' model (1280x720).
PINHOLE_MODEL = converter_pinhole(1280, 720)
_SPLIT_FIELDS = ("scene_name", "vehicle_name", "weather", "frame_id", "prev_id", "next_id")


def camera_name(name: str) -> str:
    """``front`` -> ``fisheye_camera_front``; full sensor folder names pass unchanged."""
    return name if "camera" in name else f"fisheye_camera_{name}"


@dataclass(frozen=True)
class SplitEntry:
    """One sample of a split file."""

    scene: str
    vehicle: str
    weather: str
    frame_id: str
    prev_id: str = ""
    next_id: str = ""

    @property
    def token(self) -> str:
        return f"{self.scene}.{self.vehicle}.{self.frame_id}"


def read_split(root: str | Path, split: str) -> list[SplitEntry]:
    """Entries of ``ROOT/ImageSets-2hz/<split>.json`` in file order."""
    path = Path(root) / IMAGESETS / f"{split}.json"
    if not path.is_file():
        have = sorted(p.stem for p in path.parent.glob("*.json")) if path.parent.is_dir() else []
        raise DatasetError(f"split '{split}': {path} not found (splits here: {', '.join(have) or 'none'})")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not UTF-8, not JSON, 4300+ digits
        raise DatasetError(
            f"split '{split}': {path} cannot be read as JSON ({str(exc)[:200] or 'nested too deep'})"
        ) from None
    if not isinstance(doc, list):
        raise DatasetError(f"split '{split}': {path} must hold a list of samples, got {type(doc).__name__}")
    entries = []
    for i, item in enumerate(doc):
        if not isinstance(item, dict) or not all(isinstance(item.get(k), str) for k in _SPLIT_FIELDS[:4]):
            raise DatasetError(
                f"split '{split}': entry {i} must be an object with string fields {', '.join(_SPLIT_FIELDS)}; "
                f"got {item!r}"
            )
        frame_id = item["frame_id"]
        if not frame_id.isdigit():
            raise DatasetError(f"split '{split}': entry {i}: frame_id must be digits, got {frame_id!r}")
        entries.append(
            SplitEntry(
                item["scene_name"],
                item["vehicle_name"],
                item["weather"],
                f"{int(frame_id):08d}",
                item.get("prev_id", ""),
                item.get("next_id", ""),
            )
        )
    return entries


def read_labels(path: str | Path, class_names: Sequence[str] = CLASSES) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``label_3d/<frame>.json`` -> gravity-centred boxes (K, 7) float64, labels (K,) int64, actor ids (K,) int64."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"labels {path}: file not found")
    try:
        doc = json.loads(path.read_text())
    except (OSError, ValueError, RecursionError) as exc:  # ValueError: not UTF-8, not JSON, 4300+ digits
        raise DatasetError(f"labels {path}: cannot be read as JSON ({str(exc)[:200] or 'nested too deep'})") from None
    if not isinstance(doc, list):
        raise DatasetError(f"labels {path}: expected a list of objects, got {type(doc).__name__}")
    boxes, labels, ids = np.zeros((len(doc), 7)), np.zeros(len(doc), np.int64), np.full(len(doc), -1, np.int64)
    for i, obj in enumerate(doc):
        where = f"labels {path}, object {i}"
        if not isinstance(obj, dict):
            raise DatasetError(f"{where}: expected an object, got {type(obj).__name__}")
        box = obj.get("bounding_box")
        ok = (
            isinstance(box, list)
            and len(box) == 7
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in box)
        )
        if not ok:
            raise DatasetError(f"{where}: 'bounding_box' must be 7 finite numbers [x, y, z, l, w, h, yaw], got {box!r}")
        assert isinstance(box, list)  # checked above; tells the type checker
        if min(box[3:6]) <= 0:
            raise DatasetError(f"{where}: 'bounding_box' sizes l, w, h must be positive, got {box[3:6]}")
        name = obj.get("class")
        if name not in class_names:
            raise DatasetError(f"{where}: 'class' {name!r} is not one of {', '.join(class_names)}")
        boxes[i], labels[i] = box, class_names.index(name)
        if isinstance(obj.get("id"), int):
            ids[i] = obj["id"]
    return boxes, labels, ids
