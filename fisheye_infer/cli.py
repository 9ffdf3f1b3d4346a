"""``fisheye-infer``: one subcommand per job, each a plain function that imports its extras lazily."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from fisheye_infer._version import __version__
from fisheye_infer.errors import FisheyeInferError

__all__ = ["main", "build_parser"]


def _rig_show(args: argparse.Namespace) -> int:
    from fisheye_infer.rig import resolve_rig

    print(resolve_rig(args.rig).describe())
    return 0


def _rig_plot(args: argparse.Namespace) -> int:
    from fisheye_infer.rig import resolve_rig
    from fisheye_infer.viz import draw_rig, save_png

    print(f"wrote {save_png(args.out, draw_rig(resolve_rig(args.rig)))}")
    return 0


def _rig_grid(args: argparse.Namespace) -> int:
    from fisheye_infer.geometry.grids import spherical_grid
    from fisheye_infer.rig import resolve_rig
    from fisheye_infer.viz import draw_sampling_grid, save_png

    rig = resolve_rig(args.rig)
    camera = rig.camera(args.camera) if args.camera else rig.cameras[0]
    grid = spherical_grid(camera.model, (args.rows, args.cols))
    print(f"wrote {save_png(args.out, draw_sampling_grid(camera.model, grid))}")
    return 0


def _rig_convert(args: argparse.Namespace) -> int:
    from fisheye_infer.rig import FISHEYE3DOD_CAMERAS, Rig

    if args.extrinsics:
        rig = Rig.from_ocam_extrinsics(args.calib, args.extrinsics, fov=args.fov)
    else:
        cameras = args.cameras.split(",") if args.cameras else FISHEYE3DOD_CAMERAS
        rig = Rig.from_sensor_metadata(args.sensor_metadata, args.calib, cameras=cameras, frame_id=args.frame, convention=args.convention, fov=args.fov)
    rig.save(args.out)
    print(rig.describe())
    print(f"wrote {args.out}")
    return 0


#: Score threshold of the demo's picture and counts: where the shipped model's F1 (2 m, same class)
#: peaks on held-out frames (recall 0.42, precision 0.65 on 100 of them; 0.3 keeps 0.95 precision at 0.12 recall).
DEMO_SCORE_THRESHOLD = 0.1


def _demo(args: argparse.Namespace) -> int:
    """The main job on embedded defaults: the shipped rig and its geometry, the shipped trained
    compact FisheyeBEVDet exported to a verified ONNX file, and detection on its held-out frame."""
    import json

    from fisheye_infer.geometry import BevGrid, build_pooling_plan, depth_bins, frustum_to_lidar, spherical_frustum, spherical_grid
    from fisheye_infer.rig import default_rig
    from fisheye_infer.viz import draw_rig, draw_sampling_grid, save_png

    out = Path(args.out)
    rig = default_rig()
    print(rig.describe())
    model = rig.shared_model()
    grid = spherical_grid(model)
    plan = build_pooling_plan(frustum_to_lidar(spherical_frustum(depth_bins()), rig.cam2lidar()), BevGrid())
    print(
        f"geometry: sampling grid {grid.shape[0]}x{grid.shape[1]}, "
        f"{plan.num_kept:,} of {plan.num_points:,} frustum points pooled into {int((plan.counts > 0).sum()):,} BEV cells "
        f"({len(plan.bucket_sizes)} buckets, {sum(b.size for b in plan.bucket_points) / max(plan.num_kept, 1):.2f}x padding)"
    )
    print(f"wrote {save_png(out / 'rig.png', draw_rig(rig))}")
    print(f"wrote {save_png(out / 'sampling_grid.png', draw_sampling_grid(model, grid))}")

    try:
        from fisheye_infer.export.exporter import export
        from fisheye_infer.models.pretrained import COMPACT_BEVDET as shipped
    except ImportError as exc:
        print(f"skipping export and detection: the [export] extra is not installed ({exc})")
        return 0
    onnx_path = out / f"{shipped.name}.onnx"
    print(f"\nexport: the shipped {shipped.name}, trained on randomised synthetic frames (model card: {shipped.card})")
    print(export(shipped.checkpoint, onnx_path, config=shipped.config, rig=shipped.rig, verify_images=shipped.heldout_frame).summary())

    from fisheye_infer.detect_command import run_detect

    detect_args = argparse.Namespace(model=str(onnx_path), images=[str(shipped.heldout_frame)], result=None, out=str(out / "result.json"),
                                     viz=str(out / "result.png"), score_threshold=DEMO_SCORE_THRESHOLD, classes=None, nms=None, threads=None)
    run_detect(detect_args)
    detections = json.loads((out / "result.json").read_text())["frames"][0]["detections"]
    labels = json.loads((shipped.heldout_frame / "labels.json").read_text())["records"]
    found, extra = _match_labels(detections, labels)
    print(f"\ndemo done: on the held-out frame, {found} of {len(labels)} labelled objects found (same class, centre within "
          f"{MATCH_RADIUS_M:g} m, score >= {DEMO_SCORE_THRESHOLD}); {extra} box(es) on no object; see {out}/result.png")
    return 0


#: Centre distance within which a detection finds a labelled object (the metric's 2 m threshold).
MATCH_RADIUS_M = 2.0


def _match_labels(detections: list[dict], records: list[dict]) -> tuple[int, int]:
    """(labelled objects found, detections left over): greedy by score, same class, bird's-eye centres."""
    used = [False] * len(records)
    found = 0
    for det in sorted(detections, key=lambda d: -d["score"]):
        best, best_d = -1, MATCH_RADIUS_M
        for i, rec in enumerate(records):
            d = ((det["x"] - rec["translation"][0]) ** 2 + (det["y"] - rec["translation"][1]) ** 2) ** 0.5
            if not used[i] and rec["detection_name"] == det["class_name"] and d <= best_d:
                best, best_d = i, d
        if best >= 0:
            used[best] = True
            found += 1
    return found, len(detections) - found


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fisheye-infer", description="Export, run and serve surround-view fisheye 3D object detectors.")
    parser.add_argument("--version", action="version", version=f"fisheye-infer {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo = sub.add_parser("demo", help="run the main job on the shipped defaults")
    demo.add_argument("--out", default="artifacts/demo", help="folder for the outputs (default: artifacts/demo)")
    demo.set_defaults(run=_demo)

    rig = sub.add_parser("rig", help="show, plot or convert a camera rig")
    rig_sub = rig.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    rig_help = "rig file (.json/.yaml), folder with calib_results.txt + lidar2cam.json, or 'default'"
    show = rig_sub.add_parser("show", help="print the rig's cameras, poses and hash")
    show.add_argument("rig", nargs="?", default="default", help=rig_help)
    show.set_defaults(run=_rig_show)
    plot = rig_sub.add_parser("plot", help="draw the cameras and their fields of view from above")
    plot.add_argument("rig", nargs="?", default="default", help=rig_help)
    plot.add_argument("--out", required=True, help="PNG to write")
    plot.set_defaults(run=_rig_plot)
    grid = rig_sub.add_parser("grid", help="draw where the equirectangular sampling grid reads a fisheye image")
    grid.add_argument("rig", nargs="?", default="default", help=rig_help)
    grid.add_argument("--camera", help="camera name (default: the first)")
    grid.add_argument("--rows", type=int, default=25)
    grid.add_argument("--cols", type=int, default=100)
    grid.add_argument("--out", required=True, help="PNG to write")
    grid.set_defaults(run=_rig_grid)
    convert = rig_sub.add_parser("convert", help="write a rig file from an OCam file and extrinsics")
    convert.add_argument("--calib", required=True, help="OCam calib_results.txt shared by the cameras")
    source = convert.add_mutually_exclusive_group(required=True)
    source.add_argument("--extrinsics", help='lidar2cam.json: {"cameras": {name: 4x4}}')
    source.add_argument("--sensor-metadata", help="Fisheye3DOD <scene>/<vehicle> folder with <camera>/sensor_metadata.txt")
    convert.add_argument("--cameras", help="comma-separated camera order (sensor metadata only)")
    convert.add_argument("--frame", help="frame id (sensor metadata only; default: first common frame)")
    convert.add_argument("--convention", choices=("compat", "exact"), default="compat", help="CARLA pose conversion (default: compat, as the checkpoints were trained)")
    convert.add_argument("--fov", type=float, default=220.0, help="lens field of view in degrees (default 220)")
    convert.add_argument("--out", required=True, help="rig file to write (.json or .yaml)")
    convert.set_defaults(run=_rig_convert)

    from fisheye_infer.eval.commands import configure_eval, configure_synth

    configure_eval(sub.add_parser("eval", help="measure FDS/mAP on Fisheye3DOD-layout data or on two results files"))
    configure_synth(sub.add_parser("synth", help="render synthetic fisheye frames in the Fisheye3DOD layout"))

    from fisheye_infer.export.commands import configure_export, configure_make_checkpoint, configure_rebake

    configure_export(sub.add_parser("export", help="export a checkpoint to one self-contained, verified ONNX file"))
    configure_rebake(sub.add_parser("rebake", help="recompute an ONNX file's geometry tables for a new rig (no torch)"))
    configure_make_checkpoint(sub.add_parser("make-checkpoint", help="write a seeded random-weight checkpoint (demos and tests)"))

    from fisheye_infer.train_command import configure_train

    configure_train(sub.add_parser("train", help="train a FisheyeBEVDet on synthetic frames (default: the compact model)"))

    from fisheye_infer.detect_command import configure_detect

    configure_detect(sub.add_parser("detect", help="run a model on frames; write results JSON and pictures"))

    from fisheye_infer.service.commands import configure_serve

    configure_serve(sub.add_parser("serve", help="serve a model over HTTP and WebSocket", description="Serve a model over HTTP and WebSocket (needs the [serve] extra)."))

    from fisheye_infer.triton.commands import configure_triton

    configure_triton(sub.add_parser("triton", help="write a Triton model repository (config.pbtxt + model.onnx) for an exported file"))

    from fisheye_infer.bench import configure_bench

    configure_bench(sub.add_parser("bench", help="benchmark a model on this machine: latency per stage, throughput, peak RSS"))
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "run", None):
        parser.print_help()
        return 1
    try:
        return args.run(args)
    except FisheyeInferError as exc:
        print(f"fisheye-infer {args.command}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
