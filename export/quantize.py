"""``quantize``: a verified fp32 ONNX file -> a static QDQ int8 file.

    quantize("model.onnx", "model.int8.onnx", FrameReader(frames))   # path in, path out

What it quantizes is chosen in ``int8_scope`` (``int8_nodes``: the image trunk, or by default every
layer with weights; the geometry, attention products, softmax, norms, box decoding and an
architecture's ``int8_float`` modules stay float). U8 activations (percentile ranges over the
calibration frames), S8 weights per output channel in 7 bits (``WEIGHT_BITS``), so that every x86
CPU computes the same integers.

Before quantizing, layers that become int8 are rewritten into forms ONNX Runtime runs faster in
int8 and that compute the same sums (``int8_rewrites``: the stem over 2x2 blocks, ConvTranspose
as Conv + DepthToSpace; after it, ``quantized_rewrites``: data movement on uint8 values).

The input file is never modified; the output appears only when quantization has finished and the
geometry tables are checked to be byte-identical. Whether the file is good enough to keep is judged
elsewhere (``int8_parity``, against the fp32 file).
"""

from __future__ import annotations

import contextlib
import io
import logging
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper
from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static

from fisheye_infer.errors import ExportError
from fisheye_infer.export.graph_stages import name_nodes
from fisheye_infer.geometry.tables import PREFIX as GEOMETRY_PREFIX
from fisheye_infer.precision import CALIBRATION_PERCENTILE, WEIGHT_BITS, WEIGHT_QMAX
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES
from fisheye_infer.tools.files import pending_file

from .graph import check_standard_ops, save_model
from .int8_rewrites import after_quantization, before_quantization
from .int8_scope import WEIGHTED_OPS, int8_nodes

__all__ = [
    "GEOMETRY_PREFIX",
    "QUANT_OPS",
    "FrameReader",
    "architecture_float",
    "check_weight_range",
    "eight_bit_constants",
    "int8_path_for",
    "quantize",
]

#: QuantizeLinear / DequantizeLinear: what a QDQ model adds, and what must stay inside the region.
QUANT_OPS = ("QuantizeLinear", "DequantizeLinear")

# Activation ranges: ``fisheye_infer.precision.CALIBRATION_PERCENTILE``. Weights: 7 bits, [-64, 64]
# (``fisheye_infer.precision.WEIGHT_BITS`` says why); other constants of quantized nodes keep 8 bits
# (``eight_bit_constants``).


def int8_path_for(fp32_path: str | Path) -> Path:
    """Where the int8 file of ``model.onnx`` goes: ``model.int8.onnx`` next to it."""
    path = Path(fp32_path)
    return path.with_name(f"{path.stem}.int8{path.suffix}")


class FrameReader(CalibrationDataReader):
    """Calibration frames for [`quantize`][fisheye_infer.export.quantize.quantize]: one frame per call.

    An ONNX Runtime ``CalibrationDataReader`` that feeds one `(1, N, H, W, 3)` uint8 frame with its camera mask per
    call. ``set_range`` lets the calibrator take the frames one at a time (``quantize`` asks for that): it keeps
    every recorded tensor of the frames it is given until it has folded them into its histograms, about 3.5 GB per
    frame on the full-size FisheyePETR.

    Args:
        frames (np.ndarray): The calibration frames, a non-empty `(F, N, H, W, 3)` uint8 array (F frames of N
            cameras, in the file's camera order and image size).
        valid (np.ndarray | None): Which cameras of each frame are present, an `(F, N)` bool array; None for all.

    Raises:
        ExportError: ``frames`` is not a non-empty 5-D uint8 array.
    """

    def __init__(self, frames: np.ndarray, valid: np.ndarray | None = None) -> None:
        if frames.ndim != 5 or frames.dtype != np.uint8 or len(frames) == 0:
            raise ExportError(
                f"calibration frames: expected a non-empty (F, N, H, W, 3) uint8 array, got {frames.dtype} "
                f"{frames.shape}"
            )
        self.frames = frames
        self.valid = np.ones(frames.shape[:2], bool) if valid is None else valid
        self.set_range(0, len(frames))

    def _feeds(self, start: int, end: int) -> Iterator[dict[str, np.ndarray]]:
        for i in range(start, min(end, len(self.frames))):
            yield {INPUT_IMAGES: self.frames[i : i + 1], INPUT_CAMERA_VALID: self.valid[i : i + 1]}

    def get_next(self) -> dict[str, np.ndarray] | None:
        """The next frame's inputs in the current range.

        Returns:
            The graph's inputs (``images``, ``camera_valid``) for one frame; None once the range is used up.
        """
        return next(self._items, None)

    def set_range(self, start_index: int, end_index: int) -> None:
        """Serve only frames ``start_index`` to ``end_index`` (exclusive), from the first of them.

        Args:
            start_index (int): The first frame.
            end_index (int): One past the last frame (clipped to the frame count).
        """
        self._range = (start_index, end_index)
        self._items: Iterator[dict[str, np.ndarray]] = self._feeds(start_index, end_index)

    def rewind(self) -> None:
        """Start the current range again from its first frame."""
        self._items = self._feeds(*self._range)

    def __len__(self) -> int:
        return len(self.frames)


