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
import os
import platform
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import onnx
import onnxruntime as ort
import torch

from fisheye_infer._version import __version__
from fisheye_infer.artifact import COMPARE_FRAMES, MIN_TOP_MATCHED, RANKING_OUTPUTS, ArtifactMeta, Normalisation, ParityReport, Quantization
from fisheye_infer.errors import CheckpointError, ExportError, ParityError, RigError
from fisheye_infer.preprocess import frames_from_paths, prepare_batch
from fisheye_infer.rig import Rig, resolve_rig
from fisheye_infer.synth import Renderer, random_scene

from .fp16 import to_float16
from .fp16_parity import fp16_parity
from .graph import REBAKE_WEIGHTS_KEY, encode_arrays, save_model, set_metadata, without_outputs
from .quantize import SCOPES, WEIGHT_BITS, FrameReader, architecture_float, int8_parity, int8_path_for, quantize, quantized_scope
from .tensorrt_check import check_tensorrt
from .trace import OPSET, trace_to_onnx
from .verify import verify

if TYPE_CHECKING:
    from fisheye_infer.models import GeometryReport, ModelEntry

__all__ = ["ExportResult", "Fp16Result", "Int8Result", "OpenedCheckpoint", "ReducedResult", "export", "export_fp16", "export_int8", "fp16_path_for",
           "infer_architecture", "open_checkpoint", "verification_frames", "file_sha256"]

#: Calibration frames are rendered from seeds offset by this, so they never coincide with the
#: verification frames (seeds 0, 1, ...) the int8 file is judged on.
CALIBRATION_SEED = 1000


@dataclass(frozen=True)
class ReducedResult:
    """A reduced-precision file derived from a verified fp32 file: where it went (None: not written,
    its parity failed), its metadata and parity, how long it took and its size."""

    path: Path | None
    meta: ArtifactMeta
    parity: ParityReport
    seconds: float
    file_bytes: int


class Int8Result(ReducedResult):
    """The int8 file written next to the fp32 one (``export_int8``)."""

    def summary(self) -> str:
        p, q = self.parity, self.meta.quantization
        how = (f"{q.mode}, {q.scope}, {q.weight_bits}-bit weights, calibrated on {q.calibration_frames} frame(s)" if q is not None
               else "not quantized")
        return "\n".join([
            f"int8 {'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; {how})",
            f"int8 vs the fp32 ONNX file on {p.frames} frames: {_kept(p)} of the top-50 boxes matched within "
            f"{p.tolerance_box_m:g} m with the same label (need {_needed(p):.0%}) -> {'PASSED' if p.passed else 'FAILED'}; took {self.seconds:.1f} s",
            *_by_score_lines(p),
            *_tensorrt_lines(self.meta, "int8 file: "),
        ])


class Fp16Result(ReducedResult):
    """The fp16 file written next to the fp32 one (``export_fp16``)."""

    def summary(self) -> str:
        p, q = self.parity, self.meta.quantization
        lines = [
            f"fp16 {'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; {q.scope if q else 'not reduced'})",
            f"fp16 vs the fp32 ONNX file on {p.frames} frames ({p.evaluated_with}): {_kept(p)} of the top-50 boxes matched within "
            f"{p.tolerance_box_m:g} m with the same label (need {_needed(p):.0%}; matched max |box| {p.max_box_abs_diff_m:.3f} m, "
            f"|score| {p.max_score_abs_diff:.4f}) -> {'PASSED' if p.passed else 'FAILED'}; took {self.seconds:.1f} s",
            *_by_score_lines(p),
        ]
        if p.replayed is not None:
            r = p.replayed
            lines.append(f"  at the fp16 file's own top-k choice: {r.top_matched_fraction:.1%} matched; position by position max |box| "
                         f"{r.max_box_abs_diff_m:.3f} m, |score| {r.max_score_abs_diff:.4f}; dense scores max |diff| {p.max_rank_score_abs_diff or 0.0:.4f}")
        lines += [f"  {problem}" for problem in p.problems]
        return "\n".join(lines + _tensorrt_lines(self.meta, "fp16 file: "))


