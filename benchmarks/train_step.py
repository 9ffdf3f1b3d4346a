"""Seconds per training step of the compact configurations on this machine, and steps per 3 hours.

    python benchmarks/train_step.py [--threads 1] [--steps 8] [--cases compact-b1,compact-b2,...] [--quick]

Each case builds a fresh ``Trainer`` (in a temporary run folder) and times ``--steps`` optimiser
steps (frame rendering, forward, losses with the assignment, backward, AdamW); the first step
allocates and is left out. Cases:

    compact-b1, compact-b2   the compact configuration (320 x 320), batch 1 / 2
    compact-jitter-b2        the compact configuration, batch 2, with ``--lens-jitter 4`` (each step's frames
                             rendered through moved lenses, their warp tables computed)
    compact480-b2            the compact configuration at 480 x 480 (rig x 0.6, 15 x 60 angular grid), batch 2
    official-b1              the official full-size configuration (800 x 800), batch 1
    pinhole-b2, persp-b2, cyl-b2
                             the compact BEVDet baselines (``--arch pinhole-bevdet``, ``fisheye-bevdet-persp``,
                             ``fisheye-bevdet-cyl``), batch 2
    petr-b2, pinhole-petr-b2, persp-petr-b2, cyl-petr-b2
                             the compact FisheyePETR and PETR baselines with the backbone frozen, as their
                             recipe trains them (``--freeze-backbone``), batch 2
    petr-q900-b2             the compact FisheyePETR with the official 900 queries, frozen backbone, batch 2
    petr-jitter-b2           the compact FisheyePETR, frozen backbone, batch 2, with ``--lens-jitter 4``
    petr-explicit-b2, petr-q900-explicit-b2
                             those two with the decoder's attention trained through the explicit graph the
                             export writes instead of PyTorch's fused kernel (what the fused kernel saves)

Each row carries the load average, since figures on a shared machine move with it.
"""

from __future__ import annotations

import os
import sys
import tempfile
from typing import Any

import harness
import torch

from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.models import BEVDetConfig
from fisheye_infer.models.petr_transformer import MultiheadAttention
from fisheye_infer.models.training.compact import COMPACT_SECTIONS, compact_bevdet_config, compact_rig, compact_setup
from fisheye_infer.models.training.loop import Trainer
from fisheye_infer.models.training.options import TrainOptions
from fisheye_infer.scenes.render import resized_rig

BUDGET_S = 3 * 3600


def _compact_at(side: int, feature_size: tuple[int, int]) -> tuple[BEVDetConfig, Rig]:
    sections: dict[str, Any] = {k: dict(v) for k, v in COMPACT_SECTIONS.items()}
    sections["image"] = {"height": side, "width": side}
    sections["view_transform"]["feature_size"] = feature_size
    return BEVDetConfig().replace(**sections), resized_rig(default_rig(), side / 800)


def cases() -> dict[str, tuple[Any, Rig, TrainOptions]]:
    """Case -> configuration, rig and options (a frozen backbone times the same whatever its weights)."""
    two, frozen = TrainOptions(batch_size=2), TrainOptions(batch_size=2, freeze_backbone=True)
    petr, petr_rig = compact_setup("fisheye-petr")
    petr_q900 = petr.replace(head={"num_query": 900})
    return {
        "compact-b1": (compact_bevdet_config(), compact_rig(), TrainOptions(batch_size=1)),
        "compact-b2": (compact_bevdet_config(), compact_rig(), two),
        "compact-jitter-b2": (compact_bevdet_config(), compact_rig(), TrainOptions(batch_size=2, lens_jitter=4.0)),
        "compact480-b2": (*_compact_at(480, (15, 60)), two),
        "official-b1": (BEVDetConfig(), default_rig(), TrainOptions(batch_size=1)),
        "pinhole-b2": (*compact_setup("pinhole-bevdet"), two),
        "persp-b2": (*compact_setup("fisheye-bevdet-persp"), two),
        "cyl-b2": (*compact_setup("fisheye-bevdet-cyl"), two),
        "petr-b2": (petr, petr_rig, frozen),
        "petr-explicit-b2": (petr, petr_rig, frozen),
        "petr-q900-b2": (petr_q900, petr_rig, frozen),
        "petr-jitter-b2": (petr, petr_rig, TrainOptions(batch_size=2, freeze_backbone=True, lens_jitter=4.0)),
        "petr-q900-explicit-b2": (petr_q900, petr_rig, frozen),
        "pinhole-petr-b2": (*compact_setup("pinhole-petr"), frozen),
        "persp-petr-b2": (*compact_setup("fisheye-petr-persp"), frozen),
        "cyl-petr-b2": (*compact_setup("fisheye-petr-cyl"), frozen),
    }


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="compact-b1 only, 4 steps")
    bench.parser.add_argument("--threads", type=int, default=1)
    bench.parser.add_argument("--steps", type=int, default=8)
    bench.parser.add_argument("--cases", default="compact-b1,compact-b2,compact480-b2,official-b1")
    args = bench.parse(argv)
    if args.quick:
        args.cases, args.steps = "compact-b1", 4
    torch.set_num_threads(args.threads)
    table = cases()
    rows = []
    for name in args.cases.split(","):
        config, rig, options = table[name]
        MultiheadAttention.fused_in_training = "-explicit-" not in name
        with tempfile.TemporaryDirectory() as folder:
            trainer = Trainer(config, rig, folder, options)
            seconds = harness.Stats(tuple(trainer.train_step()["seconds"] for _ in range(max(args.steps, 2)))[1:])
        rows.append(
            {
                "case": name,
                "batch": options.batch_size,
                **seconds.row("s/step"),
                "steps in 3 h": BUDGET_S / seconds.median,
                "load average": os.getloadavg()[0],
            }
        )
    bench.save(args, {f"Training step, {args.threads} thread(s)": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
