"""``quantize``: a verified fp32 ONNX file -> a static QDQ int8 file of the image backbone and neck.

    region = image_region(onnx.load("model.onnx"))                  # node names, found by position
    quantize("model.onnx", "model.int8.onnx", FrameReader(frames))   # path in, path out

Only the image trunk is quantized: every node upstream of the view transform's ``GridSample``
that depends on the ``images`` input alone (normalisation, ResNet, FPN). That is where almost
all the multiply-adds are, and it is a plain conv net, which static QDQ (U8 activations, S8
per-channel weights) runs on VNNI cores about 3x faster than fp32 (onnx-runtime-facts §4).
Geometry, pooling, the BEV encoder and the heads stay float32: their errors are measured in
metres, the pooling is gathers and batched MatMuls whose integer forms would not be faster,
and the geometry initializers must stay named and untouched so that ``rebake`` still works.

The region is found by graph position, not by node names (which change with the exporter):
a node belongs to it when it is an ancestor of a GridSample's sampled input and none of its
inputs derive from ``camera_valid`` or from a ``geom.*`` table. The input file is never
modified; the output appears only when quantization has finished and the geometry tables
are checked to be byte-identical.
"""

from __future__ import annotations

import logging
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper
from onnxruntime.quantization import CalibrationDataReader, CalibrationMethod, QuantFormat, QuantType, quantize_static

from fisheye_infer import graph_stages
from fisheye_infer.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, ParityReport
from fisheye_infer.boxes import box_diff
from fisheye_infer.errors import ArtifactError, ExportError
from fisheye_infer.geometry.tables import PREFIX as GEOMETRY_PREFIX
from fisheye_infer.graph_stages import name_nodes

from .graph import check_standard_ops, save_model
from .verify import run_onnx

__all__ = ["GEOMETRY_PREFIX", "QUANT_OPS", "FrameReader", "image_region", "int8_parity", "int8_path_for", "quantize", "quantized_scope", "top_matched"]

#: QuantizeLinear / DequantizeLinear: what a QDQ model adds, and what must stay inside the region.
QUANT_OPS = ("QuantizeLinear", "DequantizeLinear")


def int8_path_for(fp32_path: str | Path) -> Path:
    """Where the int8 file of ``model.onnx`` goes: ``model.int8.onnx`` next to it."""
    path = Path(fp32_path)
    return path.with_name(f"{path.stem}.int8{path.suffix}")


class FrameReader(CalibrationDataReader):
    """Calibration frames for ``quantize_static``: one (1, N, H, W, 3) uint8 frame per call.

    One frame at a time keeps the calibration run's memory at batch-1 size; MinMax merges the
    per-frame ranges, so the batch size does not change the result.
    """

    def __init__(self, frames: np.ndarray, valid: np.ndarray | None = None) -> None:
        if frames.ndim != 5 or frames.dtype != np.uint8 or len(frames) == 0:
            raise ExportError(f"calibration frames: expected a non-empty (F, N, H, W, 3) uint8 array, got {frames.dtype} {frames.shape}")
        self.frames = frames
        self.valid = np.ones(frames.shape[:2], bool) if valid is None else valid
        self._items: Iterator[dict[str, np.ndarray]] = self._feeds()

    def _feeds(self) -> Iterator[dict[str, np.ndarray]]:
        for i in range(len(self.frames)):
            yield {INPUT_IMAGES: self.frames[i : i + 1], INPUT_CAMERA_VALID: self.valid[i : i + 1]}

    def get_next(self) -> dict[str, np.ndarray] | None:
        return next(self._items, None)

    def rewind(self) -> None:
        self._items = self._feeds()

    def __len__(self) -> int:
        return len(self.frames)


def image_region(model: onnx.ModelProto) -> list[str]:
    """Names of the image trunk's nodes (see ``fisheye_infer.graph_stages.image_region``); a graph without
    the GridSample that anchors it cannot be quantized (``ExportError``)."""
    try:
        return graph_stages.image_region(model)
    except ArtifactError as exc:
        raise ExportError(f"int8: {exc}") from None


def _boundary(model: onnx.ModelProto, region: Sequence[str]) -> list[str]:
    """The region's values that the rest of the graph (or its outputs) reads, sorted."""
    names = set(region)
    graph = model.graph
    made = {o for n in graph.node if n.name in names for o in n.output}
    read_outside = {i for n in graph.node if n.name not in names for i in n.input} | {o.name for o in graph.output}
    return sorted(made & read_outside)


