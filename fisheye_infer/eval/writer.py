"""Write frames in the Fisheye3DOD layout, so that ``Fisheye3DOD`` reads back what was written.

The inverse of the reader: a rig becomes CARLA poses (the compat or exact conversion undone),
printed as CARLA prints sensor data, one record per frame and sensor; boxes become gravity-centred
label JSON; the OCam model becomes ``calib_results.txt``, a fisheye lens of another model its camera folder's
``camera_model.json`` (pinhole cameras must be the layout's one pinhole model, which it stores nowhere); the
samples go into the split file.

    writer = Fisheye3DODWriter(root, scene="synth-Town00-ClearNoon-0000", split="val")
    rig_read = writer.write_frame("00001000", rig, images, boxes, labels, lidar_pose)
    writer.close()                                   # writes ImageSets-2hz/val.json

``write_poses`` (and ``write_frame``) return the rig exactly as the reader will rebuild it from
the written text (decimal poses and trigonometry move cam2lidar by ~1e-15), so a caller can
render with the very matrices a reader of the folder will get.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.carla_poses import (
    CAM_TO_SENSOR,
    CarlaPose,
    Convention,
    cam2lidar_from_poses,
    parse_sensor_metadata,
    pose_matrix,
)
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.eval.dataset import IMAGESETS, PINHOLE_CAMERAS, DatasetError, converter_pinhole
from fisheye_infer.eval.lens_files import CAMERA_MODEL_FILE
from fisheye_infer.runtime.records import CLASSES, bottom_to_gravity

__all__ = ["Fisheye3DODWriter", "pose_from_matrix", "camera_poses", "format_record", "update_split"]


def pose_from_matrix(matrix: np.ndarray, convention: Convention = "compat") -> CarlaPose:
    """The CARLA pose whose ``pose_matrix(pose, convention)`` is ``matrix`` (sensor to right-handed world).

    compat: R = Rz(-yaw) Ry(pitch) Rx(-roll); exact: R = Rz(-yaw) Ry(-pitch) Rx(roll). Both are a
    z-y-x Euler decomposition R = Rz(a) Ry(b) Rx(c) with signs flipped as the convention says.
    """
    m = np.asarray(matrix, np.float64)
    r = m[:3, :3]
    a = math.atan2(r[1, 0], r[0, 0])
    b = math.atan2(-r[2, 0], math.hypot(r[0, 0], r[1, 0]))
    c = math.atan2(r[2, 1], r[2, 2])
    yaw, pitch, roll = -math.degrees(a), math.degrees(b), math.degrees(c)
    if convention == "compat":
        roll = -roll
    elif convention == "exact":
        pitch = -pitch
    else:
        raise DatasetError(f"convention: expected 'compat' or 'exact', got {convention!r}")
    x, y, z = m[:3, 3]
    return CarlaPose(float(x), float(-y), float(z), pitch, yaw, roll)


def camera_poses(rig: Rig, lidar: CarlaPose, convention: Convention = "compat") -> dict[str, CarlaPose]:
    """CARLA world pose of each camera such that ``cam2lidar_from_poses(pose, lidar)`` is the rig's cam2lidar."""
    sensor_to_cam = np.eye(4)
    sensor_to_cam[:3, :3] = CAM_TO_SENSOR.T
    lidar_to_world = pose_matrix(lidar, convention)
    return {cam.name: pose_from_matrix(lidar_to_world @ cam.matrix @ sensor_to_cam, convention) for cam in rig.cameras}


def _num(v: float) -> str:
    """Plain decimal without an exponent (the official parser refuses ``1e-05``), exact on reading back."""
    return np.format_float_positional(float(v), unique=True, trim="0")


def format_record(kind: str, frame_id: str, pose: CarlaPose, timestamp: float, extra: str = "") -> str:
    """One ``sensor_metadata.txt`` line as CARLA prints a measurement: ``Image(frame=..., ...) Transform(...)``."""
    head = f"{kind}(frame={int(frame_id)}, timestamp={timestamp:.6f}{', ' + extra if extra else ''})"
    loc = f"Location(x={_num(pose.x)}, y={_num(pose.y)}, z={_num(pose.z)})"
    rot = f"Rotation(pitch={_num(pose.pitch)}, yaw={_num(pose.yaw)}, roll={_num(pose.roll)})"
    return f"{head} Transform({loc}, {rot})\n"


