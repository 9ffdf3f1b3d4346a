"""``FrameDetector``: frames in, ``Detections`` out, around one graph run that a subclass supplies.

Decoding (on a shared pool of threads), the checks of frames and options, stacking, the checks of the
graph's outputs against the file's metadata, and post-processing live here once, so that ``Detector``
(ONNX Runtime) and ``TritonDetector`` (a Triton server) return the same boxes.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np

from fisheye_infer.errors import ArtifactError, FrameError
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector_interface import DetectorInfo
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.runtime.options import check_classes, check_nms, check_score_threshold
from fisheye_infer.runtime.preprocess import Frame, load_frames, stack_frames
from fisheye_infer.runtime.session import check_threads, usable_cpus

__all__ = ["FrameDetector"]

#: Set in a Detector's decode threads: ``map_images`` called from one runs in that thread (no nesting deadlock).
_decoding = threading.local()


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