def quantized_scope(model: onnx.ModelProto) -> str:
    """A one-line description of what ``quantize`` covers, for the file's metadata."""
    region = set(image_region(model))
    convs = sum(1 for n in model.graph.node if n.name in region and n.op_type == "Conv")
    return f"image backbone+neck: {len(region)} nodes upstream of the view transform's GridSample ({convs} Conv); geometry, pooling and heads float32"


def _geometry_bytes(model: onnx.ModelProto) -> dict[str, bytes]:
    return {i.name: numpy_helper.to_array(i).tobytes() for i in model.graph.initializer if i.name.startswith(GEOMETRY_PREFIX)}


def _trunk(model: onnx.ModelProto, region: Sequence[str], outputs: Sequence[str]) -> onnx.ModelProto:
    """The region as a model of its own: ``images`` in, the values the rest of the graph reads out.

    Calibrating this instead of the whole graph keeps ORT from recording ranges of every BEV
    and head tensor (on the full FisheyeBEVDet that is the difference between minutes and
    seconds), and the rest of the graph cannot be touched by the quantizer at all.
    """
    names = set(region)
    nodes = [n for n in model.graph.node if n.name in names]
    used = {i for n in nodes for i in n.input}
    inits = [i for i in model.graph.initializer if i.name in used]
    inputs = [i for i in model.graph.input if i.name == INPUT_IMAGES]
    outs = [onnx.helper.make_empty_tensor_value_info(name) for name in outputs]
    graph = onnx.helper.make_graph(nodes, "image_trunk", inputs, outs, inits)
    return onnx.helper.make_model(graph, opset_imports=list(model.opset_import), ir_version=model.ir_version)


def _splice(model: onnx.ModelProto, region: Sequence[str], trunk: onnx.ModelProto) -> onnx.ModelProto:
    """``model`` with its region nodes replaced by the quantized trunk's nodes; unused initializers dropped."""
    names = set(region)
    result = onnx.ModelProto()
    result.CopyFrom(model)
    graph = result.graph
    rest = [n for n in model.graph.node if n.name not in names]
    del graph.node[:]
    graph.node.extend(list(trunk.graph.node) + rest)  # the region reads nothing from the rest: still sorted
    from_trunk = {i.name for i in trunk.graph.initializer}  # the trunk's version of a shared name wins
    used = {i for n in graph.node for i in n.input} - {o for n in graph.node for o in n.output}  # a DQ may now produce a weight's name
    kept = [i for i in graph.initializer if i.name in used and i.name not in from_trunk]
    kept += [i for i in trunk.graph.initializer if i.name in used]
    del graph.initializer[:]
    graph.initializer.extend(kept)
    del graph.value_info[:]
    domains = {o.domain for o in result.opset_import}
    result.opset_import.extend(o for o in trunk.opset_import if o.domain not in domains)
    return result


class _Only(CalibrationDataReader):
    """Passes on only the inputs the trunk has (``images``), whatever else the reader feeds."""

    def __init__(self, reader: CalibrationDataReader, names: set[str]) -> None:
        self.reader, self.names = reader, names

    def get_next(self) -> dict[str, np.ndarray] | None:
        item = self.reader.get_next()
        return None if item is None else {k: v for k, v in item.items() if k in self.names}

    def rewind(self) -> None:
        self.reader.rewind()


