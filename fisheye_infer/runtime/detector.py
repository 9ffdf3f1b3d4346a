"""``Detector``: an exported model file -> ONNX Runtime -> boxes, with nothing heavier than OpenCV.

    detector = Detector("fisheye_bevdet.onnx")
    dets = detector.detect({"fisheye_camera_front": "front.png", ...})   # or arrays, bytes, a list
    dets.to_nuscenes()

The default result is exactly the official test-time output set: every box whose centre lies
in the model's post_center_range, no score threshold, no NMS. Thresholds, class filters and
NMS are opt-in, per Detector or per call. One Detector may be shared by threads: ONNX Runtime
sessions are safe to run concurrently and the Detector keeps no per-call state.

``FrameDetector`` holds everything around the graph run (decode, checks, stacking,
post-processing); ``Detector`` runs the graph with ONNX Runtime, ``TritonDetector``
(``fisheye_infer.deploy.triton``) on a Triton server, and both return the same boxes.

Options are checked where they enter, before any work, with an ``OptionError`` naming the option
(a threshold of 2.0 or NaN would otherwise silently return no boxes). The file's metadata is
checked against its graph at load: the box count against the outputs' static shapes, and the
class list against the labels the graph returns (at warm-up, and on every run).
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError, FrameError, OptionError
from fisheye_infer.runtime.artifact import (
    INPUT_CAMERA_VALID,
    INPUT_IMAGES,
    METADATA_KEY,
    OUTPUTS,
    ArtifactMeta,
    parse_meta,
)
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.runtime.options import check_classes, check_nms, check_score_threshold
from fisheye_infer.runtime.preprocess import Frame, load_frames, stack_frames
from fisheye_infer.runtime.session import (
    Provider,
    check_threads,
    create_session,
    log,
    map_ort_errors,
    resolve_providers,
    usable_cpus,
)
from fisheye_infer.tools.cpu import cpu_info, int8_saturation_warning

__all__ = ["Detector", "DetectorInfo", "FrameDetector", "check_interface", "check_output_shapes", "describe"]

#: Set in a Detector's decode threads: ``map_images`` called from one runs in that thread (no nesting deadlock).
_decoding = threading.local()


@dataclass(frozen=True)
class DetectorInfo:
    """What a caller needs to feed the model and read its output (``Detector.info``).

    Attributes:
        architecture (str): The model's architecture (``fisheye_bevdet``, ``fisheye_petr``).
        model_id (str): Architecture, rig hash and checkpoint digest: names this file's behaviour.
        classes (tuple[str, ...]): Class names, in label order.
        cameras (tuple[str, ...]): Camera names, in the order the model takes them.
        image_size (tuple[int, int]): (width, height) of the images input, pixels (the largest camera's
            behind virtual cameras).
        camera_sizes (tuple[tuple[int, int], ...]): (width, height) of each camera's images, in camera order.
        colour_order (str): ``"BGR"`` or ``"RGB"``: the channel order decoded arrays must have.
        num_boxes (int): Boxes the graph returns per frame, before the validity mask.
        rig (Rig): The camera rig baked into the file.
        providers (tuple[str, ...]): The ONNX Runtime execution providers the session got, in priority order.
        meta (ArtifactMeta): The file's full metadata
            ([`ArtifactMeta`][fisheye_infer.runtime.artifact.ArtifactMeta]).
    """

    architecture: str
    model_id: str
    classes: tuple[str, ...]
    cameras: tuple[str, ...]
    image_size: tuple[int, int]  # (width, height) of the images input (the largest camera's behind virtual cameras)
    camera_sizes: tuple[tuple[int, int], ...]  # (width, height) of each camera's images, in camera order
    colour_order: str
    num_boxes: int
    rig: Rig
    providers: tuple[str, ...]
    meta: ArtifactMeta


def check_interface(
    inputs: Mapping[str, Sequence[object]], outputs: Sequence[str], meta: ArtifactMeta, source: str
) -> None:
    """Refuse a graph (local or served) whose inputs and outputs are not the fisheye-infer interface.

    ``inputs`` maps input name -> shape with the batch axis first; the images input must be
    ``(B, N, H, W, 3)`` for the metadata's cameras and image size.
    """
    if set(inputs) != {INPUT_IMAGES, INPUT_CAMERA_VALID} or list(outputs) != list(OUTPUTS):
        raise ArtifactError(
            f"{source}: graph inputs {sorted(inputs)} / outputs {list(outputs)} are not the fisheye-infer interface"
        )
    shape = list(inputs[INPUT_IMAGES])
    width, height = meta.image_size
    if shape[1:] != [len(meta.cameras), height, width, 3]:
        raise ArtifactError(
            f"{source}: images input is {shape}, metadata says (B, {len(meta.cameras)}, {height}, {width}, 3)"
        )


def check_output_shapes(outputs: Mapping[str, Sequence[object]], meta: ArtifactMeta, source: str) -> None:
    """Refuse metadata that its graph's static output shapes (batch axis first) contradict."""
    for name, shape in outputs.items():
        boxes = shape[1] if len(shape) > 1 else None
        if isinstance(boxes, int) and boxes > 0 and boxes != meta.num_boxes:
            raise ArtifactError(
                f"{source}: num_boxes: metadata says {meta.num_boxes}, the graph's '{name}' output has {boxes}"
            )
        if (
            name == "boxes"
            and shape
            and isinstance(shape[-1], int)
            and shape[-1] > 0
            and shape[-1] != len(meta.box_layout)
        ):
            raise ArtifactError(
                f"{source}: box_layout: metadata names {len(meta.box_layout)} values per box, "
                f"the graph's 'boxes' output has {shape[-1]}"
            )


