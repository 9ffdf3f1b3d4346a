"""A split read as sequences, with what a tracking evaluation needs: frame order, stamps, ego poses, instance ids.

    for seq in read_sequences("seqs/", "val"):
        for frame in seq.frames:            # in time order
            frame.token, frame.stamp, frame.ego_pose, frame.gt_ids, frame.gt_velocities

A sequence is one ``<scene>/<vehicle>`` folder of the split; its frames are ordered by frame id.
The stamp is the lidar record's ``timestamp`` (seconds), the ego pose its pose (lidar to world, in the
convention the rigs are read with); ``gt_velocities`` are the label objects' ``velocity`` (zeros where
a label has none). Images and rigs are read by ``Fisheye3DOD`` as for any split: a frame's ``split_index`` is
its index there.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fisheye_infer.cameras.carla_poses import Convention, parse_sensor_metadata, pose_matrix
from fisheye_infer.errors import DatasetError
from fisheye_infer.eval.dataset_files import read_labels, read_split
from fisheye_infer.runtime.records import CLASSES, gravity_to_bottom

__all__ = ["TrackingFrame", "TrackingSequence", "read_sequences"]

_STAMP = re.compile(r"frame=(\d+),\s*timestamp=([0-9.eE+-]+)")


@dataclass(frozen=True)
class TrackingFrame:
    """One frame of a sequence: its place in the split, time, ego pose and ground truth (lidar frame)."""

    token: str
    split_index: int  # position in the split file (the ``Fisheye3DOD`` index)
    stamp: float
    ego_pose: np.ndarray  # (4, 4) lidar to world
    gt_boxes: np.ndarray  # (K, 7) runtime layout
    gt_labels: np.ndarray  # (K,)
    gt_ids: np.ndarray  # (K,) instance ids (-1 where a label has none)
    gt_velocities: np.ndarray  # (K, 2) m/s


@dataclass(frozen=True)
class TrackingSequence:
    """The frames of one ``<scene>/<vehicle>`` folder, in time order."""

    name: str
    frames: tuple[TrackingFrame, ...]


def _velocities(path: Path, count: int) -> np.ndarray:
    doc = json.loads(path.read_text())
    out = np.zeros((count, 2))
    for i, obj in enumerate(doc[:count]):
        v = obj.get("velocity") if isinstance(obj, dict) else None
        if v is not None:
            if not (isinstance(v, list) and len(v) == 2 and all(isinstance(c, (int, float)) for c in v)):
                raise DatasetError(f"labels {path}, object {i}: 'velocity' must be two numbers [vx, vy], got {v!r}")
            out[i] = v
    return out


def _stamps(path: Path) -> dict[str, float]:
    try:
        text = path.read_text()
    except OSError as exc:
        raise DatasetError(f"{path}: cannot be read ({exc.strerror})") from exc
    return {f"{int(f):08d}": float(t) for f, t in _STAMP.findall(text)}


def read_sequences(
    root: str | Path,
    split: str = "val",
    class_names: Sequence[str] = CLASSES,
    scenes: Sequence[str] | None = None,
    convention: Convention = "compat",
) -> list[TrackingSequence]:
    """The sequences of a split, each frame with its stamp, ego pose and labelled instances.

    Args:
        root (str | Path): The dataset root.
        split (str): The split file's name.
        class_names (Sequence[str]): The classes of the labels.
        scenes (Sequence[str] | None): Scene names to keep (default: all).
        convention (Convention): How CARLA poses are turned into matrices.

    Returns:
        list[TrackingSequence]: In the order the split first names them.
    """
    root = Path(root)
    entries = read_split(root, split)
    groups: dict[tuple[str, str], list[int]] = {}
    for i, e in enumerate(entries):
        if scenes is None or e.scene in scenes:
            groups.setdefault((e.scene, e.vehicle), []).append(i)
    out = []
    for (scene, vehicle), index in groups.items():
        folder = root / scene / vehicle
        lidar = folder / "lidar" / "sensor_metadata.txt"
        if not lidar.is_file():
            raise DatasetError(f"scene {scene}/{vehicle}: {lidar} not found (the ego poses and stamps)")
        poses, stamps = parse_sensor_metadata(lidar.read_text()), _stamps(lidar)
        frames = []
        for i in sorted(index, key=lambda k: int(entries[k].frame_id)):
            e = entries[i]
            if e.frame_id not in poses or e.frame_id not in stamps:
                raise DatasetError(f"frame {e.token}: no lidar pose or timestamp for frame {e.frame_id} in {lidar}")
            labels_path = folder / "label_3d" / f"{e.frame_id}.json"
            boxes, labels, ids = read_labels(labels_path, class_names)
            frames.append(
                TrackingFrame(
                    token=e.token,
                    split_index=i,
                    stamp=stamps[e.frame_id],
                    ego_pose=pose_matrix(poses[e.frame_id], convention),
                    gt_boxes=gravity_to_bottom(boxes),
                    gt_labels=labels,
                    gt_ids=ids,
                    gt_velocities=_velocities(labels_path, len(boxes)),
                )
            )
        stamps_in_order = [f.stamp for f in frames]
        if any(b <= a for a, b in zip(stamps_in_order, stamps_in_order[1:])):
            raise DatasetError(f"scene {scene}/{vehicle}: timestamps do not increase with the frame ids")
        out.append(TrackingSequence(f"{scene}/{vehicle}", tuple(frames)))
    return out
