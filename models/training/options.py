"""What a training run is made of: its options, the learning-rate schedule and the device it trains on.

Everything here is checked before a step runs, so a run that would fail on a bad option fails at
once, with the command-line flag named, rather than after its first checkpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from fisheye_infer.errors import ConfigError

__all__ = ["MAX_LENS_JITTER", "TrainOptions", "lr_factor", "training_device"]

#: Pixels a lens centre may move under ``--lens-jitter``: calibrations of one lens design differ by a few.
MAX_LENS_JITTER = 32.0


@dataclass(frozen=True)
class TrainOptions:
    """What a run is made of; all of it is stored in the checkpoint and, but ``steps`` and ``init``,
    must match on ``--resume``.

    ``steps`` may change on resume, down to the step reached (a run can be continued further, or
    ended sooner; the cosine then stretches or shrinks to the new end from the step it resumes at);
    ``init`` is the run's own. ``depth_weight`` weighs the
    depth loss against the synthetic frames' true ray depths (``depth.py``; 0 trains with the
    official losses alone). ``init`` starts from the weights of a checkpoint (one ``model.pth`` of
    a run, with this configuration and rig, or with fewer queries: a FisheyePETR grows its query set,
    the checkpoint's queries first) instead of the seeded initialiser: a fine-tuning run, with its
    own optimiser, warm-up and schedule. ``qat`` is the share of steps whose forward
    rounds as the int8 file will (``qat.FakeQuant``; which steps is seeded): 0 trains the float
    model alone, 1 the int8 simulation alone, between the two both (the shipped model's model card
    says what 0.5 changed). ``init_backbone`` starts only the image backbone and neck from a
    checkpoint (of any architecture with the same backbone section, e.g. a trained FisheyeBEVDet
    for a FisheyePETR): the stand-in for the official ImageNet weights; ``init`` takes precedence.
    ``freeze_backbone`` keeps the image backbone and neck as they start (weights and BatchNorm
    statistics), so a step skips their backward: about half of a compact FisheyePETR step's time.
    ``lens_jitter`` moves each camera's lens centre at random within that many pixels every step, with
    the frames and the lenses' tables to match (``lens_jitter.py``; FisheyeBEVDet and FisheyePETR): 0 trains on
    the rig's lenses.
    """

    steps: int = 8000
    batch_size: int = 2
    lr: float = 2e-4
    weight_decay: float = 0.01
    grad_clip: float = 35.0
    warmup_steps: int = 500
    seed: int = 0
    checkpoint_every: int = 100
    val_frames: int = 4
    depth_weight: float = 3.0
    init: str = ""
    qat: float = 0.0
    init_backbone: str = ""
    freeze_backbone: bool = False
    lens_jitter: float = 0.0

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "checkpoint_every"):
            if getattr(self, name) < 1:
                raise ConfigError(f"--{name.replace('_', '-')}: expected at least 1, got {getattr(self, name)}")
        if not self.lr > 0:
            raise ConfigError(f"--lr: expected a positive learning rate, got {self.lr}")
        if not self.depth_weight >= 0:
            raise ConfigError(f"--depth-weight: expected 0 or more, got {self.depth_weight}")
        if not 0 <= self.lens_jitter <= MAX_LENS_JITTER:
            raise ConfigError(
                f"--lens-jitter: expected 0 to {MAX_LENS_JITTER:g} pixels of lens-centre movement, "
                f"got {self.lens_jitter}"
            )
        if not 0 <= self.qat <= 1:
            raise ConfigError(f"--qat: expected a share of steps in [0, 1], got {self.qat}")
        if self.val_frames < 0 or self.warmup_steps < 0:
            raise ConfigError(
                f"--val-frames / warm-up steps: expected 0 or more, got {self.val_frames} / {self.warmup_steps}"
            )


def lr_factor(step: int, total: int, warmup: int, start: float = 1 / 3, floor: float = 2e-4) -> float:
    """Learning-rate multiplier at ``step`` (0-based): linear warm-up from ``start``, times a cosine from 1
    to ``floor``."""
    warm = start + (1 - start) * min(step, warmup) / warmup if warmup else 1.0
    progress = min(step / max(total, 1), 1.0)
    return warm * (floor + (1 - floor) * 0.5 * (1 + math.cos(math.pi * progress)))


def training_device(name: str) -> torch.device:
    """``name`` as a torch device this machine has; a ``ConfigError`` that says what is wrong otherwise."""
    try:
        device = torch.device(name)
    except RuntimeError as exc:
        raise ConfigError(f"--device {name!r}: not a torch device ({exc})") from None
    if device.type == "cuda" and (not torch.cuda.is_available() or (device.index or 0) >= torch.cuda.device_count()):
        raise ConfigError(
            f"--device {name}: no such CUDA device here (torch {torch.__version__} sees {torch.cuda.device_count()} "
            "GPU(s))"
        )
    if device.type not in ("cpu", "cuda"):
        raise ConfigError(f"--device {name}: expected cpu or cuda[:N]")
    return device
