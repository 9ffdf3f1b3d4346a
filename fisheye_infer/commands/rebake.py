"""``fisheye-infer rebake``: an exported file for another rig (numpy and onnx, no torch).

fisheye-infer rebake model.onnx --rig robot_rig.yaml --out model_robot.onnx [--camera-map slot=cam,...]
fisheye-infer rebake model.onnx --rig recalibrated.yaml --out model_new.onnx --tables
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from fisheye_infer.commands.common import missing_extra

if TYPE_CHECKING:
    from fisheye_infer.runtime.artifact import ArtifactMeta

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="an ONNX file written by fisheye-infer export")
    parser.add_argument(
        "--rig", required=True, help="the new rig: rig file or folder with calib_results.txt + lidar2cam.json"
    )
    parser.add_argument("--out", required=True, help="ONNX file to write (the input is never modified)")
    parser.add_argument(
        "--tables",
        action="store_true",
        help="recompute the geometry tables for the rig instead of resampling its cameras into the training "
        "cameras (the default for a rig other than the file's training rig); the network then sees pictures it "
        "was not trained on: a lens centre moved by 1 px costs the shipped FisheyeBEVDet about a third of its FDS",
    )
    parser.add_argument(
        "--camera-map",
        metavar="MAP",
        help="which rig camera stands in each of the model's cameras, e.g. "
        "fisheye_camera_front=cam0,fisheye_camera_left=cam1,... (default: by heading: each model camera takes the "
        "rig camera looking within 45 degrees of its direction; ambiguity is refused with the candidates)",
    )
    parser.add_argument(
        "--depth",
        type=float,
        metavar="M",
        help="compensate the offset between a rig camera and the model camera it stands in for points at M metres "
        "(default: rotation only, every point taken at infinity)",
    )
    parser.add_argument(
        "--picture",
        metavar="PNG",
        help="with virtual cameras: draw a synthetic scene through each rig camera beside the view the model gets "
        "from it",
    )
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    try:
        from fisheye_infer.export.rebake import rebake
    except ImportError as exc:
        return missing_extra("rebake needs the onnx package: pip install onnx", exc)
    from fisheye_infer.cameras.camera_map import parse_camera_map
    from fisheye_infer.errors import RigError

    if args.tables and (args.camera_map is not None or args.depth is not None or args.picture is not None):
        raise RigError(
            "--camera-map, --depth and --picture are for virtual cameras; --tables keeps the model's cameras"
        )
    if args.depth is not None and not args.depth > 0:
        raise RigError(f"--depth: expected a distance above 0 m, got {args.depth}")
    camera_map = None if args.camera_map is None else parse_camera_map(args.camera_map)
    meta = rebake(
        args.model,
        args.rig,
        args.out,
        mode="tables" if args.tables else "auto",
        camera_map=camera_map,
        depth=args.depth,
    )
    virtual = meta.virtual_cameras
    how = "geometry tables recomputed" if virtual is None else "virtual cameras: the rig images resampled in the graph"
    print(f"wrote {args.out}: {meta.model_id}, rig {meta.rig.name!r} ({meta.rig_hash}), {how}")
    for report in virtual.cameras if virtual is not None else ():
        print(f"  {report.summary()}")
    if args.picture is not None and virtual is not None:
        print(f"wrote {_draw(meta, args.picture)}")
    return 0


def _draw(meta: ArtifactMeta, path: str) -> Path:
    """A synthetic scene through the rig's cameras beside the training views the file makes of them."""
    import numpy as np

    from fisheye_infer.geometry.virtual import virtual_front
    from fisheye_infer.scenes.render import Renderer, random_scene
    from fisheye_infer.tools.virtual_picture import draw_virtual_cameras
    from fisheye_infer.tools.viz import save_png

    assert meta.virtual_cameras is not None
    depth = meta.virtual_cameras.depth_m
    front = virtual_front(meta.virtual_cameras.training_rig, meta.rig, meta.rig.names, depth)
    images = Renderer(texture_seed=1).render(meta.rig, random_scene(np.random.default_rng(1)))
    return save_png(path, draw_virtual_cameras(front, images))
