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
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fisheye_infer.errors import ArtifactError, OptionError
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, METADATA_KEY, OUTPUTS, parse_meta
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.detector_interface import DetectorInfo, check_interface, check_output_shapes, describe
from fisheye_infer.runtime.frame_detector import FrameDetector
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.runtime.options import check_nms, check_score_threshold
from fisheye_infer.runtime.session import (
    Provider,
    check_threads,
    create_session,
    log,
    map_ort_errors,
    resolve_providers,
)
from fisheye_infer.tools.cpu import cpu_info, int8_saturation_warning

__all__ = ["Detector", "DetectorInfo", "FrameDetector", "check_interface", "check_output_shapes", "describe"]


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
            ([`DetectorInfo`][fisheye_infer.runtime.detector_interface.DetectorInfo]).
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
        with map_ort_errors(f"model {self.path.name}"), flushed_denormals():
            return self._session.run(list(OUTPUTS), {INPUT_IMAGES: images, INPUT_CAMERA_VALID: valid})
