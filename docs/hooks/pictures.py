"""MkDocs hook: the pictures of rigs and sampling grids, drawn from the code at build time (never pasted).

- ``assets/generated/rig-shipped.png``: the shipped Fisheye3DOD rig from above (``fisheye-infer rig plot``'s drawing);
- ``assets/generated/rig-robot.png``: the example robot rig imported from a camchain (``examples/robot_rig.yaml``);
- ``assets/generated/rig-pinhole6.png``: the six-camera pinhole rig of the baselines;
- ``assets/generated/sampling-grid.png``: where the spherical grid reads the shipped lens's image.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from mkdocs.config.defaults import MkDocsConfig
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[2]
FOLDER = "assets/generated"


def _png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise RuntimeError("cv2 could not encode a picture as PNG")
    return data.tobytes()


def pictures() -> dict[str, bytes]:
    """File name (under ``assets/generated/``) -> PNG bytes of every picture."""
    from fisheye_infer.cameras.rig import Rig, default_rig, pinhole_rig
    from fisheye_infer.geometry import spherical_grid
    from fisheye_infer.tools.viz import draw_rig, draw_sampling_grid

    shipped = default_rig()
    lens = shipped.shared_model()
    return {
        "rig-shipped.png": _png(draw_rig(shipped)),
        "rig-robot.png": _png(draw_rig(Rig.load(ROOT / "examples" / "robot_rig.yaml"))),
        "rig-pinhole6.png": _png(draw_rig(pinhole_rig())),
        "sampling-grid.png": _png(draw_sampling_grid(lens, spherical_grid(lens))),
    }


def on_files(files: Files, config: MkDocsConfig) -> Files:
    for name, data in pictures().items():
        files.append(File.generated(config, f"{FOLDER}/{name}", content=data))
    return files
