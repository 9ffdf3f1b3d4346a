"""Split an exported graph into its stages and time each one: backbone+neck, view transform, head.

ORT's profiler reports nodes of the *optimised* graph, whose names and fusions change with the
ORT version and the CPU (NCHWc reorders, fused Conv+Relu); attributing them back is fragile.
Cutting the exported graph by position is not: the image trunk is every node upstream of the
view transform's GridSample that depends on the images alone (as int8 quantization finds it),
the view transform ends at the last node reading a ``geom.pool.*`` table (FisheyeBEVDet:
warp, depth/context net, lift, pooling) or at the GridSample itself (FisheyePETR: the warp),
and the head is everything else. Each stage becomes a model of its own, fed with the values
the full graph computes at its cut, and is timed with the same session options. The stages
cannot be fused across a cut, so their sum is compared with the full graph's time.

Needs the ``onnx`` package (the ``export`` extra).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import onnx
import onnxruntime as ort

from fisheye_infer.errors import ArtifactError

__all__ = ["STAGES", "Stage", "split_stages", "time_stages"]

STAGES = ("backbone_neck", "view_transform", "head")
_GEOM = "geom."
_POOL = "geom.pool."


@dataclass(frozen=True)
class Stage:
    name: str
    model: onnx.ModelProto
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    nodes: int


def _assign(model: onnx.ModelProto) -> dict[str, str]:
    """node name -> stage name (every node named; see ``export.quantize._name_nodes``)."""
    from fisheye_infer.export.quantize import image_region

    graph = model.graph
    trunk = set(image_region(model))
    pool_readers = [n for n in graph.node if any(i.startswith(_POOL) for i in n.input)]
    anchors = pool_readers[-1:] or [n for n in graph.node if n.op_type == "GridSample"]
    producer = {o: n for n in graph.node for o in n.output}
    view: set[str] = set()
    stack = [anchors[-1]]
    while stack:
        node = stack.pop()
        if node.name in view or node.name in trunk:
            continue
        view.add(node.name)
        stack.extend(producer[i] for i in node.input if i in producer)
    return {n.name: "backbone_neck" if n.name in trunk else "view_transform" if n.name in view else "head" for n in graph.node}


def split_stages(model: onnx.ModelProto) -> list[Stage]:
    """The three stage models; inputs and outputs are the values crossing each cut."""
    from fisheye_infer.export.quantize import _name_nodes

    model_copy = onnx.ModelProto()
    model_copy.CopyFrom(model)
    _name_nodes(model_copy)
    graph = model_copy.graph
    stage_of = _assign(model_copy)
    produced_in = {o: stage_of[n.name] for n in graph.node for o in n.output}
    graph_inputs = {i.name: i for i in graph.input}
    inits = {i.name: i for i in graph.initializer}
    inferred = onnx.shape_inference.infer_shapes(model_copy, strict_mode=False)
    types = {v.name: v.type.tensor_type.elem_type for v in list(inferred.graph.value_info) + list(inferred.graph.output)}
    stages = []
    for name in STAGES:
        nodes = [n for n in graph.node if stage_of[n.name] == name]
        reads = [i for n in nodes for i in n.input if i and i not in inits]
        ins = list(dict.fromkeys(i for i in reads if produced_in.get(i, "input") != name))
        read_later = {i for n in graph.node if stage_of[n.name] != name for i in n.input} | {o.name for o in graph.output}
        outs = list(dict.fromkeys(o for n in nodes for o in n.output if o in read_later))
        in_info = [graph_inputs[i] if i in graph_inputs else onnx.helper.make_tensor_value_info(i, types.get(i, onnx.TensorProto.FLOAT), None) for i in ins]
        out_info = [onnx.helper.make_tensor_value_info(o, types.get(o, onnx.TensorProto.FLOAT), None) for o in outs]
        used = {i for n in nodes for i in n.input}
        sub = onnx.helper.make_graph(nodes, name, in_info, out_info, [inits[i] for i in inits if i in used])
        stages.append(Stage(name, onnx.helper.make_model(sub, opset_imports=list(model_copy.opset_import), ir_version=model_copy.ir_version),
                            tuple(ins), tuple(outs), len(nodes)))
    return stages


def _session(model: onnx.ModelProto, options: ort.SessionOptions) -> ort.InferenceSession:
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"])


def time_stages(path: str | Path, feeds: dict[str, np.ndarray], options_for: Callable[[], ort.SessionOptions],
                repeat: int = 5, warmup: int = 1) -> dict[str, list[float]]:
    """Per-stage wall times (ms, one entry per repeat), stages run one after another on real cut values."""
    model = onnx.load(str(path))
    try:
        stages = split_stages(model)
    except Exception as exc:
        raise ArtifactError(f"model {path}: cannot split into stages ({exc})") from exc
    sessions = [_session(s.model, options_for()) for s in stages]
    times: dict[str, list[float]] = {s.name: [] for s in stages}
    for i in range(warmup + repeat):
        values = dict(feeds)
        for stage, session in zip(stages, sessions):
            t0 = time.perf_counter()
            outs = session.run(list(stage.outputs), {k: values[k] for k in stage.inputs})
            dt = (time.perf_counter() - t0) * 1e3
            values.update(zip(stage.outputs, outs))
            if i >= warmup:
                times[stage.name].append(dt)
    return times
