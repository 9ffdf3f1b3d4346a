"""Synthetic sequences: one scene over time, objects moving by class, the ego vehicle parked or driving.

    seqs = SyntheticSequences(rig, "val", seed=0, length=40)         # 10 Hz
    seq = seqs.sequence(3)                                          # poses and ground truth, no pictures
    frame = seq.frames[0]; frame.boxes, frame.ids, frame.velocities, frame.ego_pose, frame.stamp
    pictures = seqs.render(seq, 0)                                  # camera name -> BGR image
    write_sequences(seqs, "seqs/", range(8))                        # the Fisheye3DOD layout

Sequence ``i`` of a split is fully determined by ``(split, seed, i)``: the actors (class, size, start,
path: ``actors.simulate_actors``), the ego's drive (``actors.simulate_ego``) and the look. Its seed
sequence starts with the split's tag (``streams.SPLITS``) and a tag of its own, so train and val
sequences never share a draw, and none shares one with a stream frame. Actors start up to 55 m away, so
they enter and leave the 48 m labelled range as they move, and hide one another as they pass.

Ground truth is per frame, in the ego (lidar) frame of that frame: runtime boxes, labels, instance
ids (one per actor, from 1), and velocities over ground (m/s, the ego's own motion taken out,
expressed in the frame's axes). ``write_sequences`` writes one ``<scene>/ego0`` sequence per index:
frame ids step by 20 / rate (the layout's timestamps are CARLA's 20 Hz ticks, 0.05 s each), the ego
pose of every frame as the lidar's pose, and each label object's ``velocity``; the ground texture
moves with the ego (it is drawn in the lidar frame).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.scenes.actors import simulate_actors, simulate_ego
from fisheye_infer.scenes.render import Renderer
from fisheye_infer.scenes.scene import CLASS_SIZES, Appearance, Scene, random_appearance
from fisheye_infer.scenes.streams import SPLITS

__all__ = ["SequenceFrame", "Sequence", "SyntheticSequences", "write_sequences", "RATES"]

_TAG = 0x53455153  # "SEQS"
#: Frame rates the layout's 20 Hz frame ids can carry (Hz).
RATES = (1.0, 2.0, 4.0, 5.0, 10.0, 20.0)
_CLASS_WEIGHTS = (0.4, 0.1, 0.08, 0.04, 0.26, 0.12)
_RENDER_RANGE = 70.0


@dataclass(frozen=True)
class SequenceFrame:
    """One frame of a synthetic sequence; boxes and velocities in this frame's ego frame.

    Attributes:
        index (int): The frame's position in the sequence.
        stamp (float): Seconds from the sequence's start.
        ego_pose (np.ndarray): `(4, 4)` ego-to-world matrix.
        boxes (np.ndarray): `(K, 7)` runtime boxes of the objects within the labelled range.
        labels (np.ndarray): `(K,)` class indices.
        ids (np.ndarray): `(K,)` instance ids, from 1 (one per actor, stable over the sequence).
        velocities (np.ndarray): `(K, 2)` velocities over ground, m/s, in this frame's axes.
        scene (Scene): Every object near enough to be drawn (they hide what is behind them).
    """

    index: int
    stamp: float  # seconds from the sequence's start
    ego_pose: np.ndarray  # (4, 4) ego-to-world
    boxes: np.ndarray  # (K, 7) runtime layout, the objects within the labelled range
    labels: np.ndarray  # (K,)
    ids: np.ndarray  # (K,) instance ids, from 1
    velocities: np.ndarray  # (K, 2) m/s over ground
    scene: Scene  # every object near enough to be drawn (they hide what is behind them)


@dataclass(frozen=True)
class Sequence:
    """A synthetic sequence's frames, and the look they are drawn with (one colour per actor).

    Attributes:
        index (int): The sequence's index in its split.
        frames (tuple[SequenceFrame, ...]): The frames, in time order.
        look (Appearance): The look, one object colour per actor.
        texture_seed (int): Seed of the ground texture.
        drawn (tuple[np.ndarray, ...]): Per frame, the actor indices of ``frame.scene``'s boxes.
    """

    index: int
    frames: tuple[SequenceFrame, ...]
    look: Appearance
    texture_seed: int
    drawn: tuple[np.ndarray, ...]  # per frame: the actor indices of ``frame.scene``'s boxes


class SyntheticSequences:
    """Seeded synthetic sequences of one split for a rig: one scene over time, objects moving by class.

    Sequence ``i`` is fully determined by ``(split, seed, i)``; train and val sequences never share a draw.
    Actors start up to 55 m away, so they enter and leave the labelled range and hide one another as they pass.

    Args:
        rig (Rig): The cameras the frames are drawn through.
        split (str): ``train`` or ``val``.
        seed (int): Seed of the split's sequences.
        length (int): Frames per sequence.
        rate (float): Frames per second, one of ``RATES``.
        num_actors (tuple[int, int]): Least and most actors per sequence.
        ego_speed (float): Fastest ego drive, m/s (0: the ego is always parked).
        bev_range (float): Half side of the labelled square around the ego, metres.

    Raises:
        ValueError: ``split`` or ``rate`` is not one of the allowed values, or the length, actor counts or
            speed are out of range.

    Examples:
        ```python
        seqs = SyntheticSequences(rig, "val", seed=0, length=40)     # 10 Hz
        seq = seqs.sequence(3)                                       # poses and ground truth, no pictures
        for t, frame in enumerate(seq.frames):
            tracks = tracker.update(detector.detect(seqs.render(seq, t)), frame.stamp, ego_pose=frame.ego_pose)
        ```
    """

    def __init__(
        self,
        rig: Rig,
        split: str = "val",
        seed: int = 0,
        *,
        length: int = 40,
        rate: float = 10.0,
        num_actors: tuple[int, int] = (10, 24),
        ego_speed: float = 8.0,
        bev_range: float = 48.0,
    ) -> None:
        if split not in SPLITS:
            raise ValueError(f"split: expected one of {', '.join(SPLITS)}, got {split!r}")
        if rate not in RATES:
            raise ValueError(f"rate: expected one of {', '.join(f'{r:g}' for r in RATES)} Hz, got {rate}")
        if length < 1 or not 1 <= num_actors[0] <= num_actors[1] or ego_speed < 0:
            raise ValueError(
                f"length/num_actors/ego_speed: expected length >= 1, 1 <= min <= max actors and a speed >= 0, "
                f"got {length}, {num_actors}, {ego_speed}"
            )
        self.rig, self.split, self.seed = rig, split, int(seed)
        self.length, self.rate, self.num_actors = int(length), float(rate), num_actors
        self.ego_speed, self.bev_range = float(ego_speed), float(bev_range)
        self.renderer = Renderer()

    def rng(self, index: int) -> np.random.Generator:
        """The random generator sequence ``index`` is drawn from.

        Args:
            index (int): The sequence's index.

        Returns:
            np.random.Generator: A fresh generator seeded by the split, the seed and ``index``.
        """
        return np.random.default_rng([SPLITS[self.split], _TAG, self.seed, int(index)])

    def sequence(self, index: int) -> Sequence:
        """One sequence's frames (poses and ground truth) and its look, without pictures.

        Args:
            index (int): The sequence's index, >= 0.

        Returns:
            Sequence: The sequence.

        Raises:
            IndexError: ``index`` is negative.
        """
        if index < 0:
            raise IndexError(f"sequence index must be non-negative, got {index}")
        rng = self.rng(index)
        dt = 1.0 / self.rate
        height = float(np.round(rng.uniform(1.7, 2.3) * 256) / 256)
        poses = simulate_ego(rng, self.length, dt, self.ego_speed)
        n = int(rng.integers(self.num_actors[0], self.num_actors[1] + 1))
        labels = rng.choice(len(CLASSES), size=n, p=_CLASS_WEIGHTS)
        sizes = np.array([CLASS_SIZES[CLASSES[c]] for c in labels]) * rng.uniform(0.85, 1.15, (n, 3))
        radii = np.hypot(sizes[:, 0], sizes[:, 1]) / 2
        start = self._starts(rng, radii, poses)
        states = simulate_actors(rng, labels, radii, start, self.length, dt)
        look = random_appearance(rng, Scene(np.zeros((n, 7)), labels, -height))
        texture_seed = int(rng.integers(0, 2**31))
        frames, drawn = [], []
        for t in range(self.length):
            frame, near = self._frame(t, poses[t], states[t], labels, sizes, height)
            frames.append(frame)
            drawn.append(near)
        return Sequence(int(index), tuple(frames), look, texture_seed, tuple(drawn))

    def _starts(self, rng: np.random.Generator, radii: np.ndarray, poses: np.ndarray) -> np.ndarray:
        """Start x, y, heading of each actor: within 55 m of the ego's path, clear of each other and of the ego."""
        out = np.zeros((len(radii), 3))
        placed: list[int] = []
        for i in range(len(radii)):
            for _ in range(200):
                anchor = poses[int(rng.integers(0, len(poses))), :2, 3]
                r, phi = rng.uniform(5.0, 55.0), rng.uniform(-math.pi, math.pi)
                xy = anchor + r * np.array([math.cos(phi), math.sin(phi)])
                clear = all(np.hypot(*(xy - out[j, :2])) > radii[i] + radii[j] + 1.0 for j in placed)
                ego = np.min(np.hypot(*(poses[:, :2, 3] - xy).T)) > radii[i] + 3.5
                if clear and ego:
                    break
            out[i] = [xy[0], xy[1], rng.uniform(-math.pi, math.pi)]
            placed.append(i)
        return out

    def _frame(
        self, t: int, pose: np.ndarray, state: np.ndarray, labels: np.ndarray, sizes: np.ndarray, height: float
    ) -> tuple[SequenceFrame, np.ndarray]:
        ego_heading = math.atan2(pose[1, 0], pose[0, 0])
        rot = pose[:2, :2]
        xy = (state[:, :2] - pose[:2, 3]) @ rot  # world -> ego
        yaw = (state[:, 2] - ego_heading + math.pi) % (2 * math.pi) - math.pi
        boxes = np.column_stack([xy, np.full(len(xy), -height), sizes, yaw])
        v_world = state[:, 3:4] * np.stack([np.cos(state[:, 2]), np.sin(state[:, 2])], 1)
        velocities = v_world @ rot
        dist = np.hypot(xy[:, 0], xy[:, 1])
        near = np.flatnonzero(dist < _RENDER_RANGE)
        inside = np.flatnonzero((np.abs(xy[:, 0]) < self.bev_range) & (np.abs(xy[:, 1]) < self.bev_range))
        frame = SequenceFrame(
            index=t,
            stamp=t / self.rate,
            ego_pose=pose.copy(),
            boxes=boxes[inside],
            labels=labels[inside].astype(np.int64),
            ids=inside.astype(np.int64) + 1,
            velocities=velocities[inside],
            scene=Scene(boxes[near], labels[near].astype(np.int64), -height),
        )
        return frame, near

    def render(self, sequence: Sequence, t: int, rig: Rig | None = None) -> dict[str, np.ndarray]:
        """The pictures of one frame of a sequence.

        Args:
            sequence (Sequence): A sequence from
                [`sequence`][fisheye_infer.scenes.sequences.SyntheticSequences.sequence].
            t (int): The frame's index.
            rig (Rig | None): The cameras to draw through (default: the sequences' own).

        Returns:
            dict[str, np.ndarray]: Camera name -> `(H, W, 3)` uint8 BGR picture.
        """
        frame, near = sequence.frames[t], sequence.drawn[t]
        assert sequence.look.object_colours is not None
        colours = tuple(sequence.look.object_colours[i] for i in near.tolist())
        self.renderer.texture_seed = sequence.texture_seed
        return self.renderer.render(
            rig or self.rig, frame.scene, dataclasses.replace(sequence.look, object_colours=colours)
        )

    def scene_name(self, index: int) -> str:
        """The Fisheye3DOD scene folder a sequence is written to.

        Args:
            index (int): The sequence's index.

        Returns:
            str: ``synth-Town00-Sequence<Split>-seed<seed>-n<index>``.
        """
        return f"synth-Town00-Sequence{self.split.capitalize()}-seed{self.seed}-n{index:04d}"


