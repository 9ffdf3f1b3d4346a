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
    """How the work is spread.

    | option | default | meaning |
    |---|---|---|
    | ``batch_size`` | 2 | frames per ``detect_batch`` call (and per Ray Data batch) |
    | ``concurrency`` | 1 | Detector actors, each with its own ONNX Runtime session |
    | ``cpus_per_actor`` | 1.0 | CPUs Ray reserves for each actor |
    | ``threads`` | ``cpus_per_actor`` | ONNX Runtime intra-op threads per actor |
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
        return self.threads or max(1, int(self.cpus_per_actor))


@dataclass
class BatchResult:
    """Records per sample token (input order), the failed tokens with their reasons, and how it went."""

    results: dict[str, list[dict[str, Any]]]
    failed: dict[str, str]
    model_id: str
    seconds: float
    options: BatchOptions = field(default_factory=BatchOptions)

    @property
    def frames_per_second(self) -> float:
        return (len(self.results) + len(self.failed)) / self.seconds if self.seconds > 0 else 0.0

    def save(self, path: str | Path, meta: Mapping[str, Any] | None = None) -> Path:
        """``{"meta": {..., "failed": {token: reason}}, "results": {token: [record, ...]}}``, as
        ``eval --results`` reads."""
        from fisheye_infer.eval.evaluate import save_results

        info = {
            "model_id": self.model_id,
            "frames": len(self.results) + len(self.failed),
            "failed": self.failed,
            **(meta or {}),
        }
        return save_results(path, self.results, info)


def dataset_frames(dataset: Any) -> list[FrameFiles]:
    """The frames of a ``Fisheye3DOD`` split: (sample token, camera -> PNG path); files are not opened here."""
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
    """Run ``model`` over ``frames`` with Ray Data; ``progress(done, total)`` is called as frames finish."""
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
