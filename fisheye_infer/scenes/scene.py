"""What a synthetic frame holds and how it looks, drawn at random: the boxes of the six classes
(`Scene`, `random_scene`) and the lighting, ground, sky and object colours
(`Appearance`, `random_appearance`).

Kept apart from ``render`` (which ray-casts a scene through a rig) because the depth targets, the
training streams and the viewer need the scene and the class colours without the renderer; the
scene is plain data a renderer or a label writer reads.

Everything is drawn from the caller's seeded generator. Box parameters are multiples of 1/256 m
(yaw of 1/1024 rad, see `quantize`), so the gravity-centre labels written for a scene convert
back to the same numbers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fisheye_infer.runtime.records import CLASSES

__all__ = [
    "CLASS_SIZES",
    "CLASS_COLOURS",
    "Scene",
    "Appearance",
    "random_appearance",
    "random_scene",
    "quantize",
]

#: Typical (length, width, height) in metres per class.
CLASS_SIZES = {
    "Car": (4.5, 1.9, 1.6),
    "Van": (5.0, 2.0, 2.1),
    "Truck": (7.5, 2.5, 3.2),
    "Bus": (11.0, 2.9, 3.3),
    "Pedestrian": (0.7, 0.7, 1.75),
    "Cyclist": (1.8, 0.7, 1.7),
}
#: BGR colour per class, far from the greys of the ground and the blues of the sky.
CLASS_COLOURS = {
    "Car": (40, 40, 210),
    "Van": (0, 140, 255),
    "Truck": (0, 215, 235),
    "Bus": (210, 110, 20),
    "Pedestrian": (200, 40, 200),
    "Cyclist": (40, 190, 40),
}
_CLASS_WEIGHTS = (0.4, 0.15, 0.1, 0.05, 0.2, 0.1)
_SUN = (0.3, 0.5, 0.81)
_SKY_HORIZON = np.array([215, 205, 190], np.float32)
_SKY_ZENITH = np.array([205, 140, 80], np.float32)


def quantize(x: np.ndarray | float, step: float) -> np.ndarray:
    """``x`` rounded to the nearest multiple of ``step`` (float64)."""
    return np.round(np.asarray(x, np.float64) / step) * step


@dataclass(frozen=True)
class Scene:
    """The objects of one frame, standing on a flat ground.

    Attributes:
        boxes (np.ndarray): `(K, 7)` ``x, y, z_bottom, l, w, h, yaw``, lidar frame, metres and radians.
        labels (np.ndarray): `(K,)` int64 indices into the six Fisheye3DOD classes.
        ground_z (float): Height of the ground plane in the lidar frame, metres (below the lidar: negative).
    """

    boxes: np.ndarray
    labels: np.ndarray
    ground_z: float = -2.0


@dataclass(frozen=True)
class Appearance:
    """How a scene looks: lighting, ground texture, sky and object colours.

    The defaults are the renderer's standard look;
    [`random_appearance`][fisheye_infer.scenes.scene.random_appearance] varies every field for training data.
    Colours are BGR, 0-255.

    Attributes:
        light (tuple[float, float, float]): Direction towards the sun in the lidar frame, any length.
        ambient (float): Share of light every surface gets in shade, in [0, 1].
        ground_grey (float): Mean brightness of the ground.
        checker_contrast (float): Brightness step between the ground's checker squares.
        noise_contrast (float): Amplitude of the ground's fine noise texture.
        checker_size (float): Side of a checker square, metres.
        ground_tint (tuple[float, float, float]): Offset added to the ground's grey per channel.
        sky_horizon (tuple[float, float, float]): Sky colour at the horizon.
        sky_zenith (tuple[float, float, float]): Sky colour straight up.
        haze_distance (float): Distance over which the ground fades into the horizon colour, metres.
        object_colours (tuple[tuple[float, float, float], ...] | None): One colour per box of the scene
            (None: the class colours).
    """

    light: tuple[float, float, float] = _SUN  # towards the sun, any length
    ambient: float = 0.35
    ground_grey: float = 100.0
    checker_contrast: float = 40.0
    noise_contrast: float = 36.0
    checker_size: float = 2.0
    ground_tint: tuple[float, float, float] = (-6.0, 0.0, 6.0)
    sky_horizon: tuple[float, float, float] = tuple(float(v) for v in _SKY_HORIZON)  # type: ignore[assignment]
    sky_zenith: tuple[float, float, float] = tuple(float(v) for v in _SKY_ZENITH)  # type: ignore[assignment]
    haze_distance: float = 90.0
    object_colours: tuple[tuple[float, float, float], ...] | None = None


def random_appearance(rng: np.random.Generator, scene: Scene, colour_jitter: float = 45.0) -> Appearance:
    """A random look for a scene: sun, ground brightness, texture scale and tint, sky colours, haze, object colours.

    Each object's class colour is shifted by up to ``colour_jitter`` per channel and scaled in brightness, so
    classes stay told apart by colour family and size.

    Args:
        rng (np.random.Generator): The source of randomness (the same state gives the same look).
        scene (Scene): The scene the look is for (its labels give the object colours).
        colour_jitter (float): Largest shift of an object's colour per channel, 0-255 units.

    Returns:
        Appearance: The look, with one colour per box of ``scene``.
    """
    elevation, azimuth = rng.uniform(0.25, 1.4), rng.uniform(-math.pi, math.pi)
    light = (math.cos(elevation) * math.cos(azimuth), math.cos(elevation) * math.sin(azimuth), math.sin(elevation))
    colours: list[tuple[float, float, float]] = []
    for label in scene.labels:
        base = np.asarray(CLASS_COLOURS[CLASSES[int(label)]], np.float64)
        colour = np.clip((base + rng.uniform(-colour_jitter, colour_jitter, 3)) * rng.uniform(0.75, 1.2), 0, 255)
        colours.append((float(colour[0]), float(colour[1]), float(colour[2])))
    return Appearance(
        light=light,
        ambient=float(rng.uniform(0.2, 0.5)),
        ground_grey=float(rng.uniform(60, 150)),
        checker_contrast=float(rng.uniform(0, 60)),
        noise_contrast=float(rng.uniform(10, 60)),
        checker_size=float(rng.uniform(0.5, 4.0)),
        ground_tint=tuple(float(v) for v in rng.uniform(-20, 20, 3)),  # type: ignore[arg-type]
        sky_horizon=tuple(float(v) for v in np.clip(_SKY_HORIZON + rng.uniform(-40, 30, 3), 0, 255)),  # type: ignore[arg-type]
        sky_zenith=tuple(float(v) for v in np.clip(_SKY_ZENITH + rng.uniform(-40, 40, 3), 0, 255)),  # type: ignore[arg-type]
        haze_distance=float(rng.uniform(50, 200)),
        object_colours=tuple(colours),
    )


def random_scene(
    rng: np.random.Generator,
    num_objects: tuple[int, int] = (6, 14),
    ground_z: float = -2.0,
    min_range: float = 4.0,
    max_range: float = 35.0,
    size_jitter: float = 0.1,
) -> Scene:
    """A random scene: objects standing on the ground, not overlapping each other or the ego vehicle's footprint.

    Distances are uniform in [min_range, max_range], so near objects are as common as far ones. Positions and
    sizes are rounded to 1/256 m, yaws to 1/1024 rad.

    Args:
        rng (np.random.Generator): The source of randomness (the same state gives the same scene).
        num_objects (tuple[int, int]): Least and most objects; fewer are placed where no free spot is found.
        ground_z (float): Height of the ground in the lidar frame, metres.
        min_range (float): Nearest object centre, metres from the lidar.
        max_range (float): Farthest object centre, metres.
        size_jitter (float): Each size is the class's typical one times a factor in
            [1 - size_jitter, 1 + size_jitter]; in [0, 1).

    Returns:
        Scene: The objects and the ground height.

    Raises:
        ValueError: The counts, ranges or ``size_jitter`` are out of order or out of range.
    """
    lo, hi = num_objects
    if not 0 <= lo <= hi or not 0 < min_range < max_range:
        raise ValueError(
            f"num_objects/min_range/max_range: expected 0 <= {lo} <= {hi} and 0 < {min_range} < {max_range}"
        )
    if not 0 <= size_jitter < 1:
        raise ValueError(f"size_jitter: expected a fraction in [0, 1), got {size_jitter}")
    wanted = int(rng.integers(lo, hi + 1))
    sizes = np.array([CLASS_SIZES[c] for c in CLASSES])
    ground = float(quantize(ground_z, 1 / 256))
    boxes: list[np.ndarray] = []
    labels: list[int] = []
    for _ in range(50 * max(wanted, 1)):
        if len(boxes) == wanted:
            break
        label = int(rng.choice(len(CLASSES), p=_CLASS_WEIGHTS))
        lwh = sizes[label] * rng.uniform(1 - size_jitter, 1 + size_jitter, 3)
        r = rng.uniform(min_range, max_range)
        phi = rng.uniform(-math.pi, math.pi)
        box = np.array([r * math.cos(phi), r * math.sin(phi), ground, *lwh, rng.uniform(-math.pi, math.pi)])
        box[:6], box[6] = quantize(box[:6], 1 / 256), quantize(box[6], 1 / 1024)
        radius = math.hypot(box[3], box[4]) / 2
        if abs(box[0]) < 3.0 + radius and abs(box[1]) < 1.5 + radius:
            continue
        if any(math.hypot(box[0] - b[0], box[1] - b[1]) < radius + math.hypot(b[3], b[4]) / 2 + 0.3 for b in boxes):
            continue
        boxes.append(box)
        labels.append(label)
    return Scene(np.array(boxes, np.float64).reshape(-1, 7), np.array(labels, np.int64), ground)