def write_sequences(
    seqs: SyntheticSequences, root: str | Path, indices: Iterable[int], split: str | None = None
) -> list[str]:
    """Write sequences in the Fisheye3DOD layout, one ``<scene>/ego0`` folder each.

    Frame ids step by 20 / rate (the layout's timestamps are CARLA's 20 Hz ticks); each frame's ego pose is
    written as the lidar's pose, and each label object carries its ``velocity`` and actor id, so
    ``read_sequences`` and ``fisheye-infer eval --tracking`` read them back as sequences.

    Args:
        seqs (SyntheticSequences): The generator.
        root (str | Path): The dataset folder.
        indices (Iterable[int]): The sequences to write.
        split (str | None): The split file to record them in (default: the sequences' own split).

    Returns:
        list[str]: The scene folders written, in the order of ``indices``.
    """
    from fisheye_infer.eval.writer import Fisheye3DODWriter, pose_from_matrix

    step = round(20 / seqs.rate)
    scenes = []
    for index in indices:
        seq = seqs.sequence(index)
        writer = Fisheye3DODWriter(root, seqs.scene_name(index), split=split or seqs.split)
        for t, frame in enumerate(seq.frames):
            lidar = frame.ego_pose.copy()
            lidar[2, 3] = -frame.scene.ground_z  # the lidar above the world's ground plane
            pictures = seqs.render(seq, t)
            writer.write_frame(
                f"{t * step:08d}", seqs.rig, pictures, frame.boxes, frame.labels, pose_from_matrix(lidar),
                ids=frame.ids.tolist(), velocities=frame.velocities,
            )  # fmt: skip
        writer.close()
        scenes.append(seqs.scene_name(index))
    return scenes
