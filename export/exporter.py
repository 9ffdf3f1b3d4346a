"""``export``: checkpoint + rig -> one verified, self-contained ONNX file.

    result = export("fisheye_bevdet.pth", "model.onnx")            # default rig, arch from keys
    result = export(ckpt, out, config="fisheye_petr.py", rig="rig.yaml", verify_images="frames/")

Steps: read the checkpoint (weights-only), pick the architecture, build the plain-PyTorch model
for the rig and load the checkpoint strictly (its stored geometry is checked against the rig),
trace to ONNX with the geometry tables as named initializers, write the metadata, then run the
file in ONNX Runtime against PyTorch on seeded synthetic frames (and the user's frames). The
output file appears only when that parity check passes (or with ``force``); nothing is left
behind otherwise.
"""

from __future__ import annotations

import hashlib
import os
import platform
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import onnx
import onnxruntime as ort
import torch

from fisheye_infer._version import __version__
from fisheye_infer.artifact import ArtifactMeta, Normalisation, ParityReport
from fisheye_infer.errors import ExportError, ParityError, RigError
from fisheye_infer.preprocess import frames_from_paths, prepare_batch
from fisheye_infer.rig import Rig, resolve_rig
from fisheye_infer.synth import Renderer, random_scene

from .architectures import get_arch, infer_architecture
from .graph import REBAKE_WEIGHTS_KEY, encode_arrays, save_model, set_metadata
from .trace import OPSET, trace_to_onnx
from .verify import verify

__all__ = ["ExportResult", "export", "verification_frames", "file_sha256"]

@dataclass(frozen=True)
class ExportResult:
    path: Path | None
    meta: ArtifactMeta
    parity: ParityReport
    seconds: float
    file_bytes: int
    initializer_bytes: int

    def summary(self) -> str:
        p = self.parity
        lines = [
            f"{'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB, geometry tables {self.initializer_bytes / 1e6:.1f} MB)",
            f"model {self.meta.model_id}: {self.meta.architecture}, {len(self.meta.cameras)} cameras at {self.meta.image_size[0]}x{self.meta.image_size[1]}, {self.meta.num_boxes} boxes, rig {self.meta.rig_hash}",
            f"parity vs PyTorch on {p.frames} frames at {', '.join(map(str, p.threads))} thread(s): max |box| {p.max_box_abs_diff_m:.2e} m (tol {p.tolerance_box_m:g}), "
            f"max |score| {p.max_score_abs_diff:.2e} (tol {p.tolerance_score:g}), labels {'equal' if p.labels_equal else 'DIFFER'}, "
            f"order {'equal' if p.order_equal else f'equal up to {p.tie_swaps} swap(s) of tied scores'}, {p.unmatched} unmatched, "
            f"valid {'equal' if p.valid_equal else 'DIFFERS'} -> {'PASSED' if p.passed else 'FAILED'}",
            f"took {self.seconds:.1f} s",
        ]
        if self.path:
            lines.append(f"next: fisheye-infer detect {self.path} --images DIR --out result.json --viz result.png")
        return "\n".join(lines)


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def verification_frames(rig: Rig, count: int, seed: int = 0, images: str | Path | None = None) -> np.ndarray:
    """(F, N, H, W, 3) uint8: ``count`` seeded synthetic renders of the rig, then the user's frames.

    User frames come from a folder, as ``fisheye_infer.preprocess.frames_from_paths`` reads it.
    """
    renderer = Renderer(texture_seed=seed)
    frames = [renderer.render(rig, random_scene(np.random.default_rng(seed + i))) for i in range(count)]
    if images is not None:
        frames.extend(frame for _, frame in frames_from_paths([images], rig.names))
    if not frames:
        raise ExportError("verification needs at least one frame")
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    batch, _ = prepare_batch(frames, rig.names, (width, height))
    return batch


def _tool_versions() -> dict[str, str]:
    return {"fisheye_infer": __version__, "torch": torch.__version__, "onnx": onnx.__version__, "onnxruntime": ort.__version__, "opset": str(OPSET), "python": platform.python_version()}


