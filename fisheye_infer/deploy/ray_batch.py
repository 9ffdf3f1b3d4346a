"""Offline batch inference with Ray Data: frames on disk -> one nuScenes-style results file.

    fisheye-infer detect model.onnx --ray --data Fisheye3DODdataset --split val --out pred.json
    fisheye-infer eval --results pred.json --ground-truth gt.json --out report.json

    from fisheye_infer.deploy.ray_batch import BatchOptions, dataset_frames, detect_frames
    result = detect_frames("model.onnx", dataset_frames(Fisheye3DOD(root, "val")), BatchOptions(concurrency=2))
    result.save("pred.json")

The frames (sample token -> one image path per camera) become a Ray Dataset; ``map_batches``
runs them through ``DetectorActor``, a stateful class that loads one ``Detector`` per actor and
keeps it for every batch it is given. Each actor decodes its frames itself with the runtime's
own ``load_frame`` (decoding is about 1% of a frame's time), so no CPU is held by a separate
decode stage that the actors could starve. The answers are the Detector's unthresholded output,
as ``Detections.to_nuscenes()`` records, so the file is what ``fisheye-infer eval --results``
reads and what a plain loop over ``Detector.detect`` gives.

A frame that cannot be read or run is never skipped silently: the actor catches its error and
returns it with the frame's token; the result names every failed token with the reason, the
results file lists them under ``meta.failed``, and ``fisheye-infer detect --ray`` exits 1. When
a batch fails in ONNX Runtime, its frames are retried one by one, so one bad frame costs only
itself. Ray itself is started by the caller (``ray.init``) or, if not, by Ray Data on first use.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.errors import FisheyeInferError

__all__ = ["BatchOptions", "BatchResult", "DetectorActor", "dataset_frames", "detect_frames", "NEEDS_RAY"]

NEEDS_RAY = "batch inference with Ray needs the ray extra: pip install 'fisheye-infer[ray]'"

FrameFiles = tuple[str, Mapping[str, str | Path]]  # (sample token, camera -> image path); absent cameras run degraded


@dataclass(frozen=True)
class BatchOptions:
    """How [`detect_frames`][fisheye_infer.deploy.ray_batch.detect_frames] spreads the work over Ray actors.

    Attributes:
        batch_size (int): Frames per ``detect_batch`` call and per Ray Data batch; at least 1.
        concurrency (int): Detector actors, each with its own ONNX Runtime session; at least 1.
        cpus_per_actor (float): CPUs Ray reserves for each actor; positive (fractions allowed).
        threads (int | None): ONNX Runtime intra-op threads per actor; None uses ``cpus_per_actor`` rounded down
            (at least 1).

    Raises:
        ValueError: A value is out of its range.
    """

    batch_size: int = 2
    concurrency: int = 1
    cpus_per_actor: float = 1.0
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.batch_size < 1:
            raise ValueError(f"batch_size: expected at least 1, got {self.batch_size}")
        if self.concurrency < 1:
            raise ValueError(f"concurrency: expected at least 1 actor, got {self.concurrency}")
        if not self.cpus_per_actor > 0:
            raise ValueError(f"cpus_per_actor: expected a positive number, got {self.cpus_per_actor}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads: expected a positive number, got {self.threads}")

    @property
    def actor_threads(self) -> int:
        """ONNX Runtime threads per actor: ``threads``, or ``cpus_per_actor`` rounded down (at least 1)."""
        return self.threads or max(1, int(self.cpus_per_actor))


@dataclass
class BatchResult:
    """What [`detect_frames`][fisheye_infer.deploy.ray_batch.detect_frames] returns: records, failures, timing.

    Attributes:
        results (dict[str, list[dict[str, Any]]]): Sample token -> that frame's boxes as nuScenes-style records
            (``Detections.to_nuscenes()``, unthresholded), in input order.
        failed (dict[str, str]): Sample token -> why that frame could not be read or run; empty when all ran.
        model_id (str): The exported file's ``model_id``.
        seconds (float): Wall time of the Ray Data run, in seconds.
        options (BatchOptions): The options the run used.
    """

    results: dict[str, list[dict[str, Any]]]
    failed: dict[str, str]
    model_id: str
    seconds: float
    options: BatchOptions = field(default_factory=BatchOptions)

    @property
    def frames_per_second(self) -> float:
        """Frames (run or failed) per second of wall time; 0.0 for an empty run."""
        return (len(self.results) + len(self.failed)) / self.seconds if self.seconds > 0 else 0.0

    def save(self, path: str | Path, meta: Mapping[str, Any] | None = None) -> Path:
        """Write the results file that ``fisheye-infer eval --results`` reads.

        The file is ``{"meta": {..., "failed": {token: reason}}, "results": {token: [record, ...]}}``; ``meta``
        holds ``model_id``, the frame count and the failed tokens.

        Args:
            path (str | Path): The JSON file to write.
            meta (Mapping[str, Any] | None): Further entries for the file's ``meta`` (they override the defaults).

        Returns:
            Path: The written file.
        """
        from fisheye_infer.eval.evaluate import save_results

        info = {
            "model_id": self.model_id,
            "frames": len(self.results) + len(self.failed),
            "failed": self.failed,
            **(meta or {}),
        }
        return save_results(path, self.results, info)


def dataset_frames(dataset: Any) -> list[FrameFiles]:
    """The frames of a Fisheye3DOD split, as [`detect_frames`][fisheye_infer.deploy.ray_batch.detect_frames] takes them.

    The image files are not opened here.

    Args:
        dataset (Fisheye3DOD): A split read by ``fisheye_infer.eval.dataset.Fisheye3DOD`` (anything with
            ``entries`` holding ``token`` and an ``image_paths(index)`` method).

    Returns:
        One ``(sample token, {camera name: image path})`` pair per sample, in the split's order.
    """
    return [(entry.token, dataset.image_paths(i)) for i, entry in enumerate(dataset.entries)]


class DetectorActor:
    """The stateful ``map_batches`` class: one Detector per actor, frames in, records (or errors) out."""

    def __init__(self, model: str, threads: int) -> None:
        from fisheye_infer.runtime.detector import Detector

        self.detector = Detector(model, threads=threads)

    def _one(self, files: Mapping[str, str]) -> list[Any]:
        from fisheye_infer.runtime.preprocess import load_frame

        info = self.detector.info
        return load_frame(files, info.cameras, info.image_size, info.camera_sizes)

    def __call__(self, batch: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        tokens = [str(t) for t in batch["token"]]
        records, errors = [""] * len(tokens), [""] * len(tokens)
        loaded: dict[int, list[Any]] = {}
        for i, files in enumerate(batch["files"]):
            try:
                loaded[i] = self._one(json.loads(str(files)))
            except FisheyeInferError as exc:
                errors[i] = str(exc)
        order = sorted(loaded)
        try:
            results = dict(zip(order, self.detector.detect_batch([loaded[i] for i in order]))) if order else {}
        except FisheyeInferError:  # find the frame that fails, run the others
            results = {}
            for i in order:
                try:
                    results[i] = self.detector.detect(loaded[i])
                except FisheyeInferError as exc:
                    errors[i] = str(exc)
        for i, dets in results.items():
            records[i] = json.dumps(dets.to_nuscenes())
        return {
            "index": batch["index"],
            "token": batch["token"],
            "records": np.array(records, dtype=object),
            "error": np.array(errors, dtype=object),
        }


def _check(frames: Sequence[FrameFiles]) -> None:
    seen: set[str] = set()
    for token, files in frames:
        if token in seen:
            raise ValueError(f"frames: token {token!r} appears twice; each sample needs its own token")
        seen.add(token)
        if not files:
            raise ValueError(f"frames: token {token!r} has no image paths")


def detect_frames(
    model: str | Path,
    frames: Sequence[FrameFiles],
    options: BatchOptions | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> BatchResult:
    """Run an exported file over frames on disk with Ray Data, one ``Detector`` per actor.

    Each actor decodes its own frames. A frame that cannot be read or run is not skipped: it is listed in the
    result's ``failed`` with the reason (a batch that fails is retried frame by frame, so one bad frame costs only
    itself). Ray is started by the caller (``ray.init``) or, if not, by Ray Data on first use.

    Args:
        model (str | Path): An ONNX file written by ``fisheye-infer export``; it must be readable on every node.
        frames (Sequence[tuple[str, Mapping[str, str | Path]]]): ``(sample token, {camera name: image path})``
            pairs, each token once; cameras left out run degraded.
        options (BatchOptions | None): Batch size, actors and CPUs; None for ``BatchOptions()``.
        progress (Callable[[int, int], None] | None): Called as ``progress(done, total)`` each time a frame
            finishes; None for no progress reports.

    Returns:
        BatchResult: The records per sample token in input order, the failed tokens with their reasons, the
            model's id and the run's wall time.

    Raises:
        ImportError: Ray is not installed (the ``[ray]`` extra).
        ValueError: A token appears twice, or a frame has no image paths.
        ArtifactError: ``model`` is missing or not a fisheye-infer model (raised before any actor starts).
        RuntimeError: Ray Data returned no answer for some frames.

    Examples:
        ```python
        from fisheye_infer.deploy.ray_batch import BatchOptions, dataset_frames, detect_frames
        from fisheye_infer.eval.dataset import Fisheye3DOD

        frames = dataset_frames(Fisheye3DOD("Fisheye3DODdataset", "val"))
        result = detect_frames("model.onnx", frames, BatchOptions(batch_size=2, concurrency=2))
        result.save("pred.json")  # fisheye-infer eval --results pred.json ...
        print(f"{result.frames_per_second:.1f} frames/s, {len(result.failed)} failed")
        ```
    """
    try:
        import ray
        import ray.data
    except ImportError as exc:
        raise ImportError(f"{NEEDS_RAY} ({exc})") from exc
    from fisheye_infer.runtime.artifact import read_meta

    options = options or BatchOptions()
    _check(frames)
    meta = read_meta(model)  # a missing or foreign file fails here, before any actor starts
    if not frames:
        return BatchResult({}, {}, meta.model_id, 0.0, options)
    ray.data.DataContext.get_current().enable_progress_bars = False  # the caller's progress line instead
    rows = [
        {"index": i, "token": token, "files": json.dumps({c: str(Path(p).resolve()) for c, p in files.items()})}
        for i, (token, files) in enumerate(frames)
    ]
    t0 = time.perf_counter()
    dataset = ray.data.from_items(rows, override_num_blocks=math.ceil(len(rows) / options.batch_size)).map_batches(
        DetectorActor,
        batch_size=options.batch_size,
        batch_format="numpy",
        fn_constructor_kwargs={"model": str(Path(model).resolve()), "threads": options.actor_threads},
        compute=ray.data.ActorPoolStrategy(size=options.concurrency),
        num_cpus=options.cpus_per_actor,
    )
    records: dict[int, list[dict[str, Any]]] = {}
    failed: dict[int, str] = {}
    for done, row in enumerate(dataset.iter_rows(), start=1):
        index = int(row["index"])
        if row["error"]:
            failed[index] = str(row["error"])
        else:
            records[index] = json.loads(row["records"])
        if progress is not None:
            progress(done, len(rows))
    seconds = time.perf_counter() - t0
    lost = [frames[i][0] for i in range(len(frames)) if i not in records and i not in failed]
    if lost:  # Ray Data returns every row or raises; this guards the promise that nothing is skipped
        raise RuntimeError(f"frames: no answer for {', '.join(lost[:5])}{' ...' if len(lost) > 5 else ''}")
    return BatchResult(
        {frames[i][0]: records[i] for i in sorted(records)},
        {frames[i][0]: failed[i] for i in sorted(failed)},
        meta.model_id,
        seconds,
        options,
    )
