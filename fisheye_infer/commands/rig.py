"""``fisheye-infer rig show|plot|grid|convert|import``: look at a camera rig, or write one from calibration files."""

from __future__ import annotations

import argparse

from fisheye_infer.commands.common import RIG_HELP

__all__ = ["configure"]


def configure(parser: argparse.ArgumentParser) -> None:
    actions = parser.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    show = actions.add_parser("show", help="print the rig's cameras, poses and hash")
    show.add_argument("rig", nargs="?", default="default", help=RIG_HELP)
    show.set_defaults(run=run_show)
    plot = actions.add_parser("plot", help="draw the cameras and their fields of view from above")
    plot.add_argument("rig", nargs="?", default="default", help=RIG_HELP)
    plot.add_argument("--out", required=True, help="PNG to write")
    plot.set_defaults(run=run_plot)
    grid = actions.add_parser("grid", help="draw where the equirectangular sampling grid reads a fisheye image")
    grid.add_argument("rig", nargs="?", default="default", help=RIG_HELP)
    grid.add_argument("--camera", help="camera name (default: the first)")
    grid.add_argument("--rows", type=int, default=25)
    grid.add_argument("--cols", type=int, default=100)
    grid.add_argument("--out", required=True, help="PNG to write")
    grid.set_defaults(run=run_grid)
    convert = actions.add_parser("convert", help="write a rig file from an OCam file and extrinsics")
    convert.add_argument("--calib", required=True, help="OCam calib_results.txt shared by the cameras")
    source = convert.add_mutually_exclusive_group(required=True)
    source.add_argument("--extrinsics", help='lidar2cam.json: {"cameras": {name: 4x4}}')
    source.add_argument(
        "--sensor-metadata", help="Fisheye3DOD <scene>/<vehicle> folder with <camera>/sensor_metadata.txt"
    )
    convert.add_argument("--cameras", help="comma-separated camera order (sensor metadata only)")
    convert.add_argument("--frame", help="frame id (sensor metadata only; default: first common frame)")
    convert.add_argument(
        "--convention",
        choices=("compat", "exact"),
        default="compat",
        help="CARLA pose conversion (default: compat, as the checkpoints were trained)",
    )
    convert.add_argument("--fov", type=float, default=220.0, help="lens field of view in degrees (default 220)")
    convert.add_argument("--out", required=True, help="rig file to write (.json or .yaml)")
    convert.set_defaults(run=run_convert)
    imported = actions.add_parser(
        "import", help="write a rig file from Kalibr, ROS CameraInfo, OpenCV or OCamCalib calibration files"
    )
    imported.add_argument(
        "files",
        nargs="+",
        help="Kalibr camchains, or one ROS CameraInfo YAML / OpenCV FileStorage file (YAML or XML) / OCamCalib "
        "calib_results.txt per camera",
    )
    imported.add_argument(
        "--format",
        choices=("kalibr", "ros", "opencv", "ocam"),
        help="the files' format (default: recognised from each file)",
    )
    imported.add_argument(
        "--extrinsics",
        required=True,
        help='lidar2cam.json: {"cameras": {name: 4x4 lidar2cam}}; one camera of a Kalibr camchain places them all '
        "(each camchain from its own cameras)",
    )
    imported.add_argument(
        "--trust-chain",
        choices=("cn_cnm1", "imu"),
        help="for a Kalibr camchain with both T_cn_cnm1 and T_cam_imu: which places the cameras where they "
        "disagree (default: a disagreement is refused with its size)",
    )
    imported.add_argument("--names", help="comma-separated camera names, in file order (default: the files' own)")
    imported.add_argument(
        "--ocam",
        action="store_true",
        help="replace each wide-angle model by its OCam fit, the form the fisheye detectors' geometry takes "
        "(the fit's error is printed; a fit above 1 px max reprojection error is refused)",
    )
    imported.add_argument("--force-fit", action="store_true", help="with --ocam: write fits above the 1 px bound too")
    imported.add_argument("--out", required=True, help="rig file to write (.json or .yaml)")
    imported.add_argument("--plot", help="PNG of the rig from above (default: --out with .png)")
    imported.set_defaults(run=run_import)


def run_show(args: argparse.Namespace) -> int:
    from fisheye_infer.cameras.rig import resolve_rig

    print(resolve_rig(args.rig).describe())
    return 0


def run_plot(args: argparse.Namespace) -> int:
    from fisheye_infer.cameras.rig import resolve_rig
    from fisheye_infer.tools.viz import draw_rig, save_png

    print(f"wrote {save_png(args.out, draw_rig(resolve_rig(args.rig)))}")
    return 0


def run_grid(args: argparse.Namespace) -> int:
    from fisheye_infer.cameras.camera_models import OCamModel
    from fisheye_infer.cameras.rig import resolve_rig
    from fisheye_infer.errors import RigError
    from fisheye_infer.geometry.grids import spherical_grid
    from fisheye_infer.tools.viz import draw_sampling_grid, save_png

    rig = resolve_rig(args.rig)
    camera = rig.camera(args.camera) if args.camera else rig.cameras[0]
    if not isinstance(camera.model, OCamModel):
        raise RigError(
            f"camera '{camera.name}': the sampling grid is drawn for OCam models, this camera has a "
            f"{type(camera.model).__name__} model"
        )
    grid = spherical_grid(camera.model, (args.rows, args.cols))
    print(f"wrote {save_png(args.out, draw_sampling_grid(camera.model, grid))}")
    return 0


def run_convert(args: argparse.Namespace) -> int:
    from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, Rig

    if args.extrinsics:
        rig = Rig.from_ocam_extrinsics(args.calib, args.extrinsics, fov=args.fov)
    else:
        cameras = args.cameras.split(",") if args.cameras else FISHEYE3DOD_CAMERAS
        rig = Rig.from_sensor_metadata(
            args.sensor_metadata,
            args.calib,
            cameras=cameras,
            frame_id=args.frame,
            convention=args.convention,
            fov=args.fov,
        )
    rig.save(args.out)
    print(rig.describe())
    print(f"wrote {args.out}")
    return 0


def run_import(args: argparse.Namespace) -> int:
    from pathlib import Path

    from fisheye_infer.cameras.ocam_fit import MAX_FIT_ERROR_PX, fit_rig_ocam
    from fisheye_infer.cameras.rig import Rig
    from fisheye_infer.errors import OptionError
    from fisheye_infer.tools.viz import draw_rig, save_png

    if args.force_fit and not args.ocam:
        raise OptionError("--force-fit: applies to --ocam fits; add --ocam, or leave it out")
    names = [n.strip() for n in args.names.split(",")] if args.names else None
    rig = Rig.from_calibration(
        args.files, args.extrinsics, args.format, names, name=Path(args.out).stem, trust_chain=args.trust_chain
    )
    if args.ocam:
        rig, fits = fit_rig_ocam(rig, max_error_px=MAX_FIT_ERROR_PX, force=args.force_fit)
        for camera, fit in fits.items():
            error = fit.max_reprojection_error_px
            above = error > MAX_FIT_ERROR_PX
            note = f" (above the {MAX_FIT_ERROR_PX:g} px bound: written because of --force-fit)" if above else ""
            print(f"camera '{camera}': OCam fit, max reprojection error {error:.3f} px{note}")
    rig.save(args.out)
    print(rig.describe())
    plot = args.plot or str(Path(args.out).with_suffix(".png"))
    print(f"wrote {args.out} and {save_png(plot, draw_rig(rig))}")
    return 0