def export(
    ckpt: str | Path,
    out: str | Path,
    *,
    arch: str | None = None,
    config: str | Path | object | None = None,
    rig: str | Path | Rig | None = None,
    geometry: str = "verify",
    verify_images: str | Path | None = None,
    frames: int = 2,
    threads: Sequence[int] = (1, 2),
    force: bool = False,
    allow_pickle: bool = False,
    progress: Callable[[str], None] = print,
) -> ExportResult:
    """Export ``ckpt`` to ``out``; see the module docstring. Raises ``ParityError`` when parity fails.

    ``config`` is the official config file the checkpoint was trained with (read, never executed)
    or a configuration object; by default the official configuration of the architecture.
    """
    from fisheye_infer.models import load_checkpoint, load_model

    start = time.perf_counter()
    out = Path(out)
    ckpt = Path(ckpt)
    if out.suffix != ".onnx":
        raise ExportError(f"--out {out}: expected a path ending in .onnx")
    progress(f"[1/5] reading {ckpt}")
    state_dict, _ = load_checkpoint(ckpt, allow_pickle=allow_pickle)
    name = arch or infer_architecture(state_dict)
    spec = get_arch(name)
    cfg = spec.read_config(Path(config)) if isinstance(config, (str, Path)) else config
    the_rig = rig if isinstance(rig, Rig) else resolve_rig(rig)

    progress(f"[2/5] building {name} for rig {the_rig.name!r} ({the_rig.hash}) and loading the checkpoint strictly")
    model, report = load_model(name, {"state_dict": state_dict}, cfg, the_rig, geometry=geometry)
    width, height = spec.image_size(model)
    try:
        the_rig.require(the_rig.names, (width, height))
    except RigError as exc:
        raise ExportError(f"rig does not fit the model: {exc}") from exc
    progress(f"      geometry tables from the {report.source}")

    progress("[3/5] tracing to ONNX (geometry as named initializers)")
    tables = {k: v.detach().cpu().numpy() for k, v in model.geometry_tables().items()}
    proto = trace_to_onnx(model, tables, spec.num_points(model), (height, width), len(the_rig))

    mean, std = spec.normalisation(model)
    rig_hash = the_rig.hash
    ckpt_sha = file_sha256(ckpt)
    meta = ArtifactMeta(
        architecture=name,
        model_id=f"{name}-{rig_hash[:8]}-{ckpt_sha[:8]}",
        classes=spec.classes(model),
        cameras=tuple(the_rig.names),
        image_size=(width, height),
        normalisation=Normalisation(mean=mean, std=std),
        num_boxes=spec.num_boxes(model),
        score_semantics=spec.score_semantics,
        rig=the_rig,
        rig_hash=rig_hash,
        geometry=model.geometry_params(),
        geometry_source="checkpoint" if report.source == "checkpoint" else "rig",
        geometry_initializers=tuple(tables),
        checkpoint_sha256=ckpt_sha,
        tools=_tool_versions(),
    )
    weights = spec.rebake_weights(model)
    extra = {REBAKE_WEIGHTS_KEY: encode_arrays(weights)} if weights else {}
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        set_metadata(proto, meta, extra)
        save_model(proto, tmp)
        progress(f"[4/5] verifying in ONNX Runtime against PyTorch ({frames} seeded frame(s){' + ' + str(verify_images) if verify_images else ''})")
        batch = verification_frames(the_rig, frames, images=verify_images)
        parity = verify(tmp, model, batch, threads=threads)
        meta = meta.model_copy(update={"parity": parity})
        set_metadata(proto, meta, extra)
        written: Path | None = None
        if parity.passed or force:
            save_model(proto, tmp)
            os.replace(tmp, out)
            written = out
            progress(f"[5/5] wrote {out}")
    finally:
        tmp.unlink(missing_ok=True)
    geometry_bytes = sum(np.asarray(v).nbytes for v in tables.values())
    result = ExportResult(written, meta, parity, time.perf_counter() - start, out.stat().st_size if written else 0, geometry_bytes)
    if not parity.passed and not force:
        raise ParityError(f"the ONNX graph disagrees with PyTorch beyond tolerance; no file written (use --force to keep it)\n{result.summary()}")
    return result
