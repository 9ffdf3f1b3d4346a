"""Fisheye3DOD reader: split files -> lazy ``Frame`` objects with images, per-frame rig and ground truth.

Layout (§3 of the dataset description):

    ROOT/calib_results.txt                        the OCam model of every fisheye camera without its own
    ROOT/ImageSets-2hz/{train,val}.json           [{scene_name, vehicle_name, weather, frame_id, prev_id, next_id}, ...]
    ROOT/<scene>/<vehicle>/lidar/sensor_metadata.txt
    ROOT/<scene>/<vehicle>/fisheye_camera_<name>/{frame_id}.png  + sensor_metadata.txt
                                                  (+ calib_results.txt: this camera's own lens, optional,
                                                   or camera_model.json: a lens of another model)
    ROOT/<scene>/<vehicle>/nu_rgb_camera_<name>/{frame_id}.png   + sensor_metadata.txt   (pinhole, optional)
    ROOT/<scene>/<vehicle>/label_3d/{frame_id}.json

    data = Fisheye3DOD("data/Fisheye3DODdataset", split="val", limit=100)
    for frame in data:                     # Frame: token, image paths, rig, ground truth
        dets = detector.detect(frame.image_paths)

The cameras a split is read with are fisheye cameras (the OCam model of ``calib_results.txt``; a
camera folder holding a ``calib_results.txt`` of its own, a lens calibrated for that camera alone, takes
that one), pinhole cameras (``nu_rgb_camera_*``: the layout stores no pinhole intrinsics, so each takes
the official converter's ideal 90-degree pinhole at the size of its images, 1280x720 in the dataset),
or both; ``calib_results.txt`` is needed only for fisheye cameras. Extrinsics are rebuilt per
frame from the CARLA poses of each camera and the lidar at that frame, in the "compat" convention
the checkpoints were trained with; each ``sensor_metadata.txt`` is parsed once per sequence. Label
boxes are stored gravity-centred; ``Frame.gt_boxes`` is in the runtime layout (z at the bottom
face), the same as detector output.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel, Pinhole
from fisheye_infer.cameras.carla_poses import CarlaPose, Convention, cam2lidar_from_poses, parse_sensor_metadata
from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, PINHOLE_CAMERAS, Rig
from fisheye_infer.errors import DatasetError, RigError
from fisheye_infer.eval.dataset_files import (
    IMAGESETS,
    PINHOLE_MODEL,
    SplitEntry,
    camera_name,
    converter_pinhole,
    read_labels,
    read_split,
)
from fisheye_infer.eval.lens_files import camera_lens, read_lens
from fisheye_infer.runtime.records import CLASSES, boxes_to_records, gravity_to_bottom

__all__ = [
    "DatasetError",
    "Fisheye3DOD",
    "Frame",
    "SplitEntry",
    "PINHOLE_CAMERAS",
    "PINHOLE_MODEL",
    "converter_pinhole",
    "read_split",
    "read_labels",
    "camera_name",
    "IMAGESETS",
]


@dataclass(frozen=True)
class Frame:
    """One sample: where its images are, the rig at that instant, and its ground truth.

    Attributes:
        token (str): The sample token, ``<scene>.<vehicle>.<frame_id>``.
        scene (str): The scene folder.
        vehicle (str): The vehicle folder (``ego0``...).
        frame_id (str): The frame's id, eight digits.
        weather (str): The weather named by the split file.
        image_paths (dict[str, Path]): Camera name -> PNG file; the fisheye cameras in model order, then the
            pinhole ones. A [`Detector`][fisheye_infer.runtime.detector.Detector] takes it as a frame.
        rig (Rig): The fisheye cameras asked for, with this frame's extrinsics.
        gt_boxes (np.ndarray): `(K, 7)` ``x, y, z_bottom, l, w, h, yaw``, lidar frame, metres and radians.
        gt_labels (np.ndarray): `(K,)` int64 class indices into ``class_names``.
        gt_ids (np.ndarray): `(K,)` int64 CARLA actor ids, -1 where the label has none.
        class_names (tuple[str, ...]): Class names, in label order.
        pinhole_rig (Rig | None): The pinhole cameras with this frame's extrinsics, where asked for.
    """

    token: str
    scene: str
    vehicle: str
    frame_id: str
    weather: str
    image_paths: dict[str, Path]  # camera -> PNG; fisheye cameras in model order, then pinhole ones
    rig: Rig  # the cameras asked for (fisheye, pinhole or both), extrinsics of this frame
    gt_boxes: np.ndarray  # (K, 7) x, y, z_bottom, l, w, h, yaw, lidar frame
    gt_labels: np.ndarray  # (K,) int64 class ids
    gt_ids: np.ndarray  # (K,) int64 CARLA actor ids, -1 when the label has none
    class_names: tuple[str, ...] = CLASSES
    pinhole_rig: Rig | None = field(default=None)

    def image(self, camera: str) -> np.ndarray:
        """One camera's image, decoded as training decoded it (colour, alpha dropped).

        Args:
            camera (str): A camera of ``image_paths`` (the short names ``front``, ... are accepted).

        Returns:
            np.ndarray: `(H, W, 3)` uint8 BGR.

        Raises:
            DatasetError: The camera was not loaded or its file is not a readable image.
        """
        name = camera_name(camera)
        if name not in self.image_paths:
            raise DatasetError(
                f"frame {self.token}: camera '{name}' was not loaded (have: {', '.join(self.image_paths)})"
            )
        path = self.image_paths[name]
        image = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if image is None:
            raise DatasetError(f"frame {self.token}: camera '{name}': {path} is not a readable image")
        return image

    def images(self) -> dict[str, np.ndarray]:
        """Every camera's image, as [`image`][fisheye_infer.eval.dataset.Frame.image] decodes it.

        Returns:
            dict[str, np.ndarray]: Camera name -> `(H, W, 3)` uint8 BGR.

        Raises:
            DatasetError: An image is not readable.
        """
        return {name: self.image(name) for name in self.image_paths}

    def gt_records(self) -> list[dict[str, Any]]:
        """Ground truth as evaluation records.

        Returns:
            list[dict[str, Any]]: One nuScenes-style record per box, score -1.0.
        """
        return boxes_to_records(self.gt_boxes, None, self.gt_labels, self.class_names)


class _Sequence:
    """One ``<scene>/<vehicle>`` folder: its sensor poses, parsed once."""

    def __init__(self, folder: Path, token: str, cameras: Sequence[str], lens: OCamModel | None, fov: float) -> None:
        if not folder.is_dir():
            raise DatasetError(f"scene {token}: folder {folder} not found")
        self.poses: dict[str, dict[str, CarlaPose]] = {}
        self.pinholes: dict[str, Pinhole] = {}
        self.lenses: dict[str, Any] = {}
        for sensor in ("lidar", *cameras):
            path = folder / sensor / "sensor_metadata.txt"
            if not (folder / sensor).is_dir():
                what = "lidar" if sensor == "lidar" else f"camera '{sensor}'"
                raise DatasetError(f"scene {token}: {what}: folder {folder / sensor} not found")
            try:
                self.poses[sensor] = parse_sensor_metadata(path.read_text())
            except OSError as exc:
                raise DatasetError(f"scene {token}: {path} cannot be read ({exc.strerror})") from exc
            if sensor in FISHEYE3DOD_CAMERAS:
                self.lenses[sensor] = camera_lens(folder / sensor, lens, fov, f"scene {token}: camera '{sensor}'")

    def pinhole(self, camera: str, image: Path, token: str) -> Pinhole:
        """The converter's pinhole model for ``camera``, at the size of its first image read (a PNG header)."""
        if camera not in self.pinholes:
            try:
                with image.open("rb") as f:
                    header = f.read(24)
            except OSError as exc:
                what = f"frame {token}: camera '{camera}': {image}"
                raise DatasetError(f"{what} cannot be read ({exc.strerror})") from exc
            if len(header) < 24 or header[:8] != b"\x89PNG\r\n\x1a\n":
                raise DatasetError(f"frame {token}: camera '{camera}': {image} is not a PNG image")
            width, height = int.from_bytes(header[16:20], "big"), int.from_bytes(header[20:24], "big")
            self.pinholes[camera] = converter_pinhole(width, height)
        return self.pinholes[camera]

    def cam2lidar(self, camera: str, frame_id: str, token: str, convention: Convention) -> np.ndarray:
        lidar, cam = self.poses["lidar"].get(frame_id), self.poses[camera].get(frame_id)
        if lidar is None:
            raise DatasetError(f"frame {token}: no lidar pose for frame {frame_id} in lidar/sensor_metadata.txt")
        if cam is None:
            raise DatasetError(
                f"frame {token}: camera '{camera}': no pose for frame {frame_id} in its sensor_metadata.txt"
            )
        return cam2lidar_from_poses(cam, lidar, convention)