def _replace_record(path: Path, frame_id: str, line: str) -> None:
    """Append ``line``, dropping an earlier record of the same frame so a rewrite leaves one."""
    marker = f"frame={int(frame_id)},"
    if path.is_file():
        kept = [old for old in path.read_text().splitlines(keepends=True) if marker not in old]
        path.write_text("".join(kept) + line)
    else:
        path.write_text(line)


def update_split(root: str | Path, split: str, entries: Sequence[Mapping[str, str]]) -> Path:
    """Merge samples into ``ImageSets-2hz/<split>.json``; prev/next ids are recomputed per sequence."""
    path = Path(root) / IMAGESETS / f"{split}.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    existing = json.loads(path.read_text()) if path.is_file() else []
    merged = {(e["scene_name"], e["vehicle_name"], e["frame_id"]): dict(e) for e in existing}
    merged.update({(e["scene_name"], e["vehicle_name"], e["frame_id"]): dict(e) for e in entries})
    keys = sorted(merged)
    ordered = [merged[k] for k in keys]
    for i, e in enumerate(ordered):
        prev_same = i > 0 and keys[i - 1][:2] == keys[i][:2]
        next_same = i + 1 < len(keys) and keys[i + 1][:2] == keys[i][:2]
        e["prev_id"] = ordered[i - 1]["frame_id"] if prev_same else ""
        e["next_id"] = ordered[i + 1]["frame_id"] if next_same else ""
    path.write_text(json.dumps(ordered, indent=1) + "\n")
    return path


def _holds(path: Path, model: OCamModel) -> bool:
    """Whether ``path`` is absent or describes ``model``."""
    return not path.is_file() or OCamModel.from_file(path, fov=model.fov) == model


