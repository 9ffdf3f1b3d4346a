"""The checkpoint kit's models, built from ``tests/data`` (see ``tests/data/checkpoints/README.md``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"


def kit_checkpoint(arch: str, path: Path) -> Path:
    """Seeded weights whose BatchNorm statistics the official model calibrated, with the official
    geometry buffers, saved in the official format at ``path``."""
    from fisheye_infer.models import calibrated_checkpoint

    prefix = arch.replace("-", "_") + "/"
    folder = DATA / "checkpoints" / arch
    if (folder / "geometry.npz").is_file():  # the baselines: the official constructor's tables, for their own rig
        with np.load(folder / "geometry.npz") as npz:
            geometry = {k: npz[k] for k in npz.files}
    else:
        with np.load(DATA / "official_geometry.npz") as npz:
            geometry = {k[len(prefix) :]: npz[k] for k in npz.files if k.startswith(prefix)}
    with np.load(folder / "bn_stats.npz") as stats:
        calibrated_checkpoint(arch, dict(stats), geometry, path=path)
    return path
