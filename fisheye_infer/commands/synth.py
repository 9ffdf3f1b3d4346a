"""``fisheye-infer synth``: synthetic fisheye frames with labels, in the Fisheye3DOD layout.

fisheye-infer synth --rig default --frames 4 --out data/synth [--seed 0] [--scale 0.25]
fisheye-infer synth --stream val --rig runs/compact/rig.json --frames 200 --out data/heldout
fisheye-infer synth --stream val --sequences 8 --length 40 --out seqs/ [--rate 10] [--ego-speed 8]
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from fisheye_infer.commands.common import RIG_HELP, int_pair

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``fisheye-infer synth``."""
    parser.add_argument("--rig", default="default", help=RIG_HELP)
    parser.add_argument("--frames", type=int, default=1, help="frames to render (default: 1)")
    parser.add_argument(
        "--out", required=True, help="dataset root to write (Fisheye3DOD layout; existing splits are extended)"
    )
    parser.add_argument(
        "--seed", type=int, default=0, help="scene seed (default: 0); the same seed writes the same files"
    )
    parser.add_argument("--split", help="split file to add the frames to (default: val, or the --stream's name)")
    parser.add_argument(
        "--scale", type=float, default=1.0, help="image scale, e.g. 0.25 for 200x200 from an 800x800 rig"
    )
    parser.add_argument("--objects", type=int_pair, default=(6, 14), help="MIN,MAX objects per frame (default: 6,14)")
    parser.add_argument(
        "--ground-height", type=float, default=2.0, help="ground plane below the lidar, metres (default: 2)"
    )
    parser.add_argument("--scene", help="scene name (default: synth-Town00-ClearNoon-seed<SEED>)")
    parser.add_argument(
        "--stream",
        choices=("train", "val"),
        help="write frames of the randomised stream `fisheye-infer train` draws from (scenes, looks and seeds as it "
        "renders them; 'val' is never trained on) instead of the plain scenes; "
        "the split file defaults to the stream's name",
    )
    parser.add_argument(
        "--first", type=int, default=0, help="with --stream: index of the first frame (or sequence) written (default 0)"
    )
    seq = parser.add_argument_group("sequences (with --stream): the same scene over time, for tracking")
    seq.add_argument("--sequences", type=int, help="write this many sequences of the stream instead of single frames")
    seq.add_argument("--length", type=int, default=40, help="frames per sequence (default: 40)")
    seq.add_argument("--rate", type=float, default=10.0, help="frames per second: 1, 2, 4, 5, 10 or 20 (default: 10)")
    seq.add_argument(
        "--ego-speed", type=float, default=8.0, help="fastest ego drive in m/s; 0 keeps the ego parked (default: 8)"
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """Render synthetic frames of a rig into a Fisheye3DOD-layout folder."""
    from fisheye_infer.cameras.rig import resolve_rig
    from fisheye_infer.scenes.render import resized_rig, synthesize

    if args.frames < 1:
        print(f"fisheye-infer synth: error: --frames must be at least 1, got {args.frames}", file=sys.stderr)
        return 2
    rig = resolve_rig(args.rig)
    if args.scale != 1.0:
        rig = resized_rig(rig, args.scale)
    if args.sequences is not None:
        return _write_sequences(args, rig)
    if args.stream:
        return _write_stream(args, rig)
    if args.first != 0:
        print("fisheye-infer synth: error: --first needs --stream", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    frames = synthesize(
        rig,
        args.out,
        frames=args.frames,
        seed=args.seed,
        split=args.split or "val",
        scene_name=args.scene,
        num_objects=args.objects,
        ground_height=args.ground_height,
    )
    seconds = time.perf_counter() - t0
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    boxes = sum(len(f.boxes) for f in frames)
    print(
        f"wrote {len(frames)} frame(s) to {args.out}: {len(rig)} cameras at {width}x{height}, "
        f"{boxes} boxes in all, {seconds / len(frames):.2f} s per frame"
    )
    print(f"first token: {frames[0].token}")
    print(f"next: fisheye-infer eval MODEL --data {args.out} --split {args.split or 'val'} --out report.json")
    return 0


def _write_stream(args: argparse.Namespace, rig: Rig) -> int:
    """``--stream``: frames of the training command's randomised stream, in the Fisheye3DOD layout."""
    from fisheye_infer.scenes.streams import SyntheticFrames, write_split

    fixed = [
        f"--{name}"
        for name, given in (
            ("objects", args.objects != (6, 14)),
            ("ground-height", args.ground_height != 2.0),
            ("scene", args.scene is not None),
        )
        if given
    ]
    if fixed or args.first < 0:
        what = (
            f"{', '.join(fixed)} belong(s) to the plain scenes"
            if fixed
            else f"--first must be at least 0, got {args.first}"
        )
        print(
            f"fisheye-infer synth: error: {what}; a --stream frame is fixed by its stream, --seed and index",
            file=sys.stderr,
        )
        return 2
    split = args.split or args.stream
    t0 = time.perf_counter()
    frames = SyntheticFrames(rig, args.stream, args.seed)
    tokens = write_split(frames, args.out, range(args.first, args.first + args.frames), split=split)
    seconds = time.perf_counter() - t0
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    print(
        f"wrote {len(tokens)} frame(s) of the {args.stream} stream (seed {args.seed}) to {args.out}, split {split}: "
        f"{len(rig)} cameras at {width}x{height}, {seconds / len(tokens):.2f} s per frame"
    )
    print(f"first token: {tokens[0]}")
    print(f"next: fisheye-infer eval MODEL --data {args.out} --split {split} --out report.json")
    return 0


def _write_sequences(args: argparse.Namespace, rig: Rig) -> int:
    """``--sequences``: sequences of moving objects (and ego), in the Fisheye3DOD layout with ego poses and ids."""
    from fisheye_infer.scenes.sequences import SyntheticSequences, write_sequences

    problem = None
    if not args.stream:
        problem = "--sequences needs --stream train or val (the split its seeds come from)"
    elif args.sequences < 1 or args.length < 1:
        problem = f"--sequences and --length must be at least 1, got {args.sequences} and {args.length}"
    try:
        seqs = (
            None
            if problem
            else SyntheticSequences(
                rig, args.stream, args.seed, length=args.length, rate=args.rate, ego_speed=args.ego_speed
            )
        )
    except ValueError as exc:
        problem = str(exc)
    if problem or seqs is None:
        print(f"fisheye-infer synth: error: {problem}", file=sys.stderr)
        return 2
    split = args.split or args.stream
    t0 = time.perf_counter()
    scenes = write_sequences(seqs, args.out, range(args.first, args.first + args.sequences), split=split)
    seconds = time.perf_counter() - t0
    print(
        f"wrote {len(scenes)} sequence(s) of {args.length} frames at {args.rate:g} Hz of the {args.stream} stream "
        f"(seed {args.seed}) to {args.out}, split {split}, {seconds / (len(scenes) * args.length):.2f} s per frame"
    )
    print(f"first scene: {scenes[0]}")
    print(f"next: fisheye-infer eval MODEL --data {args.out} --split {split} --tracking --out report.json")
    return 0