def _kept(p: ParityReport) -> str:
    """"91.2% +- 1.1%": the share of the fp32 top-50 boxes found again and its standard error over the frames."""
    spread = f" +- {p.top_matched_standard_error:.1%}" if p.top_matched_standard_error else ""
    return f"{p.top_matched_fraction or 0.0:.1%}{spread}"


def _by_score_lines(p: ParityReport) -> list[str]:
    """The share kept per band of the fp32 box's score: what a detection threshold would keep."""
    if not p.top_matched_by_score:
        return []
    bands = [f"{band} {m / c:.1%} of {c}" for band, (m, c) in p.top_matched_by_score.items() if c]
    return ["  by the fp32 box's score: " + ", ".join(bands)]


def _needed(p: ParityReport) -> float:
    return p.min_top_matched if p.min_top_matched is not None else MIN_TOP_MATCHED  # files written before the bar was recorded


def _tensorrt_lines(meta: ArtifactMeta, prefix: str = "") -> list[str]:
    return [prefix + meta.tensorrt.summary()] if meta.tensorrt is not None else []


@dataclass(frozen=True)
class ExportResult:
    path: Path | None
    meta: ArtifactMeta
    parity: ParityReport
    seconds: float
    file_bytes: int
    initializer_bytes: int  # every initializer: weights and geometry tables
    geometry_bytes: int  # the ``geom.*`` initializers alone
    int8: Int8Result | None = None
    fp16: Fp16Result | None = None

    def summary(self) -> str:
        p = self.parity
        lines = [
            f"{'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; initializers "
            f"{self.initializer_bytes / 1e6:.1f} MB, of which geometry tables {self.geometry_bytes / 1e6:.1f} MB)",
            f"model {self.meta.model_id}: {self.meta.architecture}, {len(self.meta.cameras)} cameras at "
            f"{self.meta.image_size[0]}x{self.meta.image_size[1]}, {self.meta.num_boxes} boxes, rig {self.meta.rig_hash}",
            f"parity vs PyTorch float64 on {p.frames} frames at {', '.join(map(str, p.threads))} thread(s) "
            f"(PyTorch float32 itself: dense {_f32(p, 0)}, box {_f32(p, 1)} m, score {_f32(p, 2)}):",
            f"  scores before ranking max |diff| {p.max_rank_score_abs_diff or 0.0:.2e} (tol {p.tolerance_rank_score or p.tolerance_score:.1e}); "
            f"top-k choice: {_choice(p)}",
            f"  at that choice max |box| {p.max_box_abs_diff_m:.2e} m (tol {p.tolerance_box_m:.1e}), max |score| {p.max_score_abs_diff:.2e} "
            f"(tol {p.tolerance_score:.1e}), labels {'equal' if p.labels_equal else 'DIFFER'}, valid {'equal' if p.valid_equal else 'DIFFERS'}, "
            f"{p.unmatched} box(es) off{'; the written file DIFFERS from the checked graph' if p.written_equals_checked is False else ''} "
            f"-> {'PASSED' if p.passed else 'FAILED'}",
            *(f"  {problem}" for problem in p.problems),
            *_tensorrt_lines(self.meta),
            f"took {self.seconds:.1f} s",
        ]
        if self.int8 is not None:
            lines.append(self.int8.summary())
        if self.fp16 is not None:
            lines.append(self.fp16.summary())
        if self.path:
            lines.append(f"next: fisheye-infer detect {self.path} --images DIR --out result.json --viz result.png")
        if self.int8 is not None and self.int8.path:
            lines.append(f"      fisheye-infer detect {self.int8.path} ...   (int8); fisheye-infer bench {self.int8.path}")
        if self.fp16 is not None and self.fp16.path:
            lines.append(f"      {self.fp16.path}: for GPU execution providers (CUDA, TensorRT)")
        return "\n".join(lines)


def _f32(p: ParityReport, i: int) -> str:
    return f"{p.pytorch_float32[i]:.1e}" if p.pytorch_float32 else "-"


