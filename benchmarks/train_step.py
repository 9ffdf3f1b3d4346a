"""Seconds per training step of FisheyeBEVDet configurations on this machine, and steps per 3 hours.

    .venv/bin/python benchmarks/train_step.py [--threads 1] [--steps 8] [--cases compact-b1,compact-b2,...]

Each case builds a fresh ``Trainer`` (in a temporary run folder) and times ``--steps`` optimiser
steps (frame rendering, forward, losses with the assignment, backward, AdamW); the first step
allocates and is left out of the median. Cases:

    compact-b1, compact-b2   the compact configuration (320 x 320), batch 1 / 2
    compact480-b2            the compact configuration at 480 x 480 (rig x 0.6, 15 x 60 angular grid), batch 2
    official-b1              the official full-size configuration (800 x 800), batch 1

The load average is printed with each figure: on a shared machine the figures move with it.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
from typing import Any

import torch

from fisheye_infer.models import BEVDetConfig
from fisheye_infer.models.training.compact import COMPACT_SECTIONS, compact_bevdet_config, compact_rig
from fisheye_infer.models.training.loop import Trainer, TrainOptions
from fisheye_infer.rig import Rig, default_rig
from fisheye_infer.synth import resized_rig

BUDGET_S = 3 * 3600


def _compact_at(side: int, feature_size: tuple[int, int]) -> tuple[BEVDetConfig, Rig]:
    sections: dict[str, Any] = {k: dict(v) for k, v in COMPACT_SECTIONS.items()}
    sections["image"] = {"height": side, "width": side}
    sections["view_transform"]["feature_size"] = feature_size
    return BEVDetConfig().replace(**sections), resized_rig(default_rig(), side / 800)


def cases() -> dict[str, tuple[BEVDetConfig, Rig, int]]:
    return {"compact-b1": (compact_bevdet_config(), compact_rig(), 1),
            "compact-b2": (compact_bevdet_config(), compact_rig(), 2),
            "compact480-b2": (*_compact_at(480, (15, 60)), 2),
            "official-b1": (BEVDetConfig(), default_rig(), 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=8)
    parser.add_argument("--cases", default="compact-b1,compact-b2,compact480-b2,official-b1")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    table = cases()
    print(f"{'case':<15} {'batch':>5} {'s/step':>7} {'min':>6} {'steps in 3 h':>13}  load")
    for name in args.cases.split(","):
        config, rig, batch = table[name]
        with tempfile.TemporaryDirectory() as folder:
            trainer = Trainer(config, rig, folder, TrainOptions(batch_size=batch))
            seconds = [trainer.train_step()["seconds"] for _ in range(max(args.steps, 2))][1:]
        median = statistics.median(seconds)
        print(f"{name:<15} {batch:>5} {median:>7.2f} {min(seconds):>6.2f} {BUDGET_S / median:>13,.0f}  {os.getloadavg()[0]:.1f}", flush=True)


if __name__ == "__main__":
    main()
