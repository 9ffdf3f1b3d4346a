"""``fisheye-infer train``: train a FisheyeBEVDet, a FisheyePETR or a BEVDet baseline on synthetic frames (torch
is imported only when the command runs).

fisheye-infer train --out runs/compact [--until 1000] [--resume]
fisheye-infer train --arch fisheye-petr --out runs/petr --init-backbone runs/compact/model.pth
fisheye-infer train --arch pinhole-bevdet --out runs/pinhole
fisheye-infer train --arch fisheye-bevdet --rig my_rig.json --out runs/mine
fisheye-infer train --out runs/tuned --init runs/compact/model.pth --seed 1 --lr 5e-5 --steps 2500
fisheye-infer train --out runs/qat --init runs/compact/model.pth --qat 0.5 --device cuda --workers 7 --batch-size 8
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fisheye_infer.commands.common import NEEDS_EXPORT, ArchChoices, missing_extra

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig

__all__ = ["configure", "run", "ARCHITECTURES"]

#: ``--arch``: the trainable architectures, looked up when the value is checked so that the parser needs no torch.
ARCHITECTURES = ArchChoices(trainable=True)


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out", required=True, help="run folder: config.py, rig.json, model.pth, checkpoint.pth, log.jsonl"
    )
    parser.add_argument(
        "--arch",
        choices=ARCHITECTURES,
        default="fisheye-bevdet",
        help="the architecture to train in its compact configuration (default fisheye-bevdet; the BEVDet "
        "baselines of the paper's Table 2: pinhole-bevdet on the shipped six-camera pinhole rig, "
        "fisheye-bevdet-persp and fisheye-bevdet-cyl on rectified fisheye images); --config files name their own",
    )
    parser.add_argument("--config", help="mmdet3d-style config to train (default: the compact configuration of --arch)")
    parser.add_argument(
        "--rig",
        help="the rig to train for: with --config, as given (its image size the configuration's); without, "
        "a fisheye --arch in its compact configuration for this rig, its images scaled by 0.4 as the shipped "
        "rig's are (an OCam model per camera, images of one size; default: the shipped rig)",
    )
    parser.add_argument(
        "--cameras",
        help="comma-separated cameras of the rig to train on, in this order (default: all of them): a reduced "
        "layout trained as such, e.g. fisheye_camera_front,fisheye_camera_rear (the paper's Table 3 retrained)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help="continue the run in --out from its checkpoint.pth (config, rig and the options it was started with "
        "from the folder; an option given again must match, but --steps)",
    )
    parser.add_argument(
        "--steps",
        type=int,
        help="total optimiser steps (default 8000: the shipped model's first run, "
        "continued with --resume --steps 14000)",
    )
    parser.add_argument("--batch-size", type=int, help="frames per step (default 2)")
    parser.add_argument("--lr", type=float, help="peak learning rate of AdamW (default 2e-4)")
    parser.add_argument("--seed", type=int, help="seed of the weights and of the training frames (default 0)")
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="PyTorch threads (default 1: on a shared machine two spin-waiting threads can be ten times slower)",
    )
    parser.add_argument(
        "--until", type=int, help="stop after this step (checkpointed) and continue later with --resume"
    )
    parser.add_argument("--checkpoint-every", type=int, help="steps between checkpoints (default 100)")
    parser.add_argument("--val-frames", type=int, help="validation frames scored at each checkpoint (default 4)")
    parser.add_argument(
        "--depth-weight",
        type=float,
        help="the BEVDet family: weight of the depth loss against the frames' true ray depths "
        "(default 3, as BEVDepth; 0: the official losses alone); FisheyePETR has no depth head",
    )
    parser.add_argument(
        "--qat",
        type=float,
        help="share of steps whose forward rounds weights and activations as the int8 file will "
        "(quantization-aware training; default 0: float only)",
    )
    parser.add_argument(
        "--lens-jitter",
        type=float,
        help="fisheye-bevdet and fisheye-petr: move each camera's lens centre at random within this many pixels "
        "every step, frames and the lenses' tables to match, so the model serves other units of the lens "
        "(default 0: the rig's lenses)",
    )
    parser.add_argument("--device", default="cpu", help="where the model trains: cpu (default), cuda, cuda:1, ...")
    parser.add_argument(
        "--workers",
        type=int,
        default=0,
        help="processes rendering the next steps' frames while a step trains (default 0: rendered in the loop)",
    )
    parser.add_argument(
        "--init",
        help="start from this checkpoint's weights (a model.pth of the same configuration and rig, or of "
        "fewer queries: its queries come first, the others start seeded): a fine-tuning run with its own "
        "optimiser and schedule",
    )
    parser.add_argument(
        "--init-backbone",
        help="start the image backbone and neck from this checkpoint (any architecture with the same backbone, "
        "e.g. a trained compact FisheyeBEVDet for the compact FisheyePETR); the rest starts seeded",
    )
    parser.add_argument(
        "--freeze-backbone",
        action="store_true",
        default=None,
        help="keep the image backbone and neck as they start (from --init-backbone or --init): "
        "their weights and BatchNorm statistics; a step skips their backward",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        import torch

        from fisheye_infer.models.training.loop import Trainer, read_config_file, saved_options
        from fisheye_infer.models.training.options import TrainOptions
    except ImportError as exc:
        return missing_extra(NEEDS_EXPORT, exc)
    from fisheye_infer.cameras.rig import Rig, resolve_rig
    from fisheye_infer.errors import ConfigError
    from fisheye_infer.models.training.compact import compact_setup

    out = Path(args.out)
    if args.until is not None and args.until < 1:
        raise ConfigError(f"--until: expected a step of at least 1, got {args.until}")
    if args.threads < 1:
        raise ConfigError(f"--threads: expected at least 1, got {args.threads}")
    if args.resume:
        if args.init:
            raise ConfigError("--resume continues from the run folder's checkpoint.pth; leave out --init")
        if args.config or args.rig or args.cameras:
            raise ConfigError(
                "--resume takes the configuration and rig from the run folder; leave out --config, --rig and --cameras"
            )
        if not (out / "config.py").is_file() or not (out / "rig.json").is_file():
            raise ConfigError(f"--resume: {out} has no config.py and rig.json; is it a run folder?")
        config, rig = read_config_file(out / "config.py"), Rig.load(out / "rig.json")
    else:
        if (out / "checkpoint.pth").exists():
            raise ConfigError(
                f"--out {out} already holds a run; pass --resume to continue it, or choose another folder"
            )
        if args.config:
            if not args.rig:
                raise ConfigError("--config needs --rig: the rig whose cameras give the configuration's image size")
            config, rig = read_config_file(args.config), resolve_rig(args.rig)
        else:
            config, rig = compact_setup(args.arch, resolve_rig(args.rig) if args.rig else None)
        if args.cameras:
            config, rig = only_cameras(config, rig, args.cameras)
    given = {
        "steps": args.steps,
        "batch_size": args.batch_size,
        "lr": args.lr,
        "seed": args.seed,
        "checkpoint_every": args.checkpoint_every,
        "val_frames": args.val_frames,
        "depth_weight": args.depth_weight,
        "init": args.init,
        "qat": args.qat,
        "init_backbone": args.init_backbone,
        "freeze_backbone": args.freeze_backbone,
        "lens_jitter": args.lens_jitter,
    }
    # a resumed run keeps the options it was started with; those given again must match them (but --steps)
    start = saved_options(out) if args.resume else {}
    options = TrainOptions(**{**start, **{k: v for k, v in given.items() if v is not None}})
    previous = torch.get_num_threads()
    torch.set_num_threads(args.threads)
    try:
        trainer = Trainer(config, rig, out, options, device=args.device, workers=args.workers)
        path = trainer.run(resume=args.resume, until=args.until)
    finally:
        torch.set_num_threads(previous)
    print(f"trained to step {trainer.step} of {options.steps}; wrote {path}")
    print(
        f"next: fisheye-infer export --ckpt {path} --config {out / 'config.py'} "
        f"--rig {out / 'rig.json'} --out {out / 'model.onnx'}"
    )
    return 0


def only_cameras(config: Any, rig: Rig, cameras: str) -> tuple[Any, Rig]:
    """The configuration and rig reduced to ``--cameras`` (comma-separated names of the rig's cameras)."""
    names = [name.strip() for name in cameras.split(",") if name.strip()]
    reduced = rig.subset(names)  # names each camera the rig lacks
    return config.replace(image={"camera_names": tuple(names)}), reduced