def _choice(p: ParityReport) -> str:
    """How the graph's top-k choice relates to PyTorch's, in words."""
    if p.order_equal:
        return "PyTorch float32's own"
    if p.selection_valid:
        return f"a top-k of its scores, ties broken otherwise than PyTorch float32 ({p.tie_substitutions} substitution(s), {p.tie_swaps} position(s))"
    return "NOT a top-k of its own scores"


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


def infer_architecture(state_dict: Mapping[str, object], config: str | Path | object | None = None) -> str:
    """The registered architecture the checkpoint's keys (narrowed down by ``config``, where given) name; refuse ambiguity."""
    from fisheye_infer.models import list_models, matching_architectures

    matches = matching_architectures(state_dict, config)
    if len(matches) == 1:
        return matches[0]
    if not matches:
        sample = ", ".join(list(state_dict)[:5])
        if config is not None and matching_architectures(state_dict):
            raise ExportError(f"the checkpoint fits {', '.join(matching_architectures(state_dict))}, but the configuration "
                              f"({config if isinstance(config, (str, Path)) else type(config).__name__}) fits none of them")
        raise ExportError(f"cannot tell the architecture from the checkpoint's keys (first keys: {sample}); pass --arch ({', '.join(list_models())})")
    raise ExportError(f"the checkpoint fits several architectures ({', '.join(matches)}); pass --config (the official config "
                      "file it was trained with) or --arch")


def _architecture(state_dict: Mapping[str, object], arch: str | None, ckpt: Path, config: str | Path | object | None) -> str:
    """``arch`` if given and not contradicted by the checkpoint's keys, else the one the keys (and ``config``) name."""
    from fisheye_infer.models import list_models, matching_architectures

    if arch is None:
        return infer_architecture(state_dict, config)
    if arch not in list_models():
        raise ExportError(f"architecture {arch!r} cannot be exported (known: {', '.join(list_models())})")
    found = matching_architectures(state_dict)
    if found and arch not in found:  # keys of no known architecture: strict loading names what is wrong
        raise ExportError(f"--arch {arch}: checkpoint {ckpt.name} holds a {' or '.join(found)} model (its keys say so); "
                          f"pass {' or '.join(f'--arch {f}' for f in found)}, or omit --arch")
    return arch


def _initializer_bytes(model: onnx.ModelProto) -> int:
    """Bytes of every initializer's data (raw or typed fields), as the file stores them."""
    return sum(len(i.raw_data) if i.HasField("raw_data") else int(np.prod(i.dims, dtype=np.int64)) * onnx.helper.tensor_dtype_to_np_dtype(i.data_type).itemsize
               for i in model.graph.initializer)


def _tool_versions() -> dict[str, str]:
    return {"fisheye_infer": __version__, "torch": torch.__version__, "onnx": onnx.__version__, "onnxruntime": ort.__version__,
            "opset": str(OPSET), "python": platform.python_version()}


