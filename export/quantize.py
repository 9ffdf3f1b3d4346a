"""``quantize``: a verified fp32 ONNX file -> a static QDQ int8 file.

    nodes = int8_nodes(onnx.load("model.onnx"))                       # what int8 covers, found by position
    quantize("model.onnx", "model.int8.onnx", FrameReader(frames))   # path in, path out

Two scopes. ``trunk``: the image trunk only, every node upstream of the view transform's
warp (the gathers of its ``geom.warp.*`` taps) that depends on the ``images`` input alone
(normalisation, ResNet, FPN).
``network`` (the default): the trunk plus every layer with weights beyond it, i.e. each
``Conv``, ``ConvTranspose``, ``MatMul`` or ``Gemm`` whose weight is an initializer: the depth
and context net, the BEV encoder and neck (SECOND / SECONDFPN), the head's convolutions and
FisheyePETR's linear layers. With the trunk alone, the float rest of FisheyeBEVDet takes ~45% of
the fp32 time and caps the speed-up near 2x (``benchmarks/int8.py`` measures both scopes).

What stays float, and why: everything that reads a ``geom.*`` table (the warp, the lift and the
pooling gathers and MatMuls; those tables must stay named and untouched so that ``rebake`` still
works, and their errors are metres), products of two activations (attention scores), softmax,
layer norms and the box decoding, and the modules an architecture names in ``int8_float`` (where
quantizing was measured to cost accuracy: FisheyeBEVDet's TransFusion head but its shared
convolution and the first convolution of its heatmap branch). U8 activations (percentile ranges
over the calibration frames), S8 weights per output channel in 7 bits (``WEIGHT_BITS``), so that
every x86 CPU computes the same integers.

Before quantizing, layers that become int8 are rewritten into forms ONNX Runtime runs faster in
int8 and that compute the same sums (``int8_rewrites``: the stem over 2x2 blocks, ConvTranspose
as Conv + DepthToSpace, data movement on uint8 values).

The regions are found by graph position, initializer names and each node's recorded module path,
not by node names (which change with the exporter). The input file is never modified; the output
appears only when quantization has finished and the geometry tables are checked to be
byte-identical.
"""

from __future__ import annotations

import ast
import contextlib
import io
import logging
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper
from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static

from fisheye_infer.errors import ArtifactError, ExportError
from fisheye_infer.eval.top_match import MATCH_RADIUS_M, top_matched
from fisheye_infer.export import graph_stages
from fisheye_infer.export.graph_stages import name_nodes
from fisheye_infer.geometry.tables import PREFIX as GEOMETRY_PREFIX
from fisheye_infer.precision import CALIBRATION_PERCENTILE, MIN_TOP_MATCHED, WEIGHT_BITS, WEIGHT_QMAX, under_module
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, ReducedParityReport

from .graph import check_standard_ops, save_model
from .int8_rewrites import after_quantization, before_quantization
from .options import SCOPES
from .trace import TRACE_ROOT
from .verify import run_onnx

__all__ = [
    "GEOMETRY_PREFIX",
    "QUANT_OPS",
    "SCOPES",
    "TRUNK_OPS",
    "WEIGHTED_OPS",
    "FrameReader",
    "architecture_float",
    "check_weight_range",
    "eight_bit_constants",
    "image_region",
    "int8_nodes",
    "int8_parity",
    "int8_path_for",
    "module_of",
    "quantize",
    "quantized_scope",
]

#: QuantizeLinear / DequantizeLinear: what a QDQ model adds, and what must stay inside the region.
QUANT_OPS = ("QuantizeLinear", "DequantizeLinear")

# Activation ranges: ``fisheye_infer.precision.CALIBRATION_PERCENTILE``. Weights: 7 bits, [-64, 64]
# (``fisheye_infer.precision.WEIGHT_BITS`` says why); other constants of quantized nodes keep 8 bits
# (``eight_bit_constants``).

#: Layers with weights, which ``network`` quantizes beyond the trunk when their weight is an initializer.
WEIGHTED_OPS = ("Conv", "ConvTranspose", "MatMul", "Gemm")

#: Trunk ops that get QDQ pairs: compute, not data movement (a Reshape or Concat costs the same in
#: either precision, and each op type listed makes ORT's calibration record every node of that type
#: in the graph, the view transform's large tensors included).
TRUNK_OPS = ("Conv", "Relu", "Add", "MaxPool", "Resize")


def int8_path_for(fp32_path: str | Path) -> Path:
    """Where the int8 file of ``model.onnx`` goes: ``model.int8.onnx`` next to it."""
    path = Path(fp32_path)
    return path.with_name(f"{path.stem}.int8{path.suffix}")


