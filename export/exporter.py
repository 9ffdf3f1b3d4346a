"""``export``: checkpoint + rig -> one verified, self-contained ONNX file.

    result = export("fisheye_bevdet.pth", "model.onnx")            # default rig, arch from keys
    result = export(ckpt, out, config="fisheye_petr.py", rig="rig.yaml", verify_images="frames/")

Steps: read the checkpoint (weights-only), pick the architecture, build the plain-PyTorch model
for the rig and load the checkpoint strictly (its stored geometry is checked against the rig),
trace to ONNX with the geometry tables as named initializers (the ranking outputs the check
reads are traced too, and dropped from the file), write the metadata, then run the file in ONNX
Runtime against the PyTorch model in float64 on seeded synthetic frames (and the user's frames;
see ``verify``). The output file appears only when that check passes (or with ``force``);
nothing is left behind otherwise.
"""

from __future__ import annotations

import hashlib
import platform
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import onnx
import onnxruntime as ort
import torch

from fisheye_infer._version import __version__
from fisheye_infer.cameras.rig import Rig, resolve_rig
from fisheye_infer.errors import CheckpointError, ExportError, ParityError, RigError
from fisheye_infer.runtime.artifact import RANKING_OUTPUTS, ArtifactMeta, Normalisation
from fisheye_infer.tools.files import pending_file

from .frames import verification_frames
from .graph import REBAKE_WEIGHTS_KEY, encode_arrays, save_model, set_metadata, without_outputs
from .options import Comparison, Int8Options, options_from_keywords
from .reduced import export_fp16, export_int8, fp16_path_for, int8_path_for
from .results import ExportResult, Fp16Result, Int8Result, ReducedResult
from .tensorrt_check import check_tensorrt
from .trace import OPSET, trace_to_onnx
from .verify import Reference, verify

if TYPE_CHECKING:
    from fisheye_infer.models import GeometryReport, ModelEntry
    from fisheye_infer.models.base import FisheyeDetector

__all__ = [
    "Comparison",
    "ExportResult",
    "Fp16Result",
    "Int8Options",
    "Int8Result",
    "OpenedCheckpoint",
    "ReducedResult",
    "export",
    "export_fp16",
    "export_int8",
    "file_sha256",
    "fp16_path_for",
    "infer_architecture",
    "int8_path_for",
    "open_checkpoint",
    "verification_frames",
]


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def infer_architecture(state_dict: Mapping[str, object], config: str | Path | object | None = None) -> str:
    """The registered architecture the checkpoint's keys (narrowed down by ``config``, where given) name;
    refuse ambiguity."""
    from fisheye_infer.models import list_models, matching_architectures

    matches = matching_architectures(state_dict, config)
    if len(matches) == 1:
        return matches[0]
    if not matches:
        sample = ", ".join(list(state_dict)[:5])
        if config is not None and matching_architectures(state_dict):
            raise ExportError(
                f"the checkpoint fits {', '.join(matching_architectures(state_dict))}, but the configuration "
                f"({config if isinstance(config, (str, Path)) else type(config).__name__}) fits none of them"
            )
        raise ExportError(
            f"cannot tell the architecture from the checkpoint's keys (first keys: {sample}); pass --arch "
            f"({', '.join(list_models())})"
        )
    raise ExportError(
        f"the checkpoint fits several architectures ({', '.join(matches)}); pass --config (the official config "
        "file it was trained with) or --arch"
    )


def _architecture(
    state_dict: Mapping[str, object], arch: str | None, ckpt: Path, config: str | Path | object | None
) -> str:
    """``arch`` if given and not contradicted by the checkpoint's keys, else the one the keys (and ``config``) name."""
    from fisheye_infer.models import list_models, matching_architectures

    if arch is None:
        return infer_architecture(state_dict, config)
    if arch not in list_models():
        raise ExportError(f"architecture {arch!r} cannot be exported (known: {', '.join(list_models())})")
    found = matching_architectures(state_dict)
    if found and arch not in found:  # keys of no known architecture: strict loading names what is wrong
        raise ExportError(
            f"--arch {arch}: checkpoint {ckpt.name} holds a {' or '.join(found)} model (its keys say so); "
            f"pass {' or '.join(f'--arch {f}' for f in found)}, or omit --arch"
        )
    return arch