def describe(meta: ArtifactMeta, providers: Sequence[str]) -> DetectorInfo:
    return DetectorInfo(
        architecture=meta.architecture,
        model_id=meta.model_id,
        classes=meta.classes,
        cameras=meta.cameras,
        image_size=meta.image_size,
        camera_sizes=meta.camera_sizes(),
        colour_order=meta.colour_order,
        num_boxes=meta.num_boxes,
        rig=meta.rig,
        providers=tuple(providers),
        meta=meta,
    )


def _check_model_path(model_path: object) -> Path:
    """The model file's path; anything but a str or ``os.PathLike`` naming an existing file is refused."""
    if not isinstance(model_path, str | os.PathLike):
        raise OptionError(
            f"model_path: expected the path of an ONNX file (str or os.PathLike), got {type(model_path).__name__}"
        )
    path = Path(model_path)
    try:
        exists = path.exists()
    except (OSError, ValueError) as exc:  # a NUL byte, a name too long
        raise OptionError(f"model_path: {str(path)[:200]!r} cannot name a file ({exc})") from None
    if not exists:
        raise ArtifactError(f"model {path}: no such file")
    if not path.is_file():
        raise ArtifactError(f"model {path}: is a folder or device, not an ONNX file")
    return path


class FrameDetector:
    """Frames in, ``Detections`` out, around one graph run; subclasses say where the graph runs.

    ``Detector`` runs it in-process with ONNX Runtime; ``fisheye_infer.deploy.triton.TritonDetector``
    sends the same prepared tensors to a Triton (KServe v2) server. Decoding, validation,
    stacking and post-processing live here once, so every runtime returns the same boxes.
    """

    info: DetectorInfo

    def __init__(
        self,
        info: DetectorInfo,
        *,
        score_threshold: float | None = None,
        nms: NmsConfig | str | None = None,
        decode_threads: int | None = None,
    ) -> None:
        self.info = info
        self.score_threshold = check_score_threshold(score_threshold)
        self.nms = check_nms(nms)
        self.ready = False
        decode_threads = check_threads(decode_threads, "decode_threads")
        # Encoded images are decoded in parallel: decoding four PNGs one after another takes longer
        # than the whole graph run on a GPU. Threads start on first use; callers share them.
        self._decoder = ThreadPoolExecutor(
            max_workers=decode_threads or usable_cpus(), thread_name_prefix="fisheye-decode"
        )

    def map_images(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        """Apply ``fn`` to ``items`` on the Detector's decode threads.

        Called from a decode thread, or once the interpreter is shutting down (no new threads then), it
        runs in the calling thread.

        Args:
            fn (Callable[[Any], Any]): The function to apply (e.g. an image decoder).
            items (Iterable[Any]): Its arguments.

        Returns:
            Iterator[Any]: The results in the order of ``items``; iterating re-raises the first error.
        """
        if getattr(_decoding, "active", False):
            return map(fn, items)

        def run(item: Any) -> Any:
            _decoding.active = True
            try:
                return fn(item)
            finally:
                _decoding.active = False

        try:
            return self._decoder.map(run, items)
        except RuntimeError:  # "cannot schedule new futures after interpreter shutdown"
            return map(fn, items)

    def warmup(self) -> None:
        """One run on a black frame, so the first real call does not pay for allocation.

        Raises:
            ArtifactError: The graph's outputs contradict the file's metadata (box count, class list).
            InferenceError: The runtime failed running the graph.
        """
        width, height = self.info.image_size
        images = np.zeros((1, len(self.info.cameras), height, width, 3), np.uint8)
        self._checked_run(images, np.ones((1, len(self.info.cameras)), bool))
        self.ready = True

    # -- running ---------------------------------------------------------------------------

    def _run(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        """The graph's outputs (boxes, scores, labels, valid) for ``(B, N, H, W, 3)`` uint8 and ``(B, N)`` bool."""
        raise NotImplementedError

    def _checked_run(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        outputs = self._run(images, valid)
        self._check_outputs(outputs)
        return outputs

    def _check_outputs(self, outputs: list[np.ndarray]) -> None:
        """What only a run shows: the box count of dynamic shapes, and labels within the class list."""
        boxes, _, labels, _ = outputs
        source = f"model {self.info.model_id}"
        if boxes.shape[1] != self.info.num_boxes:
            raise ArtifactError(
                f"{source}: num_boxes: metadata says {self.info.num_boxes}, "
                f"the graph returned {boxes.shape[1]} boxes per frame"
            )
        if labels.size and (labels.min() < 0 or labels.max() >= len(self.info.classes)):
            raise ArtifactError(
                f"{source}: classes: metadata lists {len(self.info.classes)} ({', '.join(self.info.classes)}), "
                "the graph returned label "
                f"{int(labels.max() if labels.max() >= len(self.info.classes) else labels.min())}; "
                "the file's metadata does not match its graph"
            )

    def run_arrays(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        """The raw graph outputs for a prepared batch, without decoding or post-processing.

        Args:
            images (np.ndarray): `(B, N, H, W, 3)` uint8 images, N cameras in ``info.cameras`` order,
                channels in ``info.colour_order``.
            valid (np.ndarray): `(B, N)` bool, False for a camera without an image.

        Returns:
            list[np.ndarray]: ``boxes`` `(B, num_boxes, 7)`, ``scores`` `(B, num_boxes)`, ``labels``
                `(B, num_boxes)` and ``valid`` `(B, num_boxes)` (the official output set).

        Raises:
            ArtifactError: The outputs contradict the file's metadata.
            InferenceError: The runtime failed running the graph.
        """
        return self._checked_run(np.ascontiguousarray(images, np.uint8), np.ascontiguousarray(valid, bool))

    def detect(
        self,
        frame: Frame,
        *,
        score_threshold: float | None = None,
        classes: Iterable[str] | None = None,
        nms: NmsConfig | str | None = None,
    ) -> Detections:
        """Detect the boxes of one frame.

        Args:
            frame (Frame): Camera name -> image, or a sequence of images in ``info.cameras`` order. An image is
                a path, encoded bytes (PNG, JPEG) or an `(H, W, 3)` uint8 array in ``info.colour_order``;
                a camera that is left out or None runs in degraded mode.
            score_threshold (float | None): Keep boxes scoring at least this, in [0, 1]
                (default: the Detector's).
            classes (Iterable[str] | None): Keep boxes of these class names (default: all).
            nms (NmsConfig | str | None): Suppression for this call ([`NmsConfig`][fisheye_infer.runtime.nms.NmsConfig],
                or ``"rotated"``/``"circle"`` with defaults; default: the Detector's).

        Returns:
            Detections: The frame's boxes with the cameras used and the stage timings.

        Raises:
            FrameError: An image is missing, unreadable or of the wrong size (camera named).
            OptionError: An option has the wrong type or is out of range.
            InferenceError: The runtime failed running the graph.
        """
        return self.detect_batch([frame], score_threshold=score_threshold, classes=classes, nms=nms)[0]

    def detect_batch(
        self,
        frames: Iterable[Frame],
        *,
        score_threshold: float | None = None,
        classes: Iterable[str] | None = None,
        nms: NmsConfig | str | None = None,
    ) -> list[Detections]:
        """Detect the boxes of several frames, run through the graph as one batch.

        Args:
            frames (Iterable[Frame]): A list (or any iterable, such as a generator) of frames as
                [`detect`][fisheye_infer.runtime.detector.Detector.detect] takes them.
            score_threshold (float | None): As for ``detect``.
            classes (Iterable[str] | None): As for ``detect``.
            nms (NmsConfig | str | None): As for ``detect``.

        Returns:
            list[Detections]: One per frame, in order; each carries the batch's stage timings.

        Raises:
            FrameError: ``frames`` is empty or a single frame, or one of its images is unusable.
            OptionError: An option has the wrong type or is out of range.
            InferenceError: The runtime failed running the graph.
        """
        score_threshold = check_score_threshold(score_threshold)
        classes = check_classes(classes, self.info.classes)
        nms = check_nms(nms)
        if isinstance(frames, (Mapping, str, bytes, np.ndarray)) or not isinstance(frames, Iterable):
            raise FrameError(
                f"frames: expected a list (or other iterable) of frames, got {type(frames).__name__}; "
                "for one frame use detect()"
            )
        frames = frames if isinstance(frames, Sequence) else list(frames)
        if len(frames) == 0:
            raise FrameError("frames: expected a non-empty sequence of frames")
        t0 = time.perf_counter()
        loaded = load_frames(
            frames, self.info.cameras, self.info.image_size, self.map_images, camera_sizes=self.info.camera_sizes
        )
        t1 = time.perf_counter()
        images, valid = stack_frames(loaded, self.info.image_size)
        t2 = time.perf_counter()
        outputs = self._checked_run(images, valid)
        t3 = time.perf_counter()
        results = [self._postprocess(outputs, b, valid[b], score_threshold, classes, nms) for b in range(len(frames))]
        t4 = time.perf_counter()
        timings = {
            "decode": (t1 - t0) * 1e3,
            "preprocess": (t2 - t1) * 1e3,
            "inference": (t3 - t2) * 1e3,
            "postprocess": (t4 - t3) * 1e3,
        }
        for r in results:
            r.timings_ms.update(timings)
        return results

    def _postprocess(
        self,
        outputs: list[np.ndarray],
        b: int,
        valid_cameras: np.ndarray,
        score_threshold: float | None,
        classes: Iterable[str] | None,
        nms: NmsConfig | None,
    ) -> Detections:
        boxes, scores, labels, keep = (o[b] for o in outputs)
        used = tuple(c for c, ok in zip(self.info.cameras, valid_cameras) if ok)
        dets = Detections(
            boxes[keep], scores[keep], labels[keep].astype(np.int64), self.info.classes, used, {}, self.info.model_id
        )
        threshold = self.score_threshold if score_threshold is None else score_threshold
        if threshold is not None or classes is not None:
            dets = dets.filter(min_score=threshold, classes=classes)
        config = nms if nms is not None else self.nms
        return dets.with_nms(config) if config is not None else dets


class Detector(FrameDetector):
    """Runs an exported fisheye detector in ONNX Runtime: frames in, boxes out.

    The default result is exactly the official test-time output set: every box whose centre lies in the
    model's ``post_center_range``, no score threshold, no NMS; thresholds, class filters and NMS are
    opt-in, per Detector or per call. One Detector may be shared by threads. Every argument is checked
    before any work, and a bad one refused naming it.

    Args:
        model_path (str | os.PathLike): an ONNX file written by ``fisheye-infer export``.
        threads (int | None): ONNX Runtime's intra-op threads, a whole number from 1 to
            ``THREADS_PER_CPU`` (4) x the CPUs this process may use (default: those CPUs).
        providers (str | Sequence[str | tuple[str, dict]] | None): ``"auto"``, a provider name, or a
            list of names or (name, options) pairs (default: the CPU).
        score_threshold (float | None): keep boxes scoring at least this, in [0, 1].
        nms (NmsConfig | str | None): NMS after the graph, or ``"rotated"``/``"circle"`` with defaults.
        warmup (bool): one run on a black frame at construction.
        decode_threads (int | None): threads decoding encoded images, bounded as ``threads``.
        spin (bool): ``False``: the intra-op threads sleep as soon as a call ends instead of
            spinning for a while first (``session_options``), for cores shared with other processes.

    Attributes:
        info (DetectorInfo): What the model expects and returns
            ([`DetectorInfo`][fisheye_infer.runtime.detector.DetectorInfo]).
        path (Path): The model file.

    Raises:
        OptionError: An option has the wrong type or is out of range.
        ConfigError: ``providers`` names an unknown or unavailable provider.
        ArtifactError: The file is missing, not a model, or its metadata or graph is not the
            fisheye-infer interface.

    Examples:
        ```python
        from fisheye_infer import Detector

        detector = Detector("model.onnx", threads=2, score_threshold=0.3)
        print(detector.info.cameras, detector.info.classes)
        dets = detector.detect({"fisheye_camera_front": "front.png", "fisheye_camera_left": "left.png",
                                "fisheye_camera_right": "right.png", "fisheye_camera_rear": "rear.png"})
        batch = detector.detect_batch([frame_a, frame_b], nms="rotated")
        ```
    """

    def __init__(
        self,
        model_path: str | Path,
        *,
        threads: int | None = None,
        providers: str | Sequence[Provider] | None = None,
        score_threshold: float | None = None,
        nms: NmsConfig | str | None = None,
        warmup: bool = True,
        decode_threads: int | None = None,
        spin: bool = True,
    ) -> None:
        check_score_threshold(score_threshold)  # bad options are named before the session is built
        check_nms(nms)
        threads = check_threads(threads)
        check_threads(decode_threads, "decode_threads")
        resolve_providers(providers)
        for flag, value in (("warmup", warmup), ("spin", spin)):
            if not isinstance(value, bool):  # "false" would be truthy
                raise OptionError(f"{flag}: expected True or False, got {type(value).__name__} {repr(value)[:40]}")
        self.path = _check_model_path(model_path)
        self._session = create_session(self.path, threads=threads, providers=providers, spin=spin)
        meta = parse_meta(
            self._session.get_modelmeta().custom_metadata_map.get(METADATA_KEY), source=f"model {self.path}"
        )
        check_interface(
            {i.name: i.shape for i in self._session.get_inputs()},
            [o.name for o in self._session.get_outputs()],
            meta,
            f"model {self.path}",
        )
        check_output_shapes({o.name: o.shape for o in self._session.get_outputs()}, meta, f"model {self.path}")
        super().__init__(
            describe(meta, self._session.get_providers()),
            score_threshold=score_threshold,
            nms=nms,
            decode_threads=decode_threads,
        )
        if meta.quantization is not None and (
            saturation := int8_saturation_warning(meta, self._session.get_providers(), cpu_info())
        ):
            log.warning(saturation)
        if warmup:
            self.warmup()

    def _run(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        with map_ort_errors(f"model {self.path.name}"):
            return self._session.run(list(OUTPUTS), {INPUT_IMAGES: images, INPUT_CAMERA_VALID: valid})