def _geometry_bytes(model: onnx.ModelProto) -> dict[str, bytes]:
    return {
        i.name: numpy_helper.to_array(i).tobytes()
        for i in model.graph.initializer
        if i.name.startswith(GEOMETRY_PREFIX)
    }


def architecture_float(model_path: str | Path) -> tuple[str, ...]:
    """The modules that stay float32 in the int8 file of ``model_path``: its architecture's ``int8_float``."""
    from fisheye_infer.models import get_model_entry
    from fisheye_infer.runtime.artifact import read_meta

    return get_model_entry(read_meta(model_path).architecture).int8_float


def quantize(
    onnx_path: str | Path,
    out: str | Path,
    reader: FrameReader,
    *,
    scope: str = "network",
    keep_float: Sequence[str] | None = None,
    per_channel: bool = True,
    weight_bits: int = WEIGHT_BITS,
    calibration_cache: str | Path | None = None,
) -> Path:
    """Quantize an fp32 file to a static QDQ int8 file, without judging it.

    U8 activations (ranges: the 99.99th percentile of each tensor's values over the reader's frames) and S8
    weights of ``weight_bits`` bits, per output channel by default; the written file is checked to hold its weights
    to that range. Only the nodes of the chosen scope get QDQ pairs (the geometry, attention products, softmax,
    norms, box decoding and the ``keep_float`` modules stay float); every other node, initializer and the metadata
    are carried over unchanged, and the geometry tables are checked to be byte-identical. The input file is never
    modified; ``out`` appears only when quantization has finished. Whether the file is good enough is judged by
    [`export_int8`][fisheye_infer.export.reduced.export_int8], which calls this.

    Args:
        onnx_path (str | Path): An fp32 file written by ``fisheye-infer export``.
        out (str | Path): Where to write the int8 file (never ``onnx_path``).
        reader (FrameReader): The calibration frames
            ([`FrameReader`][fisheye_infer.export.quantize.FrameReader]).
        scope (str): ``network`` (the image trunk and every weighted layer beyond it) or ``trunk`` (the image
            trunk only).
        keep_float (Sequence[str] | None): Modules (state-dict prefixes) left float32; None for the file's
            architecture's ``int8_float``.
        per_channel (bool): Weight scales per output channel (True) or per tensor.
        weight_bits (int): 7, or 8 only to measure what 7 costs (an 8-bit file can give other boxes on CPUs
            without VNNI).
        calibration_cache (str | Path | None): A JSON file of activation ranges (ONNX Runtime's calibration
            cache). Missing, the ranges are computed and saved there; present, they are read instead of running
            the frames again (valid for the same file and frames and a scope within the first call's). None for no
            cache.

    Returns:
        Path: ``out``.

    Raises:
        ExportError: ``weight_bits`` is not 7 or 8, ``out`` is the input, ONNX Runtime's quantizer fails, the
            geometry tables changed, or the written weights fall outside their range.
        ArtifactError: ``keep_float`` is None and the file's metadata cannot be read.

    Examples:
        ```python
        import numpy as np

        from fisheye_infer.export.quantize import FrameReader, quantize

        frames = np.load("calibration.npy")  # (F, N, H, W, 3) uint8, the file's cameras and image size
        quantize("model.onnx", "model.int8.onnx", FrameReader(frames), scope="trunk")
        ```
    """
    src, out = Path(onnx_path), Path(out)
    if weight_bits not in WEIGHT_QMAX:
        raise ExportError(f"int8: weight_bits {weight_bits}: expected one of {sorted(WEIGHT_QMAX)}")
    if src.resolve() == out.resolve():
        raise ExportError(f"int8: output {out} is the input file; the input is never modified")
    keep_float = architecture_float(src) if keep_float is None else tuple(keep_float)
    model = onnx.load(str(src))
    name_nodes(model)
    before_quantization(
        model, int8_nodes(model, scope, keep_float)
    )  # exact rewrites ORT runs faster in int8 (int8_rewrites)
    nodes = int8_nodes(model, scope, keep_float)
    chosen = set(nodes)
    op_types = sorted({n.op_type for n in model.graph.node if n.name in chosen})
    before = _geometry_bytes(model)
    with tempfile.TemporaryDirectory(prefix="fisheye-int8-") as tmp:
        named = save_model(model, Path(tmp) / "named.onnx")
        quantized = Path(tmp) / "model.int8.onnx"
        level = logging.getLogger().level
        logging.getLogger().setLevel(
            logging.ERROR
        )  # the quantizer suggests pre-processing at WARNING on the root logger
        try:
            with contextlib.redirect_stdout(io.StringIO()):  # the histogram calibrator prints its progress
                quantize_static(
                    str(named),
                    str(quantized),
                    reader,
                    quant_format=QuantFormat.QDQ,
                    op_types_to_quantize=op_types,
                    nodes_to_quantize=nodes,
                    activation_type=QuantType.QUInt8,
                    weight_type=QuantType.QInt8,
                    per_channel=per_channel,
                    reduce_range=weight_bits == 7,  # weights; activations keep 8 bits, and so do the constants below
                    calibrate_method=CalibrationMethod.Percentile,
                    calibration_cache_path=calibration_cache,
                    extra_options={
                        "WeightSymmetric": True,
                        "ActivationSymmetric": False,
                        "CalibPercentile": CALIBRATION_PERCENTILE,
                        "CalibStridedMinMax": 1,  # frame by frame: see FrameReader
                        "TensorQuantOverrides": eight_bit_constants(model, nodes),
                    },
                )
        except Exception as exc:  # ORT's quantizer raises untyped errors
            raise ExportError(f"int8: quantize_static failed on {src} ({scope}): {exc}") from exc
        finally:
            logging.getLogger().setLevel(level)
        result = onnx.load(str(quantized))
    after_quantization(result)
    check_weight_range(result, weight_bits)
    del result.metadata_props[:]
    result.metadata_props.extend(model.metadata_props)
    del result.graph.value_info[:]
    after = _geometry_bytes(result)
    changed = sorted(k for k in before if after.get(k) != before[k])
    if changed:
        raise ExportError(f"int8: quantization altered geometry tables {changed}; refusing to write {out}")
    check_standard_ops(result)  # QDQ in the default domain only: no com.microsoft contrib nodes
    with pending_file(out) as pending:
        save_model(result, pending.path)
        return pending.commit()


