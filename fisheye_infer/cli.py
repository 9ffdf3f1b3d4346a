"""``fisheye-infer``: the table of subcommands, one module each under ``fisheye_infer.commands``.

Each module's ``configure(parser)`` adds its flags and ``run`` (and an optional ``DESCRIPTION``
for its ``--help``); its extras are imported when it runs. An error of the ``FisheyeInferError``
tree ends the command with its message and exit 1.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from fisheye_infer._version import __version__
from fisheye_infer.errors import FisheyeInferError

__all__ = ["COMMANDS", "main", "build_parser"]

#: (subcommand, module in fisheye_infer.commands, one-line help), in the order ``--help`` lists them.
COMMANDS: tuple[tuple[str, str, str], ...] = (
    ("demo", "demo", "run the main job on the shipped defaults"),
    ("rig", "rig", "show, plot or convert a camera rig"),
    ("eval", "eval", "measure FDS/mAP on Fisheye3DOD-layout data or on two results files"),
    ("synth", "synth", "render synthetic fisheye frames in the Fisheye3DOD layout"),
    ("export", "export", "export a checkpoint to one self-contained, verified ONNX file"),
    ("rebake", "rebake", "recompute an ONNX file's geometry tables for a new rig (no torch)"),
    ("make-checkpoint", "make_checkpoint", "write a seeded random-weight checkpoint (demos and tests)"),
    ("train", "train", "train a detector of the paper on synthetic frames (default: the compact FisheyeBEVDet)"),
    ("detect", "detect", "run a model on frames; write results JSON and pictures"),
    ("replay", "replay", "run a model on a recorded ROS bag; write an MCAP file for ROS 2 tools and Foxglove"),
    ("serve", "serve", "serve a model over HTTP and WebSocket"),
    ("triton", "triton", "write a Triton model repository (config.pbtxt + model.onnx) for an exported file"),
    ("bench", "bench", "benchmark a model on this machine: latency per stage, throughput, peak RSS"),
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="fisheye-infer", description="Export, run and serve surround-view fisheye 3D object detectors."
    )
    parser.add_argument("--version", action="version", version=f"fisheye-infer {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module, help_text in COMMANDS:
        command = importlib.import_module(f"fisheye_infer.commands.{module}")
        command.configure(sub.add_parser(name, help=help_text, description=getattr(command, "DESCRIPTION", None)))
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "run", None):
        parser.print_help()
        return 1
    try:
        return int(args.run(args))
    except FisheyeInferError as exc:
        print(f"fisheye-infer {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # the reader of the output went away (`fisheye-infer rig show | head -3`): stop quietly, as Unix tools do;
        # the interpreter's last flush of stdout at exit would raise again, so stdout becomes /dev/null
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, the status a shell reports for a tool stopped so


if __name__ == "__main__":
    sys.exit(main())
