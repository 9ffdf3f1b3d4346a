"""The models the benchmarks measure, exported once under ``benchmarks/artifacts/`` (gitignored) and reused.

    files = model_files("compact")           # the shipped compact FisheyeBEVDet: checkpoint, fp32 and int8 files
    files = model_files("compact-petr")      # the shipped compact FisheyePETR
    files = model_files("fisheye-bevdet")    # a full-size architecture with seeded weights (seed 0)
    path = model_path("compact", "int8")     # a script's MODEL argument: one of NAMES, or a file's path

The int8 file is kept whatever its own check says: the benchmarks measure it either way.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
#: The shipped trained models by their names here.
SHIPPED = {"compact": "fisheye-bevdet-compact", "compact-petr": "fisheye-petr-compact"}
#: The shipped models, then full-size architectures with seeded weights.
NAMES = (*SHIPPED, "fisheye-bevdet", "fisheye-petr")
#: The help of a benchmark's MODEL argument (``model_path``).
MODEL_HELP = (
    f"an exported ONNX file, one of {', '.join(NAMES)} (exported under benchmarks/artifacts/), or an official "
    "config's stem (written by benchmarks/official_configs.py)"
)


@dataclass(frozen=True)
class ModelFiles:
    """A checkpoint (with its config and rig, where not the architecture's defaults) and its two exports."""

    name: str
    checkpoint: Path
    config: Path | None
    rig: Path | None
    fp32: Path
    int8: Path


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def model_files(name: str, progress: Callable[[str], None] = _stderr) -> ModelFiles:
    """The files of ``name`` (one of ``NAMES``), exported first where missing."""
    from fisheye_infer.export.exporter import export, export_int8
    from fisheye_infer.models import make_checkpoint
    from fisheye_infer.models.pretrained import pretrained

    if name not in NAMES:
        raise ValueError(f"model {name!r}: expected one of {', '.join(NAMES)}")
    folder = ARTIFACTS / name
    folder.mkdir(parents=True, exist_ok=True)
    if name in SHIPPED:
        shipped = pretrained(SHIPPED[name])
        files = ModelFiles(
            name, shipped.checkpoint, shipped.config, shipped.rig, folder / "model.onnx", folder / "model.int8.onnx"
        )
    else:
        files = ModelFiles(name, folder / "model.pth", None, None, folder / "model.onnx", folder / "model.int8.onnx")
        if not files.checkpoint.exists():
            make_checkpoint(name, seed=0, path=files.checkpoint)
    if not files.fp32.exists():
        progress(f"{name}: exporting {files.fp32}")
        export(files.checkpoint, files.fp32, config=files.config, rig=files.rig, progress=progress)
    if not files.int8.exists():
        progress(f"{name}: exporting {files.int8}")
        export_int8(files.fp32, files.int8, force=True, progress=progress)
    return files


def model_path(model: str | Path, kind: str = "fp32") -> Path:
    """A benchmark's MODEL argument: one of ``NAMES`` (its ``kind`` file, exported first where missing), an official
    config's stem (the full-size fp32 file ``benchmarks/official_configs.py`` writes), or a file.

    Commands that name the model reproduce anywhere; commands that give a path need that file.
    """
    if str(model) in NAMES:
        files = model_files(str(model))
        return files.int8 if kind == "int8" else files.fp32
    from official_configs import STEMS, WORK_DIR

    if str(model) in STEMS:
        path = WORK_DIR / f"{model}.onnx"
        if kind != "fp32" or not path.exists():
            raise SystemExit(f"{model}: run `python benchmarks/official_configs.py --only {model}` first (fp32 only)")
        return path
    return Path(model)


def torch_model(files: ModelFiles) -> Any:
    """The PyTorch model the files were exported from, in eval mode."""
    from fisheye_infer.export.exporter import open_checkpoint

    return open_checkpoint(files.checkpoint, config=files.config, rig=files.rig).model.eval()
