"""``fisheye-infer rebake``: recompute an exported file's geometry tables for another rig (numpy and onnx, no torch).

fisheye-infer rebake model.onnx --rig new_rig.yaml --out model_new_rig.onnx
"""

from __future__ import annotations

import argparse

from fisheye_infer.commands.common import missing_extra

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="an ONNX file written by fisheye-infer export")
    parser.add_argument(
        "--rig", required=True, help="the new rig: rig file or folder with calib_results.txt + lidar2cam.json"
    )
    parser.add_argument("--out", required=True, help="ONNX file to write (the input is never modified)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from fisheye_infer.export.rebake import rebake
    except ImportError as exc:
        return missing_extra("rebake needs the onnx package: pip install onnx", exc)
    meta = rebake(args.model, args.rig, args.out)
    print(
        f"wrote {args.out}: {meta.model_id}, rig {meta.rig.name!r} ({meta.rig_hash}), "
        f"{len(meta.geometry_initializers)} geometry tables recomputed"
    )
    return 0
