"""Would an int8 file give other boxes on an x86 CPU without VNNI? Its int16 pair saturation, counted.

    python benchmarks/int8_saturation.py compact [--frames 1]      # or an int8 file

Without VNNI (AVX2 only, or AVX-512 before Cascade Lake) ONNX Runtime multiplies u8 activations by
s8 weights with ``vpmaddubsw``, which adds the products of two neighbouring input channels (at one
kernel tap of an NHWC convolution; two neighbouring rows of a MatMul's weight) in int16 and
saturates; VNNI's ``vpdpbusd`` adds in int32. This script runs the file on ``--frames`` seeded
renders of its own rig, reads the u8 input of every int8 convolution and MatMul of the QDQ graph
(ONNX Runtime fuses each into a QLinearConv or QLinearMatMul in the detectors' files), and counts
the outputs for which at least one pair leaves [-32768, 32767]. Pairs are taken as the kernels
take them: neighbouring input channels at one kernel tap (tap by tap, channel by channel, when the
channel count is odd), neighbouring rows of a MatMul's weight. Grouped convolutions and Gemm are
listed, not counted. 7-bit weights (``fisheye_infer.precision.WEIGHT_BITS``) cannot saturate
(2 x 255 x 64 = 32,640), so such a file counts zero everywhere; files with 8-bit weights
(``benchmarks/int8.py --weight-bits 8``) show where the CPUs disagree.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

import harness
import numpy as np
import onnx
import onnxruntime as ort
import torch
import torch.nn.functional as F
from model_files import model_path
from onnx import helper, numpy_helper

from fisheye_infer.export.exporter import verification_frames
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, read_meta

INT16 = (-32768, 32767)


@dataclass
class Layer:
    node: onnx.NodeProto
    activation: str  # the u8 tensor the layer's DequantizeLinear reads
    zero_point: int  # its zero point: what an int8 convolution pads with
    weight: torch.Tensor  # int8 values as float (exact)
    outputs: int = 0
    saturated: int = 0


def int8_layers(model: onnx.ModelProto) -> tuple[list[Layer], list[str]]:
    """Convolutions and MatMuls whose input and weight both come out of a DequantizeLinear (u8 activation, int8
    initializer), and the names of the quantized layers this script does not model (Gemm, grouped convolutions)."""
    inits = {i.name: i for i in model.graph.initializer}
    producer = {out: n for n in model.graph.node for out in n.output}
    layers, skipped = [], []
    for node in model.graph.node:
        if node.op_type not in ("Conv", "MatMul", "Gemm") or len(node.input) < 2:
            continue
        x, w = producer.get(node.input[0]), producer.get(node.input[1])
        if x is None or w is None or not x.op_type == w.op_type == "DequantizeLinear" or w.input[0] not in inits:
            continue
        if inits[w.input[0]].data_type != onnx.TensorProto.INT8:
            continue
        if node.op_type == "Gemm" or _attribute(node, "group", 1) != 1:
            skipped.append(node.name)
            continue
        has_zero = len(x.input) > 2 and x.input[2] in inits
        zero = int(numpy_helper.to_array(inits[x.input[2]]).ravel()[0]) if has_zero else 0
        weight = torch.from_numpy(numpy_helper.to_array(inits[w.input[0]]).astype(np.float32))
        layers.append(Layer(node, x.input[0], zero, weight))
    return layers, skipped


def _attribute(node: onnx.NodeProto, name: str, default: Any) -> Any:
    return next((helper.get_attribute_value(a) for a in node.attribute if a.name == name), default)


def saturated_outputs(layer: Layer, activation: np.ndarray) -> tuple[int, int]:
    """(outputs with at least one saturated pair, outputs) of one layer on one input."""
    a = torch.from_numpy(activation.astype(np.float32))
    if layer.node.op_type == "MatMul":  # (..., K) x (K, N): pairs of neighbouring k
        k, n = layer.weight.shape
        rows = a.reshape(-1, k)[:, : k // 2 * 2].reshape(-1, k // 2, 2)
        w = layer.weight[: k // 2 * 2].reshape(k // 2, 2, n)
        hit = torch.zeros(rows.shape[0], n, dtype=torch.bool)
        for j in range(k // 2):
            pair = rows[:, j, 0, None] * w[j, 0] + rows[:, j, 1, None] * w[j, 1]
            hit |= (pair < INT16[0]) | (pair > INT16[1])
        return int(hit.sum()), hit.numel()
    cout, cin, kh, kw = layer.weight.shape
    pads = _attribute(layer.node, "pads", [0, 0, 0, 0])
    a = F.pad(a, (pads[1], pads[3], pads[0], pads[2]), value=float(layer.zero_point))
    cols = F.unfold(
        a,
        (kh, kw),
        dilation=_attribute(layer.node, "dilations", [1, 1]),
        stride=_attribute(layer.node, "strides", [1, 1]),
    )
    cols = cols.view(a.shape[0], cin, kh * kw, -1)
    w = layer.weight.reshape(cout, cin, kh * kw)
    if cin % 2:  # im2col, then a GEMM over (tap, channel): pairs run across taps; one pair position per "tap" below
        k = cin * kh * kw // 2 * 2
        cols = cols.transpose(1, 2).reshape(a.shape[0], -1, cols.shape[-1])[:, :k].reshape(a.shape[0], k // 2, 2, 1, -1)
        w = w.transpose(1, 2).reshape(cout, -1)[:, :k].reshape(cout, k // 2, 2, 1)
    else:
        cols = cols.view(a.shape[0], cin // 2, 2, kh * kw, -1)
        w = w.view(cout, cin // 2, 2, kh * kw)
    reachable = 255 * (w[:, :, 0].abs() + w[:, :, 1].abs()) > INT16[1]  # only these (channel, pair, tap) can saturate
    hit = torch.zeros(a.shape[0], cout, cols.shape[-1], dtype=torch.bool)
    for c in torch.nonzero(reachable.flatten(1).any(dim=1)).flatten().tolist():
        pair = cols[:, :, 0] * w[c, :, 0, :, None] + cols[:, :, 1] * w[c, :, 1, :, None]
        hit[:, c] = ((pair < INT16[0]) | (pair > INT16[1])).flatten(1, 2).any(dim=1)
    return int(hit.sum()), hit.numel()


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__)
    bench.parser.add_argument(
        "model",
        help="an int8 file written by fisheye-infer export --int8, or one of compact, "
        "fisheye-bevdet, fisheye-petr (their int8 file)",
    )
    bench.parser.add_argument("--frames", type=int, default=1, help="seeded renders of the file's rig (default 1)")
    args = bench.parse(argv)
    path = model_path(args.model, "int8")
    meta = read_meta(path)
    model = onnx.load(str(path))
    layers, skipped = int8_layers(model)
    if not layers:
        raise SystemExit(f"{path}: no int8 convolution or MatMul (is it an int8 file?)")
    del model.graph.output[:]
    for name in sorted({layer.activation for layer in layers}):
        model.graph.output.append(helper.make_empty_tensor_value_info(name))
    options = ort.SessionOptions()
    # the QDQ graph as written, where its u8 tensors exist
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    session = ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])
    names = [o.name for o in session.get_outputs()]
    frames = verification_frames(meta.rig, args.frames)
    valid = np.ones((1, len(meta.cameras)), bool)
    for frame in frames:
        values = dict(zip(names, session.run(names, {INPUT_IMAGES: frame[None], INPUT_CAMERA_VALID: valid})))
        for layer in layers:
            hit, total = saturated_outputs(layer, values[layer.activation])
            layer.saturated += hit
            layer.outputs += total
    outputs = sum(layer.outputs for layer in layers)
    hits = sum(layer.saturated for layer in layers)
    summary = {
        "file": path.name,
        "int8 layers": len(layers),
        "largest weight": max(int(layer.weight.abs().max()) for layer in layers),
        "recorded weight bits": meta.quantization.weight_bits if meta.quantization else None,
        "frames": len(frames),
        "outputs": outputs,
        "outputs saturated": hits,
        "share": hits / max(outputs, 1),
        "not counted": skipped,
    }
    per_layer = [
        {
            "layer": layer.node.name,
            "weight": "x".join(map(str, layer.weight.shape)),
            "share saturated": layer.saturated / layer.outputs,
        }
        for layer in sorted(layers, key=lambda x: -x.saturated / max(x.outputs, 1))
        if layer.saturated
    ]
    bench.save(args, {"Outputs with a saturated int16 pair": [summary], "Layers with saturated outputs": per_layer})
    return 0


if __name__ == "__main__":
    sys.exit(main())