@dataclass(frozen=True)
class OpenedCheckpoint:
    """A checkpoint file in its plain-PyTorch model, built for a rig, strictly loaded, in eval mode."""

    name: str
    entry: ModelEntry
    model: torch.nn.Module
    rig: Rig
    geometry: GeometryReport

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of the camera images the model takes."""
        return self.model.config.preprocess.image_size  # type: ignore[no-any-return]


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
        report = load_official_state_dict(model, state_dict, geometry=geometry, ignore=entry.ignored_keys,
                                          context=f"{name} checkpoint {ckpt.name}")
    except CheckpointError as exc:
        if "does not fit the model" not in str(exc):
            raise
        if isinstance(config, (str, Path)):
            source = f"--config {config}"
        else:
            source = "the configuration given" if config is not None else f"the official {name} configuration"
        raise CheckpointError(f"{exc}\n(model built from {source}; pass the config the checkpoint was trained with)") from None
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
    int8: bool = False,
    calib_images: str | Path | None = None,
    calib_frames: int = 8,
    int8_scope: str = "network",
    int8_float: Sequence[str] | None = None,
    fp16: bool = False,
    compare_frames: int = COMPARE_FRAMES,
    min_kept: float = MIN_TOP_MATCHED,
    progress: Callable[[str], None] = print,
) -> ExportResult:
    """Export ``ckpt`` to ``out``; see the module docstring. Raises ``ParityError`` when parity fails.

    ``config`` is the official config file the checkpoint was trained with (read, never executed)
    or a configuration object; by default the official configuration of the architecture.
    ``int8``: once the fp32 file is written, also write ``export_int8``'s file next to it
    (``model.onnx`` -> ``model.int8.onnx``) quantized over ``int8_scope`` (``quantize.SCOPES``), with
    the modules of ``int8_float`` left float32 (default: the architecture's ``int8_float``);
    ``out`` always stays the verified fp32 file. ``fp16``: likewise ``export_fp16``'s file (``model.fp16.onnx``), for GPU execution providers.
    Each reduced file is compared with the fp32 file on ``compare_frames`` seeded frames (plus
    ``verify_images``) and written when it finds ``min_kept`` of the fp32 top-50 boxes again.
    Every file's metadata carries ``check_tensorrt``'s verdict on its graph (``tensorrt``).
    """
    start = time.perf_counter()
    out = Path(out)
    ckpt = Path(ckpt)
    if out.suffix != ".onnx":
        raise ExportError(f"--out {out}: expected a path ending in .onnx")
    if int8_scope not in SCOPES:
        raise ExportError(f"--int8-scope {int8_scope}: expected one of {', '.join(SCOPES)}")
    if int8 and calib_frames < 0:
        raise ExportError(f"--calib-frames {calib_frames}: expected 0 or more synthetic calibration frames")
    if int8 and calib_frames == 0 and calib_images is None:
        raise ExportError("--calib-frames 0 without --calib-images: int8 calibration needs at least one frame")
    if calib_images is not None and not Path(calib_images).exists():
        raise ExportError(f"--calib-images {calib_images}: no such file or folder")
    if int8 or fp16:
        _check_comparison(compare_frames, verify_images, min_kept)
    progress(f"[1/5] reading {ckpt}")
    loaded = open_checkpoint(ckpt, arch=arch, config=config, rig=rig, geometry=geometry, allow_pickle=allow_pickle,
                        progress=lambda name, r: progress(f"[2/5] building {name} for rig {r.name!r} ({r.hash}) and loading the checkpoint strictly"))
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
    result = ExportResult(written, meta, parity, time.perf_counter() - start, out.stat().st_size if written else 0,
                          _initializer_bytes(proto), geometry_bytes)
    if not parity.passed and not force:
        raise ParityError(f"the ONNX graph disagrees with PyTorch beyond tolerance; no file written (use --force to keep it)\n{result.summary()}")
    if int8 and written is not None:
        quant = export_int8(written, calib_images=calib_images, calib_frames=calib_frames, scope=int8_scope, keep_float=int8_float,
                            frames=compare_frames, verify_images=verify_images, min_kept=min_kept, threads=threads[-1], force=force,
                            progress=progress)
        result = ExportResult(result.path, result.meta, result.parity, time.perf_counter() - start, result.file_bytes,
                              result.initializer_bytes, result.geometry_bytes, quant)
        if not quant.parity.passed and not force:
            raise ParityError("the int8 file finds too few of the fp32 file's boxes; fp32 file kept, no int8 file written "
                              "(keep more layers float32 with --int8-float or --int8-scope trunk, calibrate on your own frames "
                              f"with --calib-images, accept a lower share with --min-kept, or use --force to keep it)\n{result.summary()}")
    if fp16 and written is not None:
        half = export_fp16(written, frames=compare_frames, verify_images=verify_images, min_kept=min_kept, threads=threads[-1], force=force,
                           progress=progress)
        result = ExportResult(result.path, result.meta, result.parity, time.perf_counter() - start, result.file_bytes,
                              result.initializer_bytes, result.geometry_bytes, result.int8, half)
        if not half.parity.passed and not force:
            raise ParityError("the fp16 file finds too few of the fp32 file's boxes; fp32 file kept, no fp16 file written "
                              f"(accept a lower share with --min-kept, or use --force to keep it)\n{result.summary()}")
    return result


def fp16_path_for(fp32_path: str | Path) -> Path:
    """Where the fp16 file of ``model.onnx`` goes: ``model.fp16.onnx`` next to it."""
    path = Path(fp32_path)
    return path.with_name(f"{path.stem}.fp16{path.suffix}")


def export_fp16(
    fp32_path: str | Path,
    out: str | Path | None = None,
    *,
    frames: int = COMPARE_FRAMES,
    verify_images: str | Path | None = None,
    min_kept: float = MIN_TOP_MATCHED,
    threads: int = 2,
    force: bool = False,
    progress: Callable[[str], None] = print,
) -> Fp16Result:
    """A verified fp32 file -> its float16 file for GPU execution providers; see ``fp16`` and ``fp16_parity``.

    Evidence: the fp16 file against the fp32 file on ``frames`` seeded frames (the fp32 export's
    verification frames and more) plus ``verify_images``, in ONNX Runtime's CPU execution provider;
    the file is written only when ``min_kept`` of the fp32 top-50 boxes are found again (or with ``force``). Its metadata
    carries a ``Quantization(mode="fp16")`` record, the ``ParityReport`` (``reference="fp32-onnx"``)
    and ``check_tensorrt``'s verdict on the fp16 graph.
    """
    start = time.perf_counter()
    src = Path(fp32_path)
    out = Path(out) if out is not None else fp16_path_for(src)
    _check_comparison(frames, verify_images, min_kept)
    meta = _fp32_meta(src, "fp16", "already a reduced-precision file")
    progress("fp16 [1/2] converting weights and compute to float16 (geometry tables, index arithmetic and the interface stay as in fp32)")
    proto, plan = to_float16(onnx.load(str(src)))
    tmp = out.with_name(f".{out.name}.{os.getpid()}.h.tmp")
    try:
        save_model(proto, tmp)
        batch = _comparison_frames(meta, frames, verify_images, "fp16 [2/2]", progress)
        parity = fp16_parity(src, tmp, batch, threads=threads, min_fraction=min_kept)
        written, half_meta = _write_reduced(proto, meta, parity, Quantization(mode="fp16", scope=plan.scope()), tmp, out, force)
    finally:
        tmp.unlink(missing_ok=True)
    return Fp16Result(written, half_meta, parity, time.perf_counter() - start, out.stat().st_size if written else 0)


def export_int8(
    fp32_path: str | Path,
    out: str | Path | None = None,
    *,
    calib_images: str | Path | None = None,
    calib_frames: int = 8,
    scope: str = "network",
    keep_float: Sequence[str] | None = None,
    frames: int = COMPARE_FRAMES,
    verify_images: str | Path | None = None,
    min_kept: float = MIN_TOP_MATCHED,
    threads: int = 2,
    force: bool = False,
    weight_bits: int = WEIGHT_BITS,
    progress: Callable[[str], None] = print,
) -> Int8Result:
    """A verified fp32 file -> its static-QDQ int8 file over ``scope`` (``quantize.SCOPES``); see ``quantize``.
    ``keep_float``: modules left float32 (default: the architecture's ``int8_float``). ``weight_bits``: 7,
    or 8 only to measure what 7 costs (``quantize.WEIGHT_BITS`` says why).

    Calibration: ``calib_frames`` seeded synthetic renders of the file's own rig (seeds from
    ``CALIBRATION_SEED``, disjoint from the verification seeds) plus the user's frames from
    ``calib_images``. Evidence: the int8 file against the fp32 file on ``frames`` seeded frames
    (the fp32 export's verification frames and more) plus ``verify_images``; the file is written
    only when ``min_kept`` of the fp32 top-50 boxes are found again (or with ``force``). The result carries a ``ParityReport``
    with ``reference="fp32-onnx"`` and a ``Quantization`` record in its metadata.
    """
    start = time.perf_counter()
    src = Path(fp32_path)
    out = Path(out) if out is not None else int8_path_for(src)
    _check_comparison(frames, verify_images, min_kept)
    meta = _fp32_meta(src, "int8", "already quantized")
    progress(f"int8 [1/3] rendering {calib_frames} calibration frame(s){' + ' + str(calib_images) if calib_images else ''}")
    calibration = verification_frames(meta.rig, calib_frames, seed=CALIBRATION_SEED, images=calib_images)
    tmp = out.with_name(f".{out.name}.{os.getpid()}.q.tmp")
    try:
        progress(f"int8 [2/3] static QDQ quantization, scope {scope} (U8 activations, S8 per-channel {weight_bits}-bit weights)")
        chosen_by = "the architecture's int8_float" if keep_float is None else "asked for at export"
        keep_float = architecture_float(src) if keep_float is None else tuple(keep_float)
        quantize(src, tmp, FrameReader(calibration), scope=scope, keep_float=keep_float, weight_bits=weight_bits)
        proto = onnx.load(str(tmp))
        covered = quantized_scope(onnx.load(str(src), load_external_data=False), scope, keep_float, chosen_by)
        batch = _comparison_frames(meta, frames, verify_images, "int8 [3/3]", progress)
        parity = int8_parity(src, tmp, batch, threads=threads, min_fraction=min_kept)
        quantization = Quantization(mode="int8-qdq", scope=covered, calibration_frames=len(calibration), weight_bits=weight_bits)
        written, quant_meta = _write_reduced(proto, meta, parity, quantization, tmp, out, force)
    finally:
        tmp.unlink(missing_ok=True)
    return Int8Result(written, quant_meta, parity, time.perf_counter() - start, out.stat().st_size if written else 0)


# -- the reduced-precision files (int8, fp16): derived from a verified fp32 file, judged against it ------


def _fp32_meta(src: Path, kind: str, already: str) -> ArtifactMeta:
    """The metadata of the fp32 file a reduced file is made from; a reduced file is refused."""
    from fisheye_infer.artifact import read_meta

    meta = read_meta(src)
    if meta.quantization is not None:
        raise ExportError(f"{kind}: {src} is {already} ({meta.quantization.mode}); give the fp32 file")
    return meta


def _check_comparison(frames: int, verify_images: str | Path | None, min_kept: float) -> None:
    """Refuse a reduced file's comparison that could not judge it, before anything is computed."""
    if frames < 0 or (frames == 0 and verify_images is None):
        raise ExportError(f"--compare-frames {frames}: expected 1 or more seeded frames (or 0 with --verify-images)")
    if not 0.0 < min_kept <= 1.0:
        raise ExportError(f"--min-kept {min_kept}: expected a share of the fp32 top-50 boxes in (0, 1], e.g. 0.9")


def _comparison_frames(meta: ArtifactMeta, frames: int, verify_images: str | Path | None, step: str,
                       progress: Callable[[str], None]) -> np.ndarray:
    """The frames a reduced file is compared on: seeded renders (the first ones are the fp32 export's own), then the user's."""
    progress(f"{step} comparing with the fp32 file on {frames} seeded frame(s){' + ' + str(verify_images) if verify_images else ''}")
    return verification_frames(meta.rig, frames, images=verify_images)


def _write_reduced(proto: onnx.ModelProto, meta: ArtifactMeta, parity: ParityReport, quantization: Quantization, tmp: Path, out: Path,
                   force: bool) -> tuple[Path | None, ArtifactMeta]:
    """The reduced file's metadata (its parity, what was reduced, the TensorRT check of its graph) and the file
    itself at ``out`` when its parity passed (or with ``force``): (path or None, metadata)."""
    suffix = "int8" if quantization.mode == "int8-qdq" else quantization.mode
    reduced = meta.model_copy(update={"model_id": f"{meta.model_id}-{suffix}", "parity": parity, "quantization": quantization,
                                      "tensorrt": check_tensorrt(proto)})
    set_metadata(proto, reduced)  # the re-baking key copied from the fp32 file stays
    if not (parity.passed or force):
        return None, reduced
    save_model(proto, tmp)
    os.replace(tmp, out)
    return out, reduced
