"""The randomised synthetic streams training and evaluation draw from, and their files on disk.

Frame ``i`` of a split is fully determined by ``(split, seed, i)``: the scene (object count, classes,
sizes, yaw, placements, hence occlusions), its look (sun, ground texture and tint, sky, haze,
object colours, texture seed) and so its pictures. The two splits draw from separate seed streams
(the split's tag is part of every seed sequence), so no validation frame is ever trained on.

Labels travel as Fisheye3DOD ground-truth records (the evaluator's format) and are turned into
the head's arrays with the same conversion the evaluator uses; boxes whose centre lies outside
the head's BEV range are dropped (the official ``ObjectRangeFilter``).

``write_split`` puts frames of a stream on disk in the Fisheye3DOD layout, so that a held-out set
is evaluated by ``fisheye-infer eval`` like any recorded data:

    write_split(SyntheticFrames(rig, "val"), "data/heldout", range(200))
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.cameras.carla_poses import CarlaPose
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.runtime.records import GT_SCORE, boxes_to_records, records_to_arrays
from fisheye_infer.scenes.render import Renderer
from fisheye_infer.scenes.scene import Scene, random_appearance, random_scene

__all__ = ["Sample", "SyntheticFrames", "SPLITS", "write_split", "write_frame_folder"]

#: Tag of each split in its seed sequences.
SPLITS = {"train": 0x7472, "val": 0x76616C}


@dataclass(frozen=True)
class Sample:
    """One frame: images N x H x W x 3 uint8 BGR in the rig's camera order, and its ground truth."""

    index: int
    images: np.ndarray
    records: tuple[dict[str, Any], ...]
    boxes: np.ndarray  # (M, 7) runtime layout, from the records
    labels: np.ndarray  # (M,)
    scene: Scene  # every object rendered, also those outside the BEV range (they still hide what is behind them)


class SyntheticFrames:
    """Seeded synthetic frames of one split for a rig, with the scene and look randomised per frame.

    train = SyntheticFrames(rig, "train", seed=0, bev_range=(-48, -48, 48, 48))
    sample = train[123]      # the same pictures and records every time
    """

    def __init__(
        self,
        rig: Rig,
        split: str = "train",
        seed: int = 0,
        *,
        bev_range: Sequence[float] = (-48.0, -48.0, 48.0, 48.0),
        num_objects: tuple[int, int] = (4, 16),
        max_range: float = 40.0,
        size_jitter: float = 0.2,
        colour_jitter: float = 45.0,
    ) -> None:
        if split not in SPLITS:
            raise ValueError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
        if len(bev_range) != 4 or not (bev_range[0] < bev_range[2] and bev_range[1] < bev_range[3]):
            raise ValueError(f"bev_range: expected (x_min, y_min, x_max, y_max) with min < max, got {tuple(bev_range)}")
        self.rig, self.split, self.seed = rig, split, int(seed)
        self.bev_range = tuple(float(v) for v in bev_range)
        self.num_objects, self.max_range = num_objects, float(max_range)
        self.size_jitter, self.colour_jitter = float(size_jitter), float(colour_jitter)
        self.renderer = Renderer()

    def rng(self, index: int) -> np.random.Generator:
        return np.random.default_rng([SPLITS[self.split], self.seed, int(index)])

    def __getitem__(self, index: int) -> Sample:
        return self.frame(index)

    def frame(self, index: int, rig: Rig | None = None) -> Sample:
        """Frame ``index``; ``rig`` (the same cameras, calibrated otherwise) renders its scene through other
        lenses or poses: the scene, look and records stay frame ``index``'s."""
        rig = self.rig if rig is None else rig
        if rig.names != self.rig.names:
            raise ValueError(f"rig: cameras {rig.names}, expected the stream's {self.rig.names}")
        scene, pictures, records = self.draw(index, rig)
        images = np.stack([pictures[name] for name in rig.names])
        boxes, _, labels = records_to_arrays(records, source=f"{self.split} frame {index}")
        return Sample(int(index), images, records, boxes, labels, scene)

    def draw(self, index: int, rig: Rig) -> tuple[Scene, dict[str, np.ndarray], tuple[dict[str, Any], ...]]:
        """Frame ``index``'s scene, its pictures through any ``rig`` (cameras of any names, models and sizes) and its
        ground-truth records.

        Args:
            index: The frame's index in the stream.
            rig: The cameras to render it through.

        Returns:
            tuple: The scene, camera name -> (H, W, 3) uint8 BGR picture, and the records within the BEV range.
        """
        if index < 0:
            raise IndexError(f"frame index must be non-negative, got {index}")
        rng = self.rng(index)
        scene = random_scene(
            rng,
            self.num_objects,
            ground_z=-float(rng.uniform(1.7, 2.3)),
            max_range=self.max_range,
            size_jitter=self.size_jitter,
        )
        look = random_appearance(rng, scene, self.colour_jitter)
        self.renderer.texture_seed = int(rng.integers(0, 2**31))
        pictures = self.renderer.render(rig, scene, look)
        x0, y0, x1, y1 = self.bev_range
        b = scene.boxes
        keep = (b[:, 0] >= x0) & (b[:, 0] < x1) & (b[:, 1] >= y0) & (b[:, 1] < y1)
        records = tuple(boxes_to_records(b[keep], np.full(int(keep.sum()), GT_SCORE), scene.labels[keep]))
        return scene, pictures, records


def write_split(
    frames: SyntheticFrames, root: str | Path, indices: Iterable[int], split: str | None = None
) -> list[str]:
    """Write frames ``indices`` of a stream under ``root`` in the Fisheye3DOD layout; returns their tokens.

    One sequence per stream and seed (``synth-Town00-Randomised<split>-seed<seed>/ego0``), frame id
    = stream index, so a token names the frame it came from. The ego pose is level, which makes
    the written poses give back the rig's cam2lidar (to ~1e-15); ``split`` names the split file
    (default: the stream's own name).
    """
    from fisheye_infer.eval.writer import Fisheye3DODWriter

    scene = f"synth-Town00-Randomised{frames.split.capitalize()}-seed{frames.seed}"
    writer = Fisheye3DODWriter(root, scene, split=split or frames.split)
    tokens = []
    for index in indices:
        _, images, records = frames.draw(index, frames.rig)  # each camera at its own size
        boxes, _, labels = records_to_arrays(records, source=f"{frames.split} frame {index}")
        frame_id = f"{index:08d}"
        lidar = CarlaPose(x=100.0, y=-50.0, z=2.0, pitch=0.0, yaw=0.0, roll=0.0)
        writer.write_frame(frame_id, frames.rig, images, boxes, labels, lidar)
        tokens.append(f"{scene}.{writer.vehicle}.{frame_id}")
    writer.close()
    return tokens


def write_frame_folder(frames: SyntheticFrames, index: int, folder: str | Path) -> Path:
    """One frame as ``fisheye-infer detect --images FOLDER`` reads it: ``<camera>.png`` per camera,
    plus ``labels.json`` (``{"token", "records"}``: its ground-truth records)."""
    import json

    import cv2

    _, images, records = frames.draw(index, frames.rig)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, image in images.items():
        cv2.imwrite(str(folder / f"{name}.png"), image)
    token = f"{frames.split}-seed{frames.seed}-{index:08d}"
    (folder / "labels.json").write_text(json.dumps({"token": token, "records": list(records)}, indent=1) + "\n")
    return folder
