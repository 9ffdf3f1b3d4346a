"""``fisheye-infer make-checkpoint``: a seeded random-weight checkpoint in the official format (demos and tests)."""

from __future__ import annotations

import argparse

from fisheye_infer.commands.common import NEEDS_EXPORT, ArchChoices, missing_extra

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--arch",
        choices=ArchChoices(),
        metavar="ARCH",
        default="fisheye-bevdet",
        help="architecture, one of %(choices)s (default: fisheye-bevdet)",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rig", default="default", help="rig whose geometry tables the checkpoint stores")
    parser.add_argument("--out", required=True, help=".pth file to write")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from fisheye_infer.models import make_checkpoint
    except ImportError as exc:
        return missing_extra(NEEDS_EXPORT, exc)
    from fisheye_infer.cameras.rig import resolve_rig

    make_checkpoint(args.arch, seed=args.seed, path=args.out, rig=resolve_rig(args.rig))
    print(f"wrote {args.out}: {args.arch} with seeded random weights (seed {args.seed}); its boxes mean nothing")
    return 0
