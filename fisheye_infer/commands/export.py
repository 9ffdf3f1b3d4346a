"""``fisheye-infer export``: a checkpoint to one self-contained, verified ONNX file (and an int8 one).

fisheye-infer export --ckpt fisheye_bevdet.pth --config fisheye_bevdet.py --rig rig.yaml --out model.onnx [--int8]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fisheye_infer.commands.common import NEEDS_EXPORT, ArchChoices, missing_extra
from fisheye_infer.precision import COMPARE_FRAMES, MIN_TOP_MATCHED

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--ckpt", required=True, help="official mmdet3d checkpoint (.pth) or one written by make-checkpoint"
    )
    parser.add_argument("--out", required=True, help="ONNX file to write")
    parser.add_argument(
        "--arch",
        choices=ArchChoices(),
        metavar="ARCH",
        help="architecture, one of %(choices)s (default: from the checkpoint's keys)",
    )
    parser.add_argument(
        "--config", help="the official config file the checkpoint was trained with (read, never executed)"
    )
    parser.add_argument(
        "--rig", default="default", help="rig file, folder with calib_results.txt + lidar2cam.json, or 'default'"
    )
    onto = parser.add_argument_group(
        "another rig",
        "the checkpoint's file is verified for the rig it was trained with (--rig), then resampled in the graph onto "
        "another rig's cameras (virtual cameras, as fisheye-infer rebake writes them): the network sees the "
        "pictures it was trained on",
    )
    onto.add_argument("--onto", metavar="RIG", help="the robot's rig: rig file or folder (default: none)")
    onto.add_argument(
        "--camera-map", metavar="MAP", help="with --onto: model_camera=robot_camera,... (default: by heading)"
    )
    onto.add_argument(
        "--depth", type=float, metavar="M", help="with --onto: compensate camera offsets at M metres (default: none)"
    )
    parser.add_argument(
        "--geometry",
        choices=("verify", "checkpoint", "rig"),
        default="verify",
        help="tables stored in the checkpoint vs recomputed for the rig: verify they agree (default), or choose",
    )
    parser.add_argument("--verify-images", help="folder with your own frames to add to the parity check")
    parser.add_argument(
        "--frames",
        type=int,
        default=2,
        help="seeded synthetic frames for the fp32 file's check against PyTorch (default 2)",
    )
    parser.add_argument("--force", action="store_true", help="keep the file even when parity fails")
    parser.add_argument(
        "--allow-pickle", action="store_true", help="load a checkpoint that needs pickle (only from a source you trust)"
    )
    int8 = parser.add_argument_group(
        "int8",
        "static QDQ quantization (U8 activations, S8 per-channel 7-bit weights); geometry, pooling, "
        "attention products, softmax, norms and box decoding stay float32",
    )
    int8.add_argument(
        "--int8",
        action="store_true",
        help="after the fp32 file is verified, also write an int8 file next to it: --out model.onnx -> model.int8.onnx "
        "(--out stays the fp32 file); written when it finds --min-kept of the fp32 top-50 boxes again "
        "(or with --force). Alone, it searches what stays float32 until the file passes, and reports the trials",
    )
    int8.add_argument("--calib-images", help="folder with your own frames for calibration, read like --verify-images")
    int8.add_argument(
        "--calib-frames", type=int, default=8, help="seeded synthetic calibration frames of the rig (default 8)"
    )
    int8.add_argument(
        "--int8-scope",
        choices=("auto", "network", "trunk"),
        default="auto",
        help="auto (default): start from every layer with weights less the architecture's float32 modules, keep "
        "float32 the modules whose int8 error costs most boxes until the file passes, the trunk scope last; "
        "network: every layer with weights (image trunk, depth net, BEV encoder and neck, head convolutions, "
        "linear layers) less --int8-float; trunk: the image backbone and neck only",
    )
    int8.add_argument(
        "--int8-float",
        metavar="MODULES",
        help="modules to leave float32 by hand, comma-separated state-dict prefixes "
        "(e.g. img_backbone.conv1,bbox_head; '' for none), in place of the search "
        "(with --int8-scope network or trunk alone: the architecture's own, FisheyeBEVDet's head but its shared "
        "and first heatmap convolutions): fewer int8 layers keep more of the fp32 boxes, at some of the speed-up",
    )
    parser.add_argument(
        "--fp16",
        action="store_true",
        help="after the fp32 file is verified, also write a float16 file for GPU execution providers next to it: "
        "--out model.onnx -> model.fp16.onnx; written when it finds --min-kept of the fp32 top-50 boxes again "
        "(or with --force)",
    )
    reduced = parser.add_argument_group(
        "int8 and fp16 files", "each is compared with the verified fp32 file, ONNX against ONNX"
    )
    reduced.add_argument(
        "--compare-frames",
        type=int,
        default=COMPARE_FRAMES,
        help=f"seeded synthetic frames for that comparison, plus --verify-images (default {COMPARE_FRAMES}: "
        "the share kept varies from frame to frame, and the summary gives its standard error)",
    )
    reduced.add_argument(
        "--min-kept",
        type=float,
        default=MIN_TOP_MATCHED,
        help=f"share of the fp32 top-50 boxes (within 0.5 m, same label) a file must find again to be written "
        f"(default {MIN_TOP_MATCHED:g})",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from fisheye_infer.export.exporter import export
        from fisheye_infer.export.options import Comparison, Int8Options
    except ImportError as exc:
        return missing_extra(NEEDS_EXPORT, exc)
    if (
        args.calib_images is not None
        or args.calib_frames != 8
        or args.int8_scope != "auto"
        or args.int8_float is not None
    ) and not args.int8:
        print(
            "fisheye-infer export: error: --calib-images/--calib-frames/--int8-scope/--int8-float need --int8",
            file=sys.stderr,
        )
        return 2
    if (args.camera_map is not None or args.depth is not None) and args.onto is None:
        print("fisheye-infer export: error: --camera-map/--depth need --onto", file=sys.stderr)
        return 2
    if (args.compare_frames != COMPARE_FRAMES or args.min_kept != MIN_TOP_MATCHED) and not (args.int8 or args.fp16):
        print("fisheye-infer export: error: --compare-frames/--min-kept need --int8 or --fp16", file=sys.stderr)
        return 2
    int8_float = None if args.int8_float is None else tuple(m.strip() for m in args.int8_float.split(",") if m.strip())
    int8 = (
        Int8Options(
            calib_images=args.calib_images, calib_frames=args.calib_frames, scope=args.int8_scope, keep_float=int8_float
        )
        if args.int8
        else None
    )
    comparison = Comparison(frames=args.compare_frames, min_kept=args.min_kept, images=args.verify_images)
    result = export(
        args.ckpt,
        args.out,
        arch=args.arch,
        config=args.config,
        rig=args.rig,
        geometry=args.geometry,
        verify_images=args.verify_images,
        frames=args.frames,
        force=args.force,
        allow_pickle=args.allow_pickle,
        int8=int8,
        fp16=args.fp16,
        comparison=comparison,
    )
    print(result.summary())
    if args.onto is not None:
        return _onto(args, [f for f in (result.path, *(r.path for r in (result.int8, result.fp16) if r)) if f])
    return 0


def _onto(args: argparse.Namespace, files: list[Path]) -> int:
    """Each written file re-targeted onto ``--onto``'s cameras in place (``rebake``'s virtual cameras)."""
    from fisheye_infer.cameras.camera_map import parse_camera_map
    from fisheye_infer.export.rebake import rebake

    camera_map = None if args.camera_map is None else parse_camera_map(args.camera_map)
    for path in files:
        staged = path.with_name(f".{path.name}.onto")
        meta = rebake(path, args.onto, staged, mode="virtual", camera_map=camera_map, depth=args.depth)
        staged.replace(path)
        print(f"{path}: virtual cameras onto {meta.rig.name!r} ({meta.rig_hash})")
        for report in meta.virtual_cameras.cameras if meta.virtual_cameras else ():
            print(f"  {report.summary()}")
    return 0