class Fisheye3DODWriter:
    """Writes the frames of one ``<scene>/<vehicle>`` sequence in the Fisheye3DOD layout, so that
    [`Fisheye3DOD`][fisheye_infer.eval.dataset.Fisheye3DOD] reads back what was written; call ``close`` to
    record the frames in the split file.

    Args:
        root (str | Path): The dataset folder.
        scene (str): The scene folder's name; its third ``-``-separated part is taken as the weather.
        vehicle (str): The vehicle folder's name.
        split (str): The split file the frames are recorded in (``ImageSets-2hz/<split>.json``).
        convention (Convention): How poses and matrices convert (``"compat"`` or ``"exact"``), as the reader
            will be told.

    Raises:
        DatasetError: ``scene`` or ``vehicle`` contains a ``.`` (it separates a token's parts).

    Examples:
        ```python
        writer = Fisheye3DODWriter("out", scene="synth-Town00-ClearNoon-0000", split="val")
        rig_read = writer.write_frame("00001000", rig, images, boxes, labels, lidar_pose)
        writer.close()                       # writes out/ImageSets-2hz/val.json
        ```
    """

    def __init__(
        self, root: str | Path, scene: str, vehicle: str = "ego0", split: str = "val", convention: Convention = "compat"
    ) -> None:
        if "." in scene or "." in vehicle:
            raise DatasetError(
                f"scene/vehicle: names must not contain '.', which separates token parts; got {scene!r}/{vehicle!r}"
            )
        self.root, self.scene, self.vehicle, self.split, self.convention = Path(root), scene, vehicle, split, convention
        parts = scene.split("-")
        self.weather = parts[2] if len(parts) > 2 else ""
        self.folder = self.root / scene / vehicle
        self._entries: list[dict[str, str]] = []

    def write_calib(self, model: OCamModel, camera: str | None = None) -> Path:
        """Write an OCam lens as ``calib_results.txt``.

        Args:
            model (OCamModel): The lens.
            camera (str | None): None: ``<root>/calib_results.txt``, the lens of every fisheye camera; a name:
                the lens of that camera alone, in its folder of this sequence.

        Returns:
            Path: The file (an existing one describing the same model is kept).

        Raises:
            DatasetError: ``model`` is not an OCam model, or an existing file holds a different one.
        """
        if not isinstance(model, OCamModel):
            raise DatasetError(f"calib: the layout stores OCam models of fisheye cameras, got a {type(model).__name__}")
        path = (self.root if camera is None else self.folder / camera) / "calib_results.txt"
        if path.is_file():
            if not _holds(path, model):
                raise DatasetError(f"calib: {path} already holds a different camera model")
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(model.to_text())
        return path

    def _write_model_file(self, camera: str, model: Any) -> Path:
        """``<camera>/camera_model.json``: a lens that OCam's ``calib_results.txt`` cannot express; an existing file
        must describe the same model."""
        path = self.folder / camera / CAMERA_MODEL_FILE
        text = model.model_dump_json(indent=1) + "\n"
        if path.is_file():
            if path.read_text() != text:
                raise DatasetError(f"calib: {path} already holds a different camera model")
            return path
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path

    def _write_models(self, rig: Rig) -> None:
        """``calib_results.txt`` for the fisheye cameras: one at the root for a lens they share (while the root
        holds none or that one, and the sequence has no camera files yet), else one in each camera's folder;
        pinhole cameras must be the converter's 90-degree pinhole of their size (`converter_pinhole`),
        which the reader rebuilds from the images."""
        fisheye = [c for c in rig.cameras if c.name not in PINHOLE_CAMERAS]
        for cam in rig.cameras:
            ideal = converter_pinhole(cam.model.width, cam.model.height)
            if cam.name in PINHOLE_CAMERAS and cam.model != ideal:
                raise DatasetError(
                    f"camera '{cam.name}': the layout stores no pinhole intrinsics and its reader takes the official "
                    f"converter's 90-degree pinhole of the images' size ({ideal}); this camera differs ({cam.model})"
                )
        for cam in fisheye:
            if not isinstance(cam.model, OCamModel):
                self._write_model_file(cam.name, cam.model)
        lenses = {cam.name: cam.model for cam in fisheye if isinstance(cam.model, OCamModel)}  # all of them, checked
        if not lenses:
            return
        shared = next(iter(lenses.values())) if len(set(lenses.values())) == 1 else None
        own = any((self.folder / name / "calib_results.txt").is_file() for name in lenses)
        if shared is not None and not own and _holds(self.root / "calib_results.txt", shared):
            self.write_calib(shared)
        else:
            for name, lens in lenses.items():
                self.write_calib(lens, name)

    def write_poses(self, frame_id: str, rig: Rig, lidar_pose: CarlaPose) -> Rig:
        """Write this frame's lidar and camera poses to the sensors' ``sensor_metadata.txt`` (and the lenses).

        Args:
            frame_id (str): The frame's id (a whole number; written with eight digits).
            rig (Rig): The cameras, their extrinsics relative to the lidar.
            lidar_pose (CarlaPose): The lidar's world pose, as CARLA prints it (metres, degrees).

        Returns:
            Rig: The rig as the reader will rebuild it from the written text (decimal poses move cam2lidar by
                about 1e-15), so a caller can render with the very matrices a reader gets.

        Raises:
            DatasetError: A lens cannot be stored in the layout, or differs from one already written.
        """
        frame_id = f"{int(frame_id):08d}"
        self._write_models(rig)
        timestamp = int(frame_id) * 0.05
        poses = {"lidar": lidar_pose, **camera_poses(rig, lidar_pose, self.convention)}
        written: dict[str, CarlaPose] = {}
        for sensor, pose in poses.items():
            folder = self.folder / sensor
            folder.mkdir(parents=True, exist_ok=True)
            if sensor == "lidar":
                line = format_record("LidarMeasurement", frame_id, pose, timestamp, "number_of_points=0")
            else:
                model = rig.camera(sensor).model
                line = format_record("Image", frame_id, pose, timestamp, f"width={model.width}, height={model.height}")
            _replace_record(folder / "sensor_metadata.txt", frame_id, line)
            written[sensor] = parse_sensor_metadata(line)[frame_id]
        matrices = {c: cam2lidar_from_poses(written[c], written["lidar"], self.convention) for c in rig.names}
        return Rig.from_cameras(
            {c.name: c.model for c in rig.cameras}, matrices, rig.names, name=f"{self.scene}/{self.vehicle}@{frame_id}"
        )

    def write_images(self, frame_id: str, images: Mapping[str, np.ndarray]) -> None:
        """Write ``<camera>/<frame_id>.png`` for each image.

        Args:
            frame_id (str): The frame's id.
            images (Mapping[str, np.ndarray]): Camera name -> `(H, W, 3)` uint8 BGR image.

        Raises:
            DatasetError: An image cannot be written.
        """
        frame_id = f"{int(frame_id):08d}"
        for camera, image in images.items():
            folder = self.folder / camera
            folder.mkdir(parents=True, exist_ok=True)
            if not cv2.imwrite(str(folder / f"{frame_id}.png"), image):
                raise DatasetError(f"frame {frame_id}: camera '{camera}': could not write {folder / f'{frame_id}.png'}")

    def write_labels(
        self,
        frame_id: str,
        boxes: np.ndarray,
        labels: np.ndarray,
        ids: Sequence[int] | None = None,
        class_names: Sequence[str] = CLASSES,
        velocities: np.ndarray | None = None,
    ) -> None:
        """Write ``label_3d/<frame_id>.json`` (boxes stored gravity-centred) and queue the frame for the split.

        Args:
            frame_id (str): The frame's id.
            boxes (np.ndarray): `(K, 7)` ``x, y, z_bottom, l, w, h, yaw``, lidar frame, metres and radians.
            labels (np.ndarray): `(K,)` class indices into ``class_names``.
            ids (Sequence[int] | None): Actor id of each object (default: 1 to K).
            class_names (Sequence[str]): Class names, in label order.
            velocities (np.ndarray | None): `(K, 2)` m/s in the lidar frame's axes, stored as each object's
                ``velocity``.
        """
        frame_id = f"{int(frame_id):08d}"
        label_boxes = bottom_to_gravity(boxes)
        lab = np.asarray(labels, np.int64)
        actor = list(ids) if ids is not None else list(range(1, len(lab) + 1))
        objects = [
            {
                "id": int(i),
                "class": class_names[c],
                "name": f"synthetic.{class_names[c].lower()}",
                "bounding_box": [float(v) for v in box],
            }
            for i, c, box in zip(actor, lab.tolist(), label_boxes)
        ]
        if velocities is not None:
            for obj, v in zip(objects, np.asarray(velocities, np.float64).reshape(-1, 2).tolist()):
                obj["velocity"] = v
        (self.folder / "label_3d").mkdir(parents=True, exist_ok=True)
        (self.folder / "label_3d" / f"{frame_id}.json").write_text(json.dumps(objects))
        entry = {
            "scene_name": self.scene,
            "vehicle_name": self.vehicle,
            "weather": self.weather,
            "frame_id": frame_id,
            "prev_id": "",
            "next_id": "",
        }
        self._entries.append(entry)

    def write_frame(
        self,
        frame_id: str,
        rig: Rig,
        images: Mapping[str, np.ndarray],
        boxes: np.ndarray,
        labels: np.ndarray,
        lidar_pose: CarlaPose,
        ids: Sequence[int] | None = None,
        class_names: Sequence[str] = CLASSES,
        velocities: np.ndarray | None = None,
    ) -> Rig:
        """Write one frame: poses, images and labels.

        Args:
            frame_id (str): The frame's id.
            rig (Rig): The cameras and their extrinsics.
            images (Mapping[str, np.ndarray]): One `(H, W, 3)` uint8 BGR image per rig camera.
            boxes (np.ndarray): `(K, 7)` runtime boxes, lidar frame.
            labels (np.ndarray): `(K,)` class indices.
            lidar_pose (CarlaPose): The lidar's world pose.
            ids (Sequence[int] | None): Actor id of each object (default: 1 to K).
            class_names (Sequence[str]): Class names, in label order.
            velocities (np.ndarray | None): `(K, 2)` velocities, m/s.

        Returns:
            Rig: The rig as the reader will rebuild it (see ``write_poses``).

        Raises:
            DatasetError: A rig camera has no image, or a lens or image cannot be written.
        """
        missing = [c for c in rig.names if c not in images]
        if missing:
            raise DatasetError(f"frame {frame_id}: no image for camera(s) {', '.join(missing)}")
        written = self.write_poses(frame_id, rig, lidar_pose)
        self.write_images(frame_id, images)
        self.write_labels(frame_id, boxes, labels, ids, class_names, velocities)
        return written

    def close(self) -> Path:
        """Record the written frames in the split file (merged with the samples it holds).

        Returns:
            Path: The split file, ``<root>/ImageSets-2hz/<split>.json``.
        """
        return update_split(self.root, self.split, self._entries)
