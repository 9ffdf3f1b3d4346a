"""``fisheye-infer demo``: the main job on the shipped defaults.

The shipped rig and its geometry (pictures of the rig and of the sampling grid), and each shipped
trained model (the compact FisheyeBEVDet and FisheyePETR) exported to a verified ONNX file and run
on the held-out frame, with how many of the frame's labelled objects it found.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="artifacts/demo", help="folder for the outputs (default: artifacts/demo)")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    """The main job on embedded defaults: the shipped rig and its geometry, and each shipped trained model
    exported to a verified ONNX file and run on the held-out frame."""
    from fisheye_infer.cameras.rig import default_rig
    from fisheye_infer.geometry import (
        BevGrid,
        build_pooling_plan,
        depth_bins,
        frustum_to_lidar,
        spherical_frustum,
        spherical_grid,
    )
    from fisheye_infer.tools.viz import draw_rig, draw_sampling_grid, save_png

    out = Path(args.out)
    rig = default_rig()
    print(rig.describe())
    model = rig.shared_model()
    grid = spherical_grid(model)
    plan = build_pooling_plan(frustum_to_lidar(spherical_frustum(depth_bins()), rig.cam2lidar()), BevGrid())
    print(
        f"geometry: sampling grid {grid.shape[0]}x{grid.shape[1]}, "
        f"{plan.num_kept:,} of {plan.num_points:,} frustum points pooled into "
        f"{int((plan.counts > 0).sum()):,} BEV cells "
        f"({len(plan.bucket_sizes)} buckets, "
        f"{sum(b.size for b in plan.bucket_points) / max(plan.num_kept, 1):.2f}x padding)"
    )
    print(f"wrote {save_png(out / 'rig.png', draw_rig(rig))}")
    print(f"wrote {save_png(out / 'sampling_grid.png', draw_sampling_grid(model, grid))}")

    try:
        from fisheye_infer.export.exporter import export  # noqa: F401 (the [export] extra)
        from fisheye_infer.models.pretrained import PRETRAINED
    except ImportError as exc:
        print(f"skipping export and detection: the [export] extra is not installed ({exc})")
        return 0
    for shipped in PRETRAINED:
        _export_and_detect(shipped, out)
    return 0


def _export_and_detect(shipped: Any, out: Path) -> None:
    """Export a shipped model (``Pretrained``) to ``out/<name>.onnx``, verified on its held-out frame, and run it
    there: ``<name>.json``, ``<name>.png`` and how many labelled objects its boxes above its threshold find."""
    import json

    from fisheye_infer.commands import detect
    from fisheye_infer.export.exporter import export

    onnx_path = out / f"{shipped.name}.onnx"
    print(f"\nexport: the shipped {shipped.name}, trained on randomised synthetic frames (model card: {shipped.card})")
    print(
        export(
            shipped.checkpoint, onnx_path, config=shipped.config, rig=shipped.rig, verify_images=shipped.heldout_frame
        ).summary()
    )
    detect_parser = argparse.ArgumentParser(prog="fisheye-infer detect")  # detect's own flags and defaults
    detect.configure(detect_parser)
    result, picture = out / f"{shipped.name}.json", out / f"{shipped.name}.png"
    threshold = str(shipped.score_threshold)
    argv = [str(onnx_path), "--images", str(shipped.heldout_frame), "--out", str(result), "--viz", str(picture)]
    detect.run(detect_parser.parse_args([*argv, "--score-threshold", threshold]))
    detections = json.loads(result.read_text())["frames"][0]["detections"]
    labels = json.loads((shipped.heldout_frame / "labels.json").read_text())["records"]
    found, extra = _match_labels(detections, labels)
    print(
        f"\n{shipped.name} on the held-out frame: {found} of {len(labels)} labelled objects found "
        f"(same class, centre within {MATCH_RADIUS_M:g} m, score >= {threshold}); "
        f"{extra} box(es) on no object; see {picture}"
    )


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