class Fisheye3DOD:
    """A split of a Fisheye3DOD-layout folder, read lazily: indexing or iterating yields
    [`Frame`][fisheye_infer.eval.dataset.Frame] objects.

    Args:
        root (str | Path): The dataset folder (holding ``ImageSets-2hz`` and the scene folders).
        split (str): The split file's name (``train``, ``val``...).
        cameras (Sequence[str]): The cameras to load: a non-empty subset of the four fisheye and the pinhole
            cameras (default: the four fisheye cameras, in model order).
        pinhole (bool): Also load the pinhole cameras, into ``Frame.pinhole_rig``.
        scenes (Sequence[str] | None): Keep only these scenes (default: every scene of the split).
        limit (int | None): Keep only the first this many samples.
        convention (Convention): How CARLA poses become matrices: ``"compat"`` as the official converter
            computes them, ``"exact"`` the exact rotation.
        fov (float): Field of view of the fisheye lenses, degrees (the OCam files do not store it).
        class_names (Sequence[str]): Class names, in label order.

    Raises:
        DatasetError: The folder, split or a scene is missing, a camera is unknown, ``limit`` is negative, or
            a file is malformed (also when a sample is read).

    Examples:
        ```python
        from fisheye_infer.eval import Fisheye3DOD

        data = Fisheye3DOD("data/Fisheye3DODdataset", "val", limit=10)
        for frame in data:
            dets = detector.detect(frame.image_paths)
            print(frame.token, len(frame.gt_boxes), len(dets))
        gt = data.ground_truth()          # reads the label files only
        ```
    """

    def __init__(
        self,
        root: str | Path,
        split: str = "val",
        *,
        cameras: Sequence[str] = FISHEYE3DOD_CAMERAS,
        pinhole: bool = False,
        scenes: Sequence[str] | None = None,
        limit: int | None = None,
        convention: Convention = "compat",
        fov: float = 220.0,
        class_names: Sequence[str] = CLASSES,
    ) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise DatasetError(f"dataset root {self.root}: folder not found")
        self.split, self.convention = split, convention
        self.class_names = tuple(class_names)
        self.cameras = tuple(camera_name(c) for c in cameras)
        unknown = [c for c in self.cameras if c not in FISHEYE3DOD_CAMERAS + PINHOLE_CAMERAS]
        if unknown or not self.cameras:
            raise DatasetError(
                f"cameras: expected a non-empty subset of {', '.join(FISHEYE3DOD_CAMERAS + PINHOLE_CAMERAS)}, "
                f"got {list(cameras)}"
            )
        self.pinhole_cameras = PINHOLE_CAMERAS if pinhole else ()
        self.fov = fov
        self.model: OCamModel | None = None  # the root's, for the cameras without a calib_results.txt of their own
        calib = self.root / "calib_results.txt"
        if calib.is_file() and any(c in FISHEYE3DOD_CAMERAS for c in self.cameras):
            self.model = read_lens(calib, fov)
        entries = read_split(self.root, split)
        if scenes is not None:
            known = {e.scene for e in entries}
            missing = [s for s in scenes if s not in known]
            if missing:
                raise DatasetError(f"scenes: not in split '{split}': {', '.join(missing)}")
            entries = [e for e in entries if e.scene in set(scenes)]
        if limit is not None:
            if limit < 0:
                raise DatasetError(f"limit: expected a non-negative count, got {limit}")
            entries = entries[:limit]
        self.entries = entries
        self._sequences: dict[tuple[str, str], _Sequence] = {}

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def tokens(self) -> list[str]:
        """The sample tokens, in split order."""
        return [e.token for e in self.entries]

    def __iter__(self) -> Iterator[Frame]:
        for i in range(len(self.entries)):
            yield self[i]

    def _sequence(self, entry: SplitEntry) -> _Sequence:
        key = (entry.scene, entry.vehicle)
        if key not in self._sequences:
            sensors = tuple(dict.fromkeys((*self.cameras, *self.pinhole_cameras)))
            self._sequences[key] = _Sequence(
                self.root / entry.scene / entry.vehicle, f"{entry.scene}/{entry.vehicle}", sensors, self.model, self.fov
            )
        return self._sequences[key]

    def _rig(self, seq: _Sequence, entry: SplitEntry, cameras: Sequence[str]) -> Rig:
        matrices = {c: seq.cam2lidar(c, entry.frame_id, entry.token, self.convention) for c in cameras}
        folder = self.root / entry.scene / entry.vehicle
        models = {
            c: seq.pinhole(c, folder / c / f"{entry.frame_id}.png", entry.token)
            if c in PINHOLE_CAMERAS
            else seq.lenses[c]
            for c in cameras
        }
        try:
            return Rig.from_cameras(models, matrices, cameras, name=f"{entry.scene}/{entry.vehicle}@{entry.frame_id}")
        except RigError as exc:
            raise DatasetError(f"frame {entry.token}: {exc}") from exc

    def image_paths(self, index: int) -> dict[str, Path]:
        """Where a sample's images are, without reading or checking them.

        Args:
            index (int): The sample's position in the split.

        Returns:
            dict[str, Path]: Camera name -> PNG file.
        """
        entry = self.entries[index]
        folder = self.root / entry.scene / entry.vehicle
        return {
            cam: folder / cam / f"{entry.frame_id}.png" for cam in dict.fromkeys((*self.cameras, *self.pinhole_cameras))
        }

    def __getitem__(self, index: int) -> Frame:
        entry = self.entries[index]
        seq = self._sequence(entry)
        folder = self.root / entry.scene / entry.vehicle
        paths = self.image_paths(index)
        for cam, path in paths.items():
            if not path.is_file():
                raise DatasetError(f"frame {entry.token}: camera '{cam}': image {path} not found")
        boxes, labels, ids = read_labels(folder / "label_3d" / f"{entry.frame_id}.json", self.class_names)
        return Frame(
            token=entry.token,
            scene=entry.scene,
            vehicle=entry.vehicle,
            frame_id=entry.frame_id,
            weather=entry.weather,
            image_paths=paths,
            rig=self._rig(seq, entry, self.cameras),
            gt_boxes=gravity_to_bottom(boxes),
            gt_labels=labels,
            gt_ids=ids,
            class_names=self.class_names,
            pinhole_rig=self._rig(seq, entry, self.pinhole_cameras) if self.pinhole_cameras else None,
        )

    def ground_truth(self) -> dict[str, list[dict[str, Any]]]:
        """The ground truth of every sample, reading the label files only.

        Returns:
            dict[str, list[dict[str, Any]]]: Sample token -> evaluation records (score -1.0).

        Raises:
            DatasetError: A label file is missing or malformed.
        """
        out = {}
        for e in self.entries:
            boxes, labels, _ = read_labels(
                self.root / e.scene / e.vehicle / "label_3d" / f"{e.frame_id}.json", self.class_names
            )
            out[e.token] = boxes_to_records(gravity_to_bottom(boxes), None, labels, self.class_names)
        return out
