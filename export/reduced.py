"""Reduced-precision files (int8, fp16) derived from a verified fp32 file and judged against it.

    export_int8("model.onnx")                                   # -> model.int8.onnx, if it passes
    export_fp16("model.onnx", comparison=Comparison(frames=8))  # -> model.fp16.onnx, if it passes

Each file is compared with the fp32 file on the ``Comparison``'s frames (``int8_parity``,
``fp16_parity``) and written only when it finds the required share of the fp32 top-50 boxes again
(or with ``force``). Its metadata carries the ``ReducedParityReport``, a ``Quantization`` record and
``check_tensorrt``'s verdict on its own graph.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import onnx

from fisheye_infer.errors import ExportError
from fisheye_infer.runtime.artifact import ArtifactMeta, Quantization, ReducedParityReport, read_meta
from fisheye_infer.tools.files import PendingFile, pending_file

from .fp16 import to_float16
from .fp16_parity import fp16_parity
from .frames import CALIBRATION_SEED, verification_frames
from .graph import save_model, set_metadata
from .int8_parity import int8_parity
from .int8_scope import quantized_scope
from .int8_search import search_int8
from .options import Comparison, Int8Options, options_from_keywords
from .quantize import FrameReader, architecture_float, int8_path_for, quantize
from .results import Fp16Result, Int8Result
from .tensorrt_check import check_tensorrt

__all__ = ["export_fp16", "export_int8", "fp16_path_for", "int8_path_for"]

#: The previous release's keywords of ``export_int8``/``export_fp16`` that now live in ``Comparison``.
_COMPARISON_KEYWORDS = {"frames": "frames", "verify_images": "images", "threads": "threads", "min_kept": "min_kept"}


def fp16_path_for(fp32_path: str | Path) -> Path:
    """Where the fp16 file of ``model.onnx`` goes: ``model.fp16.onnx`` next to it."""
    path = Path(fp32_path)
    return path.with_name(f"{path.stem}.fp16{path.suffix}")


def export_fp16(
    fp32_path: str | Path,
    out: str | Path | None = None,
    *,
    comparison: Comparison | None = None,
    force: bool = False,
    progress: Callable[[str], None] = print,
    **legacy: Any,
) -> Fp16Result:
    """Make the float16 file of a verified fp32 file, for GPU execution providers, and judge it.

    Weights and compute become float16; the geometry tables, index arithmetic and the interface stay as in the fp32
    file. The fp16 file is compared with the fp32 file in ONNX Runtime's CPU execution provider on the
    ``comparison``'s frames and written only when it passes (or with ``force``). Its metadata carries the
    comparison, a ``quantization`` record and the TensorRT check of its own graph.

    Args:
        fp32_path (str | Path): An fp32 file written by ``fisheye-infer export``.
        out (str | Path | None): Where to write; None for ``model.fp16.onnx`` next to ``model.onnx``.
        comparison (Comparison | None): How the file is judged
            ([`Comparison`][fisheye_infer.export.options.Comparison]); None for ``Comparison()``.
        force (bool): Write the file even when its comparison fails.
        progress (Callable[[str], None]): Called with one line per step; ``print`` by default.
        **legacy (Any): The previous release's keywords (``frames=``, ``verify_images=``, ``threads=``,
            ``min_kept=``), folded into ``comparison`` with a ``DeprecationWarning``.

    Returns:
        Fp16Result: The written file (None when its comparison failed and ``force`` is not given), its metadata,
            comparison, time and size.

    Raises:
        ExportError: ``fp32_path`` is already a reduced-precision file.
        ArtifactError: ``fp32_path`` is missing or not a fisheye-infer model.
        TypeError: An unknown keyword argument.
    """
    _, comparison = options_from_keywords(
        None, comparison or Comparison(), legacy, comparison_names=_COMPARISON_KEYWORDS, caller="export_fp16"
    )
    start = time.perf_counter()
    src = Path(fp32_path)
    out = Path(out) if out is not None else fp16_path_for(src)
    meta = _fp32_meta(src, "fp16", "already a reduced-precision file")
    progress(
        "fp16 [1/2] converting weights and compute to float16 (geometry tables, index arithmetic and the interface "
        "stay as in fp32)"
    )
    proto, plan = to_float16(onnx.load(str(src)))
    with pending_file(out, "h") as pending:
        save_model(proto, pending.path)
        batch = _comparison_frames(meta, comparison, "fp16 [2/2]", progress)
        parity = fp16_parity(src, pending.path, batch, threads=comparison.threads, min_fraction=comparison.min_kept)
        reduced = _reduced_meta(proto, meta, parity, Quantization(mode="fp16", scope=plan.scope()))
        written = _publish(proto, reduced, pending, parity.passed or force)
    return Fp16Result(written, reduced, parity, time.perf_counter() - start, out.stat().st_size if written else 0)


def export_int8(
    fp32_path: str | Path,
    out: str | Path | None = None,
    *,
    options: Int8Options | None = None,
    comparison: Comparison | None = None,
    force: bool = False,
    progress: Callable[[str], None] = print,
    **legacy: Any,
) -> Int8Result:
    """Make the static-QDQ int8 file of a verified fp32 file and judge it against the fp32 file.

    Calibration uses the options' seeded synthetic renders of the file's own rig (seeds disjoint from the
    comparison's) plus your calibration frames. The int8 file is compared with the fp32 file on the
    ``comparison``'s frames and written only when it passes (or with ``force``). By default what stays float32 is
    searched for until the file passes; the search's record is in the metadata.

    Args:
        fp32_path (str | Path): An fp32 file written by ``fisheye-infer export``.
        out (str | Path | None): Where to write; None for ``model.int8.onnx`` next to ``model.onnx``.
        options (Int8Options | None): Calibration, scope, float32 modules and weight bits
            ([`Int8Options`][fisheye_infer.export.options.Int8Options]); None for ``Int8Options()``.
        comparison (Comparison | None): How the file is judged
            ([`Comparison`][fisheye_infer.export.options.Comparison]); None for ``Comparison()``.
        force (bool): Write the file even when its comparison fails.
        progress (Callable[[str], None]): Called with one line per step; ``print`` by default.
        **legacy (Any): The previous release's keywords (``calib_frames=``, ``min_kept=``, ...), folded into
            ``options`` and ``comparison`` with a ``DeprecationWarning``.

    Returns:
        Int8Result: The written file (None when its comparison failed and ``force`` is not given), its metadata,
            comparison, time and size.

    Raises:
        ExportError: ``fp32_path`` is already quantized, or quantization fails.
        ArtifactError: ``fp32_path`` is missing or not a fisheye-infer model.
        TypeError: An unknown keyword argument.

    Examples:
        ```python
        from fisheye_infer.export.options import Comparison, Int8Options
        from fisheye_infer.export.reduced import export_int8

        result = export_int8("model.onnx", options=Int8Options(calib_images="frames/"), comparison=Comparison(frames=8))
        print(result.summary())  # model.int8.onnx, if it finds 95% of the fp32 file's top-50 boxes again
        ```
    """
    options, comparison = options_from_keywords(
        options, comparison or Comparison(), legacy, comparison_names=_COMPARISON_KEYWORDS, caller="export_int8"
    )
    options = options or Int8Options()
    start = time.perf_counter()
    src = Path(fp32_path)
    out = Path(out) if out is not None else int8_path_for(src)
    meta = _fp32_meta(src, "int8", "already quantized")
    progress(
        f"int8 [1/3] rendering {options.calib_frames} calibration "
        f"frame(s){' + ' + str(options.calib_images) if options.calib_images else ''}"
    )
    calibration = verification_frames(
        meta.rig, options.calib_frames, seed=CALIBRATION_SEED, images=options.calib_images
    )
    fp32_graph = onnx.load(str(src), load_external_data=False)
    with pending_file(out, "q") as pending:
        batch = _comparison_frames(meta, comparison, "int8 [2/3]", progress)
        if options.searched:
            progress(
                f"int8 [3/3] static QDQ quantization (U8 activations, S8 per-channel {options.weight_bits}-bit "
                "weights), searching what stays float32 for the file to pass"
            )
            searched = search_int8(
                src,
                pending.path,
                FrameReader(calibration),
                batch,
                comparison,
                start=architecture_float(src),
                weight_bits=options.weight_bits,
                force=force,
                progress=progress,
            )
            scope, keep_float, parity, search = searched.scope, searched.float_modules, searched.parity, searched.record
            chosen_by = "the int8 search"
        else:
            scope = options.chosen_scope
            keep_float = architecture_float(src) if options.keep_float is None else tuple(options.keep_float)
            chosen_by = "the architecture's int8_float" if options.keep_float is None else "asked for at export"
            progress(
                f"int8 [3/3] static QDQ quantization, scope {scope} (U8 activations, S8 per-channel "
                f"{options.weight_bits}-bit weights), then the comparison"
            )
            quantize(
                src,
                pending.path,
                FrameReader(calibration),
                scope=scope,
                keep_float=keep_float,
                weight_bits=options.weight_bits,
            )
            parity = int8_parity(src, pending.path, batch, threads=comparison.threads, min_fraction=comparison.min_kept)
            search = None
        proto = onnx.load(str(pending.path))
        quantization = Quantization(
            mode="int8-qdq",
            scope=quantized_scope(fp32_graph, scope, keep_float, chosen_by),
            calibration_frames=len(calibration),
            weight_bits=options.weight_bits,
            float_modules=keep_float,
            search=search,
        )
        reduced = _reduced_meta(proto, meta, parity, quantization)
        written = _publish(proto, reduced, pending, parity.passed or force)
    return Int8Result(written, reduced, parity, time.perf_counter() - start, out.stat().st_size if written else 0)


def _fp32_meta(src: Path, kind: str, already: str) -> ArtifactMeta:
    """The metadata of the fp32 file a reduced file is made from; a reduced file is refused."""
    meta = read_meta(src)
    if meta.quantization is not None:
        raise ExportError(f"{kind}: {src} is {already} ({meta.quantization.mode}); give the fp32 file")
    return meta


def _comparison_frames(
    meta: ArtifactMeta, comparison: Comparison, step: str, progress: Callable[[str], None]
) -> np.ndarray:
    """The frames a reduced file is compared on: seeded renders (the first ones are the fp32 export's own),
    then the user's."""
    images = comparison.images
    progress(
        f"{step} comparing with the fp32 file on {comparison.frames} seeded "
        f"frame(s){' + ' + str(images) if images else ''}"
    )
    return verification_frames(meta.rig, comparison.frames, images=images)


def _reduced_meta(
    proto: onnx.ModelProto, meta: ArtifactMeta, parity: ReducedParityReport, quantization: Quantization
) -> ArtifactMeta:
    """The reduced file's metadata: its parity, what was reduced, the TensorRT check of its own graph."""
    suffix = "int8" if quantization.mode == "int8-qdq" else quantization.mode
    return meta.model_copy(
        update={
            "model_id": f"{meta.model_id}-{suffix}",
            "parity": parity,
            "quantization": quantization,
            "tensorrt": check_tensorrt(proto),
        }
    )


def _publish(proto: onnx.ModelProto, meta: ArtifactMeta, pending: PendingFile, keep: bool) -> Path | None:
    """Set the reduced file's metadata (the re-baking key copied from the fp32 file stays) and, when
    ``keep``, write the file in place of the pending one: its path, or None."""
    set_metadata(proto, meta)
    if not keep:
        return None
    save_model(proto, pending.path)
    return pending.commit()