class FrameReader(CalibrationDataReader):
    """Calibration frames for ``quantize_static``: one (1, N, H, W, 3) uint8 frame per call.

    ``set_range`` lets the calibrator take the frames one at a time (``quantize`` asks for that):
    it keeps every recorded tensor of the frames it is given until it has folded them into its
    histograms, and on the full-size FisheyePETR that is about 3.5 GB per frame (eight frames at
    once did not fit in 24 GB).
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
        return next(self._items, None)

    def set_range(self, start_index: int, end_index: int) -> None:
        self._range = (start_index, end_index)
        self._items: Iterator[dict[str, np.ndarray]] = self._feeds(start_index, end_index)

    def rewind(self) -> None:
        self._items = self._feeds(*self._range)

    def __len__(self) -> int:
        return len(self.frames)


def image_region(model: onnx.ModelProto) -> list[str]:
    """Names of the image trunk's nodes (see ``fisheye_infer.export.graph_stages.image_region``); a graph without
    the warp that anchors it cannot be quantized (``ExportError``)."""
    try:
        return graph_stages.image_region(model)
    except ArtifactError as exc:
        raise ExportError(f"int8: {exc}") from None


def int8_nodes(model: onnx.ModelProto, scope: str = "network", keep_float: Sequence[str] = ()) -> list[str]:
    """Names of the nodes the int8 file quantizes (every node named, see ``name_nodes``), in graph order.

    ``trunk``: the image trunk's compute (``image_region``, ops of ``TRUNK_OPS``). ``network``: the
    trunk, plus each node of ``WEIGHTED_OPS`` outside it whose weight (input 1) is an initializer,
    and the ``TRUNK_OPS`` nodes reading what those produce (a ReLU or residual Add after a
    convolution: without them ORT would leave the convolution float, for want of a quantized
    output). No node reading a ``geom.*`` table directly, and none of the modules named in
    ``keep_float`` (state-dict prefixes, the architecture's ``int8_float``; see ``module_of``).
    """
    if scope not in SCOPES:
        raise ExportError(f"int8: scope {scope!r} is not one of {', '.join(SCOPES)}")
    graph = model.graph
    image = set(image_region(model))
    weights = {i.name for i in graph.initializer if not i.name.startswith(GEOMETRY_PREFIX)}
    geometry = {i.name for i in graph.initializer if i.name.startswith(GEOMETRY_PREFIX)}
    modules = {n.name: module_of(n, weights) for n in graph.node}
    for prefix in keep_float:
        if not any(under_module(m, prefix) for m in modules.values()):
            raise ExportError(
                f"int8: keep float32 {prefix!r}: no node of the graph belongs to that module "
                "(expected a state-dict prefix such as 'img_backbone.conv1' or 'bbox_head')"
            )
    floats = {name for name, m in modules.items() if any(under_module(m, prefix) for prefix in keep_float)}
    trunk = {n.name for n in graph.node if n.name in image and n.op_type in TRUNK_OPS and n.name not in floats}
    region = set(trunk)
    if scope == "network":
        made_in_region: set[str] = set()
        for node in graph.node:  # graph order: a follower comes after the layer it follows
            weighted = node.op_type in WEIGHTED_OPS and len(node.input) > 1 and node.input[1] in weights
            follower = node.op_type in TRUNK_OPS and any(i in made_in_region for i in node.input)
            if (
                (weighted or follower or node.name in trunk)
                and not geometry.intersection(node.input)
                and node.name not in floats
            ):
                region.add(node.name)
                made_in_region.update(node.output)
    return [n.name for n in graph.node if n.name in region]


def module_of(node: onnx.NodeProto, weights: set[str] | None = None) -> str:
    """The model module a node was traced from, as a state-dict prefix (``bbox_head.heatmap_head.0``).

    A layer whose weight (input 1, one of ``weights``) is a parameter of the traced model belongs
    to that parameter's module: a convolution with a folded BatchNorm is recorded under the
    BatchNorm (``img_backbone.bn1`` for ``img_backbone.conv1``). Other nodes: the module path the
    exporter records in their metadata (``pkg.torch.onnx.name_scopes``, under the trace wrapper's
    ``model``). Empty when neither says.
    """
    if (
        weights is not None
        and len(node.input) > 1
        and node.input[1] in weights
        and node.input[1].startswith(TRACE_ROOT + ".")
    ):
        return node.input[1].removeprefix(TRACE_ROOT + ".").rsplit(".", 1)[0]
    for prop in node.metadata_props:
        if prop.key == "pkg.torch.onnx.name_scopes":
            scopes = [s for s in ast.literal_eval(prop.value) if s == TRACE_ROOT or s.startswith(TRACE_ROOT + ".")]
            return scopes[-1].removeprefix(TRACE_ROOT).removeprefix(".") if scopes else ""
    return ""


def quantized_scope(
    model: onnx.ModelProto,
    scope: str = "network",
    keep_float: Sequence[str] = (),
    chosen_by: str = "the architecture's int8_float",
) -> str:
    """A one-line description of what ``quantize`` covers, for the file's metadata; ``chosen_by``
    says where ``keep_float`` came from."""
    model = _named(model)
    trunk, nodes = set(image_region(model)), set(int8_nodes(model, scope, keep_float))
    layers = [n for n in model.graph.node if n.name in nodes and n.op_type in WEIGHTED_OPS]
    in_trunk = sum(1 for n in layers if n.name in trunk)
    if scope == "trunk":  # only the float modules inside the trunk change what this scope covers
        weights = {i.name for i in model.graph.initializer}
        keep_float = [
            p
            for p in keep_float
            if any(under_module(module_of(n, weights), p) for n in model.graph.node if n.name in trunk)
        ]
    kept = f"{', '.join(keep_float)} ({chosen_by}), " if keep_float else ""
    if scope == "trunk":
        return (
            f"image backbone+neck: {in_trunk} weighted layers upstream of the view transform's warp; "
            f"float32: {kept}geometry, pooling and heads"
        )
    return (
        f"network: {len(layers)} weighted layers, {in_trunk} in the image backbone+neck and {len(layers) - in_trunk} "
        f"beyond it; float32: {kept}geometry, pooling, attention products, softmax, norms and box decoding"
    )


def _named(model: onnx.ModelProto) -> onnx.ModelProto:
    """A copy of ``model`` with every node named (the input is left as it is)."""
    copy = onnx.ModelProto()
    copy.CopyFrom(model)
    name_nodes(copy)
    return copy


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
) -> Path:
    """Static QDQ quantization of ``onnx_path``'s ``int8_nodes(scope, keep_float)`` into ``out``; returns ``out``.
    ``keep_float`` defaults to the file's architecture's (``architecture_float``).

    U8 activations (ranges: the ``CALIBRATION_PERCENTILE`` of each tensor's values over the reader's
    frames; ORT records the tensors of every node whose op type is quantized, which is why
    ``int8_nodes`` leaves data movement out), S8 weights of ``weight_bits`` bits (per output channel by
    default; ``check_weight_range`` holds the written file to them; 8 only to measure what 7 costs, since
    such a file can give other boxes on CPUs without VNNI). Only the
    chosen nodes get QDQ pairs; every other node, initializer and the metadata are carried over unchanged (the
    exporter then replaces the metadata with the int8 parity report).
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
    tmp_out = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    try:
        save_model(result, tmp_out)
        os.replace(tmp_out, out)
    finally:
        tmp_out.unlink(missing_ok=True)
    return out


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


def int8_parity(
    fp32_path: str | Path,
    int8_path: str | Path,
    frames: np.ndarray,
    threads: int = 2,
    min_fraction: float = MIN_TOP_MATCHED,
) -> ReducedParityReport:
    """The int8 file against the fp32 ONNX file on ``frames``, one frame at a time.

    int8 is not expected to reproduce fp32 to 1e-3 m; the criterion is detection-level: at
    least ``min_fraction`` of the fp32 top-50 boxes found again within 0.5 m with the same label.
    """
    valid = np.ones(frames.shape[:2], bool)
    ref, cand = (
        [run_onnx(path, frames, valid, threads, per_frame=True)[k] for k in OUTPUTS] for path in (fp32_path, int8_path)
    )
    kept = top_matched(ref, cand)
    return ReducedParityReport(
        frames=len(frames),
        threads=(threads,),
        top_matched_fraction=kept.fraction,
        top_matched_standard_error=kept.standard_error,
        top_matched_by_score=kept.by_score,
        min_top_matched=min_fraction,
        match_radius_m=MATCH_RADIUS_M,
        unmatched=kept.considered - kept.matched,
        max_box_abs_diff_m=kept.max_box_diff,
        max_score_abs_diff=kept.max_score_diff,
        labels_equal=bool(np.array_equal(ref[2], cand[2])),
        valid_equal=bool(np.array_equal(ref[3], cand[3])),
        passed=kept.fraction >= min_fraction,
    )
