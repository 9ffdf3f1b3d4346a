"""Synthetic fisheye pictures: a scene's boxes on a textured ground, ray-cast through any rig.

Every pixel of every camera is unprojected with the camera's own model and followed into the
lidar frame: a ray that hits a box shows the box's class colour shaded by the face it hits, one
that falls towards the ground shows a checker-and-noise texture fading into haze, the rest shows
a sky gradient. Pixels outside the lens's field of view are black, as in real fisheye frames.
Because the pictures are made with the same camera model and extrinsics the detectors' geometry
uses, they exercise the whole data path (reader, rig, projection, metric) without the dataset.
The scene and its look are drawn in ``scenes.scene`` (`random_scene`, ``random_appearance``);
this module turns them into pixels, and `synthesize` writes whole frames with their labels.

    frames = synthesize(default_rig(), "data/synth", frames=4, seed=0)   # Fisheye3DOD layout
    Fisheye3DOD("data/synth", "val")                                   # reads the same rig and boxes

Everything is seeded: the same arguments write the same bytes.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel, Pinhole
from fisheye_infer.cameras.carla_poses import CarlaPose, Convention
from fisheye_infer.cameras.rig import Rig, RigCamera
from fisheye_infer.cameras.virtual_view import pixel_rays
from fisheye_infer.errors import RigError
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.scenes.scene import CLASS_COLOURS, Appearance, Scene, quantize, random_scene

__all__ = [
    "Renderer",
    "SynthFrame",
    "synthesize",
    "resized_rig",
    "random_scene",  # from scenes.scene; synthesize draws with it, and callers import it beside Renderer
]

_DEFAULT_SUN = Appearance().light
_LIGHT = np.array(_DEFAULT_SUN, np.float32) / np.linalg.norm(_DEFAULT_SUN)
_HAZE = np.array([200, 195, 185], np.float32)


def _hash01(ix: np.ndarray, iy: np.ndarray, seed: int) -> np.ndarray:
    """Deterministic value noise in [0, 1) per integer cell."""
    h = (ix.astype(np.int64) * 73856093) ^ (iy.astype(np.int64) * 19349663) ^ (seed * 83492791)
    h = (h ^ (h >> 13)) * 1274126177
    return ((h ^ (h >> 16)) & 0xFFFF).astype(np.float32) / 65536.0


#: Camera models whose rays a renderer keeps: a rig's lenses, with room for a training step's moved ones.
RAY_CACHE_MODELS = 16


class Renderer:
    """Ray-casts scenes through any camera model: a checkered, textured ground, a sky, and shaded boxes.

    The per-pixel rays of the latest camera models are kept (``RAY_CACHE_MODELS``, 16), so a rig's are
    computed once and moved lenses do not pile up.

    Args:
        texture_seed (int): Seed of the ground's noise texture.

    Examples:
        ```python
        import numpy as np
        from fisheye_infer import default_rig
        from fisheye_infer.scenes.render import Renderer
        from fisheye_infer.scenes.scene import random_scene

        scene = random_scene(np.random.default_rng(0))
        images = Renderer(texture_seed=0).render(default_rig(), scene)
        dets = detector.detect(images)           # what a model sees of the scene
        ```
    """

    def __init__(self, texture_seed: int = 0) -> None:
        self.texture_seed = texture_seed
        self._rays: dict[object, tuple[np.ndarray, np.ndarray]] = {}

    def camera_rays(self, model: object) -> tuple[np.ndarray, np.ndarray]:
        """Every pixel's unit ray in the camera frame, and which pixels lie inside the field of view.

        Args:
            model (object): A camera model (``unproject``, ``width``, ``height``; ``fov`` in degrees where it has one).

        Returns:
            tuple[np.ndarray, np.ndarray]: Rays `(3, H*W)` float32, component-major and row-major over the pixels,
                and `(H*W,)` bool, True inside the field of view.
        """
        if model not in self._rays:
            rays, inside = pixel_rays(model)
            if len(self._rays) >= RAY_CACHE_MODELS:
                del self._rays[next(iter(self._rays))]  # the oldest
            self._rays[model] = (np.ascontiguousarray(rays.T, np.float32), inside)
        return self._rays[model]

    def render(self, rig: Rig, scene: Scene, appearance: Appearance | None = None) -> dict[str, np.ndarray]:
        """One picture per camera of a rig.

        Args:
            rig (Rig): The cameras, their models and extrinsics.
            scene (Scene): The objects and the ground, lidar frame.
            appearance (Appearance | None): The look (default: ``Appearance()``).

        Returns:
            dict[str, np.ndarray]: Camera name -> `(H, W, 3)` uint8 BGR picture; black outside the lens's field.

        Raises:
            ValueError: ``appearance.object_colours`` does not have one colour per box.
        """
        return {cam.name: self.render_camera(cam, scene, appearance) for cam in rig.cameras}

    def render_camera(self, camera: RigCamera, scene: Scene, appearance: Appearance | None = None) -> np.ndarray:
        """One camera's picture.

        Args:
            camera (RigCamera): The camera: its model and cam2lidar matrix.
            scene (Scene): The objects and the ground, lidar frame.
            appearance (Appearance | None): The look (default: ``Appearance()``).

        Returns:
            np.ndarray: `(H, W, 3)` uint8 BGR picture.

        Raises:
            ValueError: ``appearance.object_colours`` does not have one colour per box.
        """
        look = appearance or Appearance()
        if look.object_colours is not None and len(look.object_colours) != len(scene.boxes):
            raise ValueError(f"appearance: {len(look.object_colours)} object colours for {len(scene.boxes)} boxes")
        rays_cam, inside = self.camera_rays(camera.model)
        m = camera.matrix
        d = m[:3, :3].astype(np.float32) @ rays_cam  # 3 x N, lidar frame
        o = m[:3, 3].astype(np.float32)
        colour, depth = self._background(o, d, scene.ground_z, look)
        light = np.array(look.light, np.float32) / np.linalg.norm(look.light)
        for i, (box, label) in enumerate(zip(scene.boxes, scene.labels)):
            bgr = CLASS_COLOURS[CLASSES[label]] if look.object_colours is None else look.object_colours[i]
            self._draw_box(o, d, box, bgr, colour, depth, light, look.ambient)
        colour[:, ~inside] = 0
        model = camera.model
        return np.clip(colour, 0, 255).astype(np.uint8).T.reshape(model.height, model.width, 3)

    def ray_depth(self, origin: np.ndarray, directions: np.ndarray, scene: Scene) -> np.ndarray:
        """Distance to the first surface (ground or box) along rays, with the pictures' own intersection code.

        A depth target computed here agrees with what the pixels show.

        Args:
            origin (np.ndarray): `(3,)` the rays' origin, lidar frame, metres.
            directions (np.ndarray): `(3, N)` unit rays, lidar frame.
            scene (Scene): The objects and the ground.

        Returns:
            np.ndarray: `(N,)` distances, metres; inf where a ray meets nothing.
        """
        o = np.asarray(origin, np.float32)
        d = np.ascontiguousarray(directions, np.float32)
        colour, depth = self._background(o, d, scene.ground_z, Appearance())
        for box in scene.boxes:
            self._draw_box(o, d, box, (0.0, 0.0, 0.0), colour, depth)
        return depth

    def _background(
        self, o: np.ndarray, d: np.ndarray, ground_z: float, look: Appearance
    ) -> tuple[np.ndarray, np.ndarray]:
        """Sky gradient everywhere, then the textured ground where rays fall towards it; colour is (3, N)."""
        up = np.clip(d[2], 0, 1)
        horizon, zenith = np.asarray(look.sky_horizon, np.float32), np.asarray(look.sky_zenith, np.float32)
        colour = horizon[:, None] * (1 - up) + zenith[:, None] * up
        depth = np.full(d.shape[1], np.inf, np.float32)
        if o[2] <= ground_z:
            return colour, depth
        down = np.nonzero(d[2] < -1e-4)[0]
        t = (np.float32(ground_z) - o[2]) / d[2, down]
        px, py = o[0] + t * d[0, down], o[1] + t * d[1, down]
        size = np.float32(look.checker_size)
        checker = (np.floor(px / size).astype(np.int64) + np.floor(py / size).astype(np.int64)) & 1
        noise = _hash01(np.floor(px * 4), np.floor(py * 4), self.texture_seed) - 0.5
        grey = (
            np.float32(look.ground_grey)
            + np.float32(look.checker_contrast) * checker
            + np.float32(look.noise_contrast) * noise
        )
        fog = np.exp(-np.hypot(px - o[0], py - o[1]) / np.float32(look.haze_distance))
        for ch, tint in enumerate(np.asarray(look.ground_tint, np.float32)):
            colour[ch, down] = (grey + tint) * fog + _HAZE[ch] * (1 - fog)
        depth[down] = t
        return colour, depth

    @staticmethod
    def _draw_box(
        o: np.ndarray,
        d: np.ndarray,
        box: np.ndarray,
        bgr: Sequence[float],
        colour: np.ndarray,
        depth: np.ndarray,
        light: np.ndarray = _LIGHT,
        ambient: float = 0.35,
    ) -> None:
        """Slab test against one oriented box, in place: nearer hits overwrite colour and depth.

        Only rays passing within the box's bounding sphere are tested.
        """
        x, y, zb, length, width, height, yaw = (float(v) for v in box)
        centre = np.array([x, y, zb + height / 2], np.float32)
        half = np.array([length / 2, width / 2, height / 2], np.float32)
        v = centre - o
        along = v @ d
        radius2 = float(half @ half)
        cand = np.nonzero((float(v @ v) - along * along < radius2) & (along > -math.sqrt(radius2)))[0]
        if len(cand) == 0:
            return
        c, s = math.cos(yaw), math.sin(yaw)
        to_box = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]], np.float32)  # lidar -> box frame
        ol = to_box @ (o - centre)
        dl = (to_box @ d[:, cand]).T  # m x 3
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / dl
            t1, t2 = (-half - ol) * inv, (half - ol) * inv
        tmin, tmax = np.fmin(t1, t2), np.fmax(t1, t2)
        near, far = tmin.max(axis=1), tmax.min(axis=1)
        hit = (near <= far) & (near > 0) & (near < depth[cand])
        cand, near, dl, axis = cand[hit], near[hit], dl[hit], tmin[hit].argmax(axis=1)
        if len(cand) == 0:
            return
        rows = np.arange(len(cand))
        normal = np.zeros((len(cand), 3), np.float32)
        normal[rows, axis] = -np.sign(dl[rows, axis])
        shade = ambient + (1 - ambient) * np.clip((normal @ to_box) @ light, 0, 1)  # normal back to the lidar frame
        local = ol + near[:, None] * dl
        edge = (np.abs(local) > half - 0.05).sum(axis=1) >= 2
        shade = np.where(edge, 0.3 * shade, shade)
        colour[:, cand] = np.asarray(bgr, np.float32)[:, None] * shade
        depth[cand] = near


@dataclass(frozen=True)
class SynthFrame:
    """What [`synthesize`][fisheye_infer.scenes.render.synthesize] wrote for one frame.

    Attributes:
        token (str): The sample token, ``<scene>.<vehicle>.<frame_id>``.
        frame_id (str): The frame's id, eight digits.
        rig (Rig): The rig as the reader rebuilds it from the written poses.
        boxes (np.ndarray): `(K, 7)` runtime boxes, lidar frame.
        labels (np.ndarray): `(K,)` class indices.
    """

    token: str
    frame_id: str
    rig: Rig
    boxes: np.ndarray  # (K, 7) runtime layout
    labels: np.ndarray  # (K,)


def synthesize(
    rig: Rig,
    out: str | Path,
    frames: int = 1,
    seed: int = 0,
    split: str = "val",
    scene_name: str | None = None,
    num_objects: tuple[int, int] = (6, 14),
    ground_height: float = 2.0,
    first_frame: int = 1000,
    convention: Convention = "compat",
) -> list[SynthFrame]:
    """Write synthetic frames of one sequence in the Fisheye3DOD layout, readable by ``Fisheye3DOD``.

    The ego vehicle drives along a gentle curve (level, so the compat conversion is exact); each frame gets
    its own seeded objects. The fisheye cameras' lenses are written as OCam's ``calib_results.txt`` (one
    shared, or one in each camera's folder), or as ``camera_model.json`` for other models; the pinhole
    cameras must be the layout's (``rig-pinhole6``'s), which the writer checks.

    Args:
        rig (Rig): The cameras the frames are rendered through.
        out (str | Path): The dataset folder (created if missing; other sequences in it are kept).
        frames (int): Frames to write, at least 1.
        seed (int): Seed of the objects and the texture; the same seed writes the same frames.
        split (str): The split file the frames are recorded in.
        scene_name (str | None): The scene folder (default: ``synth-Town00-ClearNoon-seed<seed>``).
        num_objects (tuple[int, int]): Least and most objects per frame.
        ground_height (float): Height of the lidar above the ground, metres.
        first_frame (int): Id of the first frame; ids step by 5 (CARLA's 20 Hz ticks at 4 Hz).
        convention (Convention): How poses convert (``"compat"`` or ``"exact"``).

    Returns:
        list[SynthFrame]: What was written per frame (token, rig as read back, boxes, labels).

    Raises:
        ValueError: ``frames`` is below 1.
        DatasetError: A lens cannot be stored in the layout, or the folder holds a different one.

    Examples:
        ```python
        from fisheye_infer import default_rig
        from fisheye_infer.eval import Fisheye3DOD
        from fisheye_infer.scenes.render import synthesize

        written = synthesize(default_rig(), "synth/", frames=8, seed=0)
        data = Fisheye3DOD("synth/", "val")
        assert data.tokens == [f.token for f in written]
        ```
    """
    from fisheye_infer.eval.writer import Fisheye3DODWriter

    if frames < 1:
        raise ValueError(f"frames: expected at least 1, got {frames}")
    scene_name = scene_name or f"synth-Town00-ClearNoon-seed{seed}"
    writer = Fisheye3DODWriter(out, scene_name, split=split, convention=convention)
    renderer = Renderer(texture_seed=seed)
    written = []
    for i in range(frames):
        rng = np.random.default_rng([seed, i])
        frame_id = f"{first_frame + 5 * i:08d}"
        heading = (seed * 37.0 + 2.0 * i) % 360.0 - 180.0
        lidar = CarlaPose(
            x=100.0 + 4.0 * i,
            y=-50.0 + 0.5 * i,
            z=float(quantize(ground_height, 1 / 256)),
            pitch=0.0,
            yaw=heading,
            roll=0.0,
        )
        scene = random_scene(rng, num_objects, ground_z=-ground_height)
        frame_rig = writer.write_poses(frame_id, rig, lidar)
        writer.write_images(frame_id, renderer.render(frame_rig, scene))
        writer.write_labels(frame_id, scene.boxes, scene.labels)
        written.append(
            SynthFrame(f"{scene_name}.{writer.vehicle}.{frame_id}", frame_id, frame_rig, scene.boxes, scene.labels)
        )
    writer.close()
    return written


def resized_rig(rig: Rig, scale: float) -> Rig:
    """The same rig with every image scaled by ``scale`` (e.g. 0.25: 800x800 -> 200x200); OCam and pinhole models.

    Pixel centres stay at integers: u' + 1/2 = s (u + 1/2). Image radii scale by s, so an OCam
    model's invpol is multiplied by s and pol's i-th coefficient by s^(1-i); a pinhole's focal
    lengths are multiplied by s.
    """
    if not scale > 0:
        raise ValueError(f"scale: expected a positive factor, got {scale}")
    cameras = []
    for cam in rig.cameras:
        m = cam.model
        if not isinstance(m, (OCamModel, Pinhole)):
            raise RigError(f"camera '{cam.name}': only OCam and pinhole models can be resized, got {m.type}")
        width, height = round(m.width * scale), round(m.height * scale)
        if width < 1 or height < 1 or abs(width / m.width - height / m.height) > 1e-9:
            raise ValueError(
                f"scale: {scale} does not give a whole image with the same aspect "
                f"({m.width}x{m.height} -> {width}x{height})"
            )
        s = width / m.width
        size = {"width": width, "height": height}
        resized: OCamModel | Pinhole
        if isinstance(m, Pinhole):
            resized = m.model_copy(
                update={
                    "fx": m.fx * s,
                    "fy": m.fy * s,
                    "cx": (m.cx + 0.5) * s - 0.5,
                    "cy": (m.cy + 0.5) * s - 0.5,
                    **size,
                }
            )
        else:
            resized = m.model_copy(
                update={
                    "pol": tuple(p * s ** (1 - i) for i, p in enumerate(m.pol)),
                    "invpol": tuple(p * s for p in m.invpol),
                    "center_row": (m.center_row + 0.5) * s - 0.5,
                    "center_col": (m.center_col + 0.5) * s - 0.5,
                    **size,
                }
            )
        cameras.append({"name": cam.name, "model": resized.model_dump(), "cam2lidar": cam.cam2lidar})
    return Rig.from_dict({"name": f"{rig.name}@x{scale:g}", "cameras": cameras})
