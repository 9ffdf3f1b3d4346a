"""What each training step trains on: step ``s`` -> frames ``s*B .. s*B+B-1`` and their depth targets.

A step's frames are a function of the step alone (seeded, rendered on demand), so resuming a run
continues with the frames the uninterrupted run would have used, and ``DataLoader`` workers can
render the next steps ahead of the loop without changing what any step sees. With lens-centre
jitter (``lens_jitter.py``) a step's lenses are a function of the step too.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch

from fisheye_infer.scenes.streams import Sample, SyntheticFrames

from .depth import DepthTargets
from .lens_jitter import LensJitter, StepLenses

__all__ = ["Batch", "StepBatches", "collate", "step_loader"]


class Batch(NamedTuple):
    """One step's frames, their depth targets (B*N x H x W bins; None for a model without a depth head) and,
    with lens-centre jitter, the lenses the frames were rendered through (else None)."""

    samples: list[Sample]
    depth: np.ndarray | None
    lenses: StepLenses | None = None


def collate(samples: list[Sample]) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Samples -> images B x N x H x W x 3 uint8, and per-frame boxes and labels."""
    return (np.stack([s.images for s in samples]), [s.boxes for s in samples], [s.labels for s in samples])


class StepBatches(torch.utils.data.Dataset[Batch]):
    """Step ``s`` -> frames ``s*B .. s*B+B-1`` of ``frames`` with their depth targets: what one step
    trains on, rendered where it is asked for (in the loop, or ahead in ``DataLoader`` workers); with
    ``jitter``, through the step's moved lenses."""

    def __init__(
        self,
        frames: SyntheticFrames,
        depth_targets: DepthTargets | None,
        batch_size: int,
        jitter: LensJitter | None = None,
    ) -> None:
        self.frames, self.depth_targets, self.batch_size, self.jitter = frames, depth_targets, batch_size, jitter

    def __getitem__(self, step: int) -> Batch:
        indices = range(step * self.batch_size, (step + 1) * self.batch_size)
        lenses = None if self.jitter is None else self.jitter(step)
        samples = [self.frames[i] if lenses is None else self.frames.frame(i, lenses.rig) for i in indices]
        if self.depth_targets is None:
            return Batch(samples, None, lenses)
        inside = None if lenses is None else lenses.inside_lens
        return Batch(samples, np.concatenate([self.depth_targets(s.scene, inside) for s in samples]), lenses)


def step_loader(batches: StepBatches, start: int, stop: int, workers: int) -> torch.utils.data.DataLoader[Batch]:
    """The batches of steps ``start`` .. ``stop - 1``, in order, rendered ahead by ``workers`` processes
    (0: rendered in the loop)."""
    workers = workers if stop > start else 0  # nothing left to render: no processes to start
    ahead: dict[str, Any] = (
        {"multiprocessing_context": "spawn", "prefetch_factor": 4, "worker_init_fn": _one_thread_worker}
        if workers
        else {}
    )
    # batch_size=None: collate_fn gets one item, not the list torch's annotation has it take
    return torch.utils.data.DataLoader(
        batches,
        batch_size=None,
        sampler=range(start, stop),
        num_workers=workers,
        collate_fn=_as_is,  # type: ignore[arg-type]
        **ahead,
    )


def _as_is(batch: Batch) -> Batch:
    """A batch is one step's already: nothing to collate."""
    return batch


def _one_thread_worker(_: int) -> None:
    import cv2

    cv2.setNumThreads(1)  # each worker renders one step; many workers, not many threads each