def quantize(onnx_path: str | Path, out: str | Path, reader: CalibrationDataReader, *, per_channel: bool = True) -> Path:
    """Static QDQ quantization of ``onnx_path``'s image trunk into ``out``; returns ``out``.

    U8 activations (MinMax over the reader's frames), S8 weights (per output channel by default).
    Metadata is copied from the input; the exporter replaces it with the int8 parity report.
    """
    src, out = Path(onnx_path), Path(out)
    if src.resolve() == out.resolve():
        raise ExportError(f"int8: output {out} is the input file; the input is never modified")
    model = onnx.load(str(src))
    name_nodes(model)
    region = image_region(model)
    boundary = _boundary(model, region)
    before = _geometry_bytes(model)
    with tempfile.TemporaryDirectory(prefix="fisheye-int8-") as tmp:
        trunk_path = save_model(_trunk(model, region, boundary), Path(tmp) / "trunk.onnx")
        quantized = Path(tmp) / "trunk.int8.onnx"
        level = logging.getLogger().level
        logging.getLogger().setLevel(logging.ERROR)  # the quantizer suggests pre-processing at WARNING on the root logger
        try:
            quantize_static(
                str(trunk_path), str(quantized), _Only(reader, {INPUT_IMAGES}),
                quant_format=QuantFormat.QDQ,
                activation_type=QuantType.QUInt8,
                weight_type=QuantType.QInt8,
                per_channel=per_channel,
                calibrate_method=CalibrationMethod.MinMax,
                extra_options={"WeightSymmetric": True, "ActivationSymmetric": False},
            )
        except Exception as exc:  # ORT's quantizer raises untyped errors
            raise ExportError(f"int8: quantize_static failed on the image trunk of {src}: {exc}") from exc
        finally:
            logging.getLogger().setLevel(level)
        trunk = onnx.load(str(quantized))
    missing = sorted(set(boundary) - {o for n in trunk.graph.node for o in n.output})
    if missing:
        raise ExportError(f"int8: the quantized trunk no longer produces {missing}; cannot splice it back")
    result = _splice(model, region, trunk)
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


# -- evidence: int8 boxes against the fp32 file's ------------------------------------------------

TOP_K = 50
MATCH_RADIUS_M = 0.5
MIN_TOP_MATCHED = 0.95


def top_matched(reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray], top_k: int = TOP_K,
                radius_m: float = MATCH_RADIUS_M) -> tuple[int, int, float, float]:
    """Match each frame's top-``top_k`` valid reference boxes (by score) to candidate boxes.

    A reference box is matched by the nearest unused valid candidate box of the same label whose
    centre lies within ``radius_m`` (bird's-eye distance, as nuScenes' centre distance), greedily
    in reference score order. Returns (matched, considered, max box abs diff over matched pairs,
    max score diff over matched pairs).
    """
    rb, rs, rl, rv = reference
    cb, cs, cl, cv = candidate
    matched = considered = 0
    box_err = score_diff = 0.0
    for f in range(len(rb)):
        order = [i for i in np.argsort(-rs[f], kind="stable") if rv[f][i]][:top_k]
        pool = np.flatnonzero(cv[f])
        used = np.zeros(len(pool), bool)
        for i in order:
            considered += 1
            same = (cl[f][pool] == rl[f][i]) & ~used
            dist = np.hypot(*(cb[f][pool, :2] - rb[f][i, :2]).T)
            dist[~same] = np.inf
            if len(pool) and dist.min() <= radius_m:
                j = int(np.argmin(dist))
                used[j] = True
                matched += 1
                box_err = max(box_err, float(box_diff(cb[f][pool[j]], rb[f][i])))
                score_diff = max(score_diff, abs(float(cs[f][pool[j]]) - float(rs[f][i])))
    return matched, considered, box_err, score_diff


def int8_parity(fp32_path: str | Path, int8_path: str | Path, frames: np.ndarray, threads: int = 2,
                min_fraction: float = MIN_TOP_MATCHED) -> ParityReport:
    """The int8 file against the fp32 ONNX file on ``frames``, one frame at a time.

    int8 is not expected to reproduce fp32 to 1e-3 m; the criterion is detection-level: at
    least ``min_fraction`` of the fp32 top-50 boxes found again within 0.5 m with the same label.
    """
    valid = np.ones(frames.shape[:2], bool)
    runs = []
    for path in (fp32_path, int8_path):
        outs = [run_onnx(path, frames[i : i + 1], valid[i : i + 1], threads) for i in range(len(frames))]
        runs.append([np.concatenate([o[k] for o in outs]) for k in OUTPUTS])
    ref, cand = runs
    matched, considered, box, score = top_matched(ref, cand)
    fraction = matched / considered if considered else 1.0
    return ParityReport(
        frames=len(frames), threads=(threads,), max_box_abs_diff_m=box, max_score_abs_diff=score,
        labels_equal=bool(np.array_equal(ref[2], cand[2])),
        order_equal=bool(np.array_equal(ref[2], cand[2]) and np.allclose(ref[0], cand[0], atol=MATCH_RADIUS_M)),
        valid_equal=bool(np.array_equal(ref[3], cand[3])), unmatched=considered - matched,
        tolerance_box_m=MATCH_RADIUS_M, tolerance_score=1.0, passed=fraction >= min_fraction,
        reference="fp32-onnx", top_matched_fraction=fraction,
    )