def eight_bit_constants(model: onnx.ModelProto, nodes: Sequence[str]) -> dict[str, list[dict[str, bool]]]:
    """``TensorQuantOverrides`` that keep at 8 bits the constants ``nodes`` read other than weights (a Linear's
    bias Add): ORT's ``reduce_range`` applies to every quantized initializer, and would cut those u8 constants
    to [0, 127] although only weights are multiplied in int16 pairs."""
    chosen = set(nodes)
    initializers = {i.name for i in model.graph.initializer}
    return {
        name: [{"reduce_range": False}]
        for node in model.graph.node
        if node.name in chosen
        for index, name in enumerate(node.input)
        if name in initializers and not (node.op_type in WEIGHTED_OPS and index >= 1)
    }


def check_weight_range(model: onnx.ModelProto, weight_bits: int = WEIGHT_BITS) -> None:
    """Every int8 weight a ``DequantizeLinear`` reads from an initializer lies within +-``WEIGHT_QMAX[weight_bits]``,
    with zero point 0; an ``ExportError`` names the first that does not (why: ``WEIGHT_BITS``)."""
    qmax = WEIGHT_QMAX[weight_bits]
    initializers = {i.name: i for i in model.graph.initializer}
    for node in model.graph.node:
        if node.op_type != "DequantizeLinear" or node.input[0] not in initializers:
            continue
        if initializers[node.input[0]].data_type != onnx.TensorProto.INT8:
            continue
        values = numpy_helper.to_array(initializers[node.input[0]]).astype(np.int32)
        zero = (
            numpy_helper.to_array(initializers[node.input[2]]).astype(np.int32)
            if len(node.input) > 2 and node.input[2] in initializers
            else np.zeros(1, np.int32)
        )
        if values.size and (np.abs(values).max() > qmax or np.any(zero != 0)):
            raise ExportError(
                f"int8: weight {node.input[0]} spans [{values.min()}, {values.max()}] with zero point "
                f"{sorted(set(zero.ravel().tolist()))[:3]}; expected {weight_bits}-bit weights, [-{qmax}, {qmax}] "
                "around 0"
            )