def _initializer_bytes(model: onnx.ModelProto) -> int:
    """Bytes of every initializer's data (raw or typed fields), as the file stores them."""
    return sum(
        len(i.raw_data)
        if i.HasField("raw_data")
        else int(np.prod(i.dims, dtype=np.int64)) * onnx.helper.tensor_dtype_to_np_dtype(i.data_type).itemsize
        for i in model.graph.initializer
    )


def _tool_versions() -> dict[str, str]:
    return {
        "fisheye_infer": __version__,
        "torch": torch.__version__,
        "onnx": onnx.__version__,
        "onnxruntime": ort.__version__,
        "opset": str(OPSET),
        "python": platform.python_version(),
    }


@dataclass(frozen=True)
class OpenedCheckpoint:
    """A checkpoint file in its plain-PyTorch model, built for a rig, strictly loaded, in eval mode."""

    name: str
    entry: ModelEntry
    model: FisheyeDetector
    rig: Rig
    geometry: GeometryReport

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the camera images the model takes."""
        return self.model.config.preprocess.image_size


def open_checkpoint(
    ckpt: str | Path,
    *,
    arch: str | None = None,
    config: str | Path | object | None = None,
    rig: str | Path | Rig | None = None,
    geometry: str = "verify",
    allow_pickle: bool = False,
    progress: Callable[[str, Rig], None] | None = None,
) -> OpenedCheckpoint:
    """Read ``ckpt`` (weights only), pick its architecture, build the model for the rig, load strictly.

    The arguments mean what they mean for ``export``; the model is what export traces, and what
    a PyTorch-side evaluation (``TorchDetector``) runs.
    """
    from fisheye_infer.models import create_model, get_model_entry, load_checkpoint, load_official_state_dict

    ckpt = Path(ckpt)
    state_dict, _ = load_checkpoint(ckpt, allow_pickle=allow_pickle)
    name = _architecture(state_dict, arch, ckpt, config)
    entry = get_model_entry(name)
    cfg = entry.config_cls.from_mmdet3d_config(Path(config)) if isinstance(config, (str, Path)) else config
    the_rig = rig if isinstance(rig, Rig) else resolve_rig(rig)
    if progress is not None:
        progress(name, the_rig)
    model = create_model(name, cfg, the_rig)
    width, height = model.config.preprocess.image_size
    try:  # before the checkpoint's geometry is compared, which would blame the calibration instead
        the_rig.require(the_rig.names, (width, height))
    except RigError as exc:
        raise ExportError(f"rig {the_rig.name!r} does not fit the {name} configuration: {exc}") from exc
    try:
        report = load_official_state_dict(
            model, state_dict, geometry=geometry, ignore=entry.ignored_keys, context=f"{name} checkpoint {ckpt.name}"
        )
    except CheckpointError as exc:
        if "does not fit the model" not in str(exc):
            raise
        if isinstance(config, (str, Path)):
            source = f"--config {config}"
        else:
            source = "the configuration given" if config is not None else f"the official {name} configuration"
        raise CheckpointError(
            f"{exc}\n(model built from {source}; pass the config the checkpoint was trained with)"
        ) from None
    return OpenedCheckpoint(name, entry, model.eval(), the_rig, report)


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
    int8: Int8Options | bool | None = None,
    fp16: bool = False,
    comparison: Comparison | None = None,
    progress: Callable[[str], None] = print,
    **legacy: Any,
) -> ExportResult:
    """Export a checkpoint to one verified, self-contained ONNX file, and optionally its int8 and fp16 files.

    The checkpoint is read (weights only), its architecture picked, the plain-PyTorch model built for the rig and
    loaded strictly, then traced to ONNX with the geometry tables as named initializers. The file is run in ONNX
    Runtime against the PyTorch model in float64 on seeded synthetic frames (plus ``verify_images``) at each of
    ``threads``, and appears at ``out`` only when that check passes (or with ``force``); nothing is left behind
    otherwise. Every file's metadata carries the parity report and
    [`check_tensorrt`][fisheye_infer.export.tensorrt_check.check_tensorrt]'s verdict on its graph. ``out`` always
    stays the fp32 file; the reduced files go next to it ([`export_int8`][fisheye_infer.export.reduced.export_int8],
    [`export_fp16`][fisheye_infer.export.reduced.export_fp16]).

    Args:
        ckpt (str | Path): The checkpoint (``.pth``) to export.
        out (str | Path): The ONNX file to write; must end in ``.onnx``.
        arch (str | None): The registered architecture (``fisheye-bevdet``, ``fisheye-petr``, ...); None infers it
            from the checkpoint's keys (and ``config``).
        config (str | Path | object | None): The official config file the checkpoint was trained with (read, never
            executed) or a configuration object; None for the architecture's official configuration.
        rig (str | Path | Rig | None): The cameras: a rig file or folder, ``default``, or a ``Rig``; None for the
            default rig.
        geometry (str): The geometry tables stored in the checkpoint against those recomputed for the rig:
            ``verify`` (they must agree), ``checkpoint`` (use the stored ones) or ``rig`` (use the recomputed ones).
        verify_images (str | Path | None): A folder of your own frames added to the parity check (and to the
            reduced files' comparison); None for synthetic frames only.
        frames (int): Seeded synthetic frames for the check against PyTorch.
        threads (Sequence[int]): ONNX Runtime thread counts the file is checked at; the last one also runs the
            reduced files' comparison.
        force (bool): Write the files even when their check fails (the result still reports the failure).
        allow_pickle (bool): Read a checkpoint that holds arbitrary Python objects; this can run code from the
            file, so only for trusted checkpoints.
        int8 (Int8Options | bool | None): Also write the int8 file (``model.onnx`` -> ``model.int8.onnx``): an
            [`Int8Options`][fisheye_infer.export.options.Int8Options], or True for the default options; None or
            False for none.
        fp16 (bool): Also write the float16 file for GPU execution providers (``model.fp16.onnx``).
        comparison (Comparison | None): How the reduced files are judged against the fp32 file
            ([`Comparison`][fisheye_infer.export.options.Comparison]); None for ``Comparison`` with
            ``verify_images`` and the last of ``threads``.
        progress (Callable[[str], None]): Called with one line per step; ``print`` by default.
        **legacy (Any): The previous release's keywords (``calib_images=``, ``min_kept=``, ...), folded into
            ``int8`` and ``comparison`` with a ``DeprecationWarning``.

    Returns:
        ExportResult: The written file (or None), its metadata, its parity report, sizes, time, and the int8 and fp16
            results where asked for.

    Raises:
        ExportError: ``out`` does not end in ``.onnx``, the architecture cannot be told or does not fit, or the rig
            does not fit the configuration.
        CheckpointError: The checkpoint cannot be read, its keys or shapes do not fit the model, or its stored
            geometry differs from the rig's with ``geometry="verify"``.
        RigError: The rig cannot be read.
        ParityError: The fp32 file disagrees with PyTorch beyond tolerance (no file written), or an int8 or fp16 file
            finds too few of the fp32 file's boxes (the fp32 file is kept); not with ``force``.
        TypeError: An unknown keyword argument.

    Examples:
        ```python
        from fisheye_infer.export.exporter import export
        from fisheye_infer.export.options import Comparison, Int8Options

        result = export("fisheye_bevdet.pth", "model.onnx", rig="rig.yaml", verify_images="frames/")
        print(result.summary())
        result = export("fisheye_petr.pth", "petr.onnx", config="fisheye_petr.py",
                        int8=Int8Options(calib_images="frames/"), fp16=True, comparison=Comparison(frames=8))
        print(result.int8.path, result.fp16.path)  # petr.int8.onnx petr.fp16.onnx
        ```
    """
    start = time.perf_counter()
    out = Path(out)
    ckpt = Path(ckpt)
    if out.suffix != ".onnx":
        raise ExportError(f"--out {out}: expected a path ending in .onnx")
    int8_options = Int8Options() if int8 is True else (int8 or None)
    int8_options, comparison = options_from_keywords(
        int8_options, comparison or Comparison(images=verify_images, threads=threads[-1]), legacy, caller="export"
    )
    if not int8:
        int8_options = None
    progress(f"[1/5] reading {ckpt}")
    loaded = open_checkpoint(
        ckpt,
        arch=arch,
        config=config,
        rig=rig,
        geometry=geometry,
        allow_pickle=allow_pickle,
        progress=lambda name, r: progress(
            f"[2/5] building {name} for rig {r.name!r} ({r.hash}) and loading the checkpoint strictly"
        ),
    )
    name, entry, model, the_rig, report = loaded.name, loaded.entry, loaded.model, loaded.rig, loaded.geometry
    pre = model.config.preprocess
    width, height = pre.image_size
    progress(f"      geometry tables from the {report.source}")

    progress("[3/5] tracing to ONNX (geometry as named initializers)")
    tables = {k: v.detach().cpu().numpy() for k, v in model.geometry_tables().items()}
    proto = without_outputs(trace_to_onnx(model, tables, (height, width), len(the_rig)), RANKING_OUTPUTS)

    rig_hash = the_rig.hash
    ckpt_sha = file_sha256(ckpt)
    meta = ArtifactMeta(
        architecture=name,
        model_id=f"{name}-{rig_hash[:8]}-{ckpt_sha[:8]}",
        classes=pre.classes,
        cameras=tuple(the_rig.names),
        image_size=(width, height),
        colour_order=pre.colour_order,
        normalisation=Normalisation(mean=pre.mean, std=pre.std),
        num_boxes=model.config.num_boxes,
        score_semantics=entry.score_semantics,
        rig=the_rig,
        rig_hash=rig_hash,
        geometry=model.geometry_params(),
        geometry_source="checkpoint" if report.source == "checkpoint" else "rig",
        geometry_initializers=tuple(tables),
        checkpoint_sha256=ckpt_sha,
        tools=_tool_versions(),
        tensorrt=check_tensorrt(proto),
    )
    weights = model.table_weights()
    extra = {REBAKE_WEIGHTS_KEY: encode_arrays(weights)} if weights else {}
    with pending_file(out) as pending:
        set_metadata(proto, meta, extra)
        save_model(proto, pending.path)
        progress(
            f"[4/5] verifying in ONNX Runtime against PyTorch ({frames} seeded "
            f"frame(s){' + ' + str(verify_images) if verify_images else ''})"
        )
        batch = verification_frames(the_rig, frames, images=verify_images)
        parity = verify(pending.path, Reference(model, batch), threads=threads)
        meta = meta.model_copy(update={"parity": parity})
        set_metadata(proto, meta, extra)
        written: Path | None = None
        if parity.passed or force:
            save_model(proto, pending.path)
            written = pending.commit()
            progress(f"[5/5] wrote {out}")
    geometry_bytes = sum(np.asarray(v).nbytes for v in tables.values())
    result = ExportResult(
        written,
        meta,
        parity,
        time.perf_counter() - start,
        out.stat().st_size if written else 0,
        _initializer_bytes(proto),
        geometry_bytes,
    )
    if not parity.passed and not force:
        raise ParityError(
            "the ONNX graph disagrees with PyTorch beyond tolerance; no file written "
            f"(use --force to keep it)\n{result.summary()}"
        )
    if int8_options is not None and written is not None:
        quant = export_int8(written, options=int8_options, comparison=comparison, force=force, progress=progress)
        result = replace(result, seconds=time.perf_counter() - start, int8=quant)
        if not quant.parity.passed and not force:
            raise ParityError(
                "the int8 file finds too few of the fp32 file's boxes; fp32 file kept, no int8 file written (choose "
                "the float32 layers by hand with --int8-float or --int8-scope, calibrate on your own frames with "
                f"--calib-images, accept a lower share with --min-kept, or use --force to keep it)\n{result.summary()}"
            )
    if fp16 and written is not None:
        half = export_fp16(written, comparison=comparison, force=force, progress=progress)
        result = replace(result, seconds=time.perf_counter() - start, fp16=half)
        if not half.parity.passed and not force:
            raise ParityError(
                "the fp16 file finds too few of the fp32 file's boxes; fp32 file kept, no fp16 file written "
                f"(accept a lower share with --min-kept, or use --force to keep it)\n{result.summary()}"
            )
    return result
