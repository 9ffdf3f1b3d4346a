"""The stages of an exported graph, found by position: backbone+neck, view transform, head.

    region = image_region(onnx.load("model.onnx"))     # the image trunk's node names (what int8 quantizes)
    times = time_stages("model.onnx", feeds, options)   # each stage timed as a model of its own (bench)

ORT's profiler reports nodes of the *optimised* graph, whose names and fusions change with the
ORT version and the CPU (NCHWc reorders, fused Conv+Relu); attributing them back is fragile.
Cutting the exported graph by position is not: the image trunk is every node upstream of the
view transform's warp (the first nodes that combine the image features with a geometry table)
that depends on the images alone (as int8 quantization finds it), the view transform ends at the
last node reading a ``geom.pool.*`` table (FisheyeBEVDet: warp, depth/context net, lift,
pooling) or at the last node reading the warp's taps (FisheyePETR: the warp), and the head is
everything else (a virtual-camera front end, which makes the training images from the robot's, counts with the
image trunk). Each stage becomes a model of its own, fed with the values
the full graph computes at its cut, and is timed with the same session options. The stages
cannot be fused across a cut, so their sum is compared with the full graph's time.

Needs the ``onnx`` package (the ``export`` extra).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort

from fisheye_infer.errors import ArtifactError
from fisheye_infer.geometry.tables import POOL_PREFIX, PREFIX, WARP
from fisheye_infer.geometry.virtual import VIRTUAL
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.session import Provider, open_session

__all__ = ["STAGES", "Stage", "name_nodes", "image_region", "split_stages", "time_stages"]

STAGES = ("backbone_neck", "view_transform", "head")


@dataclass(frozen=True)
class Stage:
    name: str
    model: onnx.ModelProto
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    nodes: int


def name_nodes(model: onnx.ModelProto) -> None:
    """Give every node a unique name: ``nodes_to_quantize`` selects by name."""
    seen: set[str] = set()
    for i, node in enumerate(model.graph.node):
        if not node.name or node.name in seen:
            node.name = f"{node.op_type}_{i}"
        seen.add(node.name)


def image_region(model: onnx.ModelProto) -> list[str]:
    """Names of the nodes that make up the image trunk (normalisation, backbone, neck), in graph order.

    The anchors are the nodes that combine a value derived from the images alone with one derived
    from a ``geom.*`` table: the warp's gathers (or a GridSample). A node belongs to the region
    when it is an ancestor of an anchor's image input and none of its inputs derive from
    ``camera_valid`` or from a ``geom.*`` table. Every node needs a name (``name_nodes``). Raises
    ``ArtifactError`` when no node samples the image features with a geometry table.
    """
    graph = model.graph
    # a virtual-camera front end's tables (geom.virtual.*) make the training images: part of the image path
    from_geometry = {i.name for i in graph.initializer if i.name.startswith(PREFIX) and not i.name.startswith(VIRTUAL)}
    tainted = set(from_geometry) | {INPUT_CAMERA_VALID}  # values that must not feed the region
    from_images = {INPUT_IMAGES}
    producer: dict[str, onnx.NodeProto] = {}
    anchors: list[onnx.NodeProto] = []
    for node in graph.node:  # ONNX graphs are topologically sorted
        for out in node.output:
            producer[out] = node
        ins = [n for n in node.input if n]
        if any(n in from_images for n in ins) and any(n in from_geometry for n in ins):
            anchors.append(node)
        if any(n in from_geometry for n in ins):
            from_geometry.update(node.output)
        if any(n in tainted for n in ins):
            tainted.update(node.output)
        elif any(n in from_images for n in ins):
            from_images.update(node.output)
    if not anchors:
        raise ArtifactError(
            "no node samples the image features with a geometry table (geom.*); cannot locate the image backbone and "
            "neck"
        )
    region: set[str] = set()
    stack = [n for a in anchors for n in a.input if n in from_images]
    while stack:
        value = stack.pop()
        node = producer.get(value)
        if node is None or node.name in region or value in tainted:
            continue
        region.add(node.name)
        stack.extend(n for n in node.input if n)
    return [n.name for n in graph.node if n.name in region]


def _assign(model: onnx.ModelProto) -> dict[str, str]:
    """node name -> stage name (every node named; see ``name_nodes``)."""
    graph = model.graph
    trunk = set(image_region(model))
    pool_readers = [n for n in graph.node if any(i.startswith(POOL_PREFIX) for i in n.input)]
    anchors = pool_readers[-1:] or [n for n in graph.node if any(i.startswith(WARP) for i in n.input)]
    producer = {o: n for n in graph.node for o in n.output}
    view: set[str] = set()
    stack = [anchors[-1]]
    while stack:
        node = stack.pop()
        if node.name in view or node.name in trunk:
            continue
        view.add(node.name)
        stack.extend(producer[i] for i in node.input if i in producer)
    return {
        n.name: "backbone_neck" if n.name in trunk else "view_transform" if n.name in view else "head"
        for n in graph.node
    }


def split_stages(model: onnx.ModelProto) -> list[Stage]:
    """The three stage models; inputs and outputs are the values crossing each cut."""
    model_copy = onnx.ModelProto()
    model_copy.CopyFrom(model)
    name_nodes(model_copy)
    graph = model_copy.graph
    stage_of = _assign(model_copy)
    produced_in = {o: stage_of[n.name] for n in graph.node for o in n.output}
    graph_inputs = {i.name: i for i in graph.input}
    inits = {i.name: i for i in graph.initializer}
    inferred = onnx.shape_inference.infer_shapes(model_copy, strict_mode=False)
    types = {
        v.name: v.type.tensor_type.elem_type for v in list(inferred.graph.value_info) + list(inferred.graph.output)
    }
    stages = []
    for name in STAGES:
        nodes = [n for n in graph.node if stage_of[n.name] == name]
        reads = [i for n in nodes for i in n.input if i and i not in inits]
        ins = list(dict.fromkeys(i for i in reads if produced_in.get(i, "input") != name))
        read_later = {i for n in graph.node if stage_of[n.name] != name for i in n.input} | {
            o.name for o in graph.output
        }
        outs = list(dict.fromkeys(o for n in nodes for o in n.output if o in read_later))
        in_info = [
            graph_inputs[i]
            if i in graph_inputs
            else onnx.helper.make_tensor_value_info(i, types.get(i, onnx.TensorProto.FLOAT), None)
            for i in ins
        ]
        out_info = [onnx.helper.make_tensor_value_info(o, types.get(o, onnx.TensorProto.FLOAT), None) for o in outs]
        used = {i for n in nodes for i in n.input}
        sub = onnx.helper.make_graph(nodes, name, in_info, out_info, [inits[i] for i in inits if i in used])
        stages.append(
            Stage(
                name,
                onnx.helper.make_model(
                    sub, opset_imports=list(model_copy.opset_import), ir_version=model_copy.ir_version
                ),
                tuple(ins),
                tuple(outs),
                len(nodes),
            )
        )
    return stages


def _session(
    model: onnx.ModelProto, options: ort.SessionOptions, providers: Sequence[Provider]
) -> ort.InferenceSession:
    return open_session(model.SerializeToString(), options, providers, f"stage model {model.graph.name}")


def time_stages(
    path: str | Path,
    feeds: dict[str, np.ndarray],
    options_for: Callable[[], ort.SessionOptions],
    repeat: int = 5,
    warmup: int = 1,
    providers: Sequence[Provider] = ("CPUExecutionProvider",),
) -> dict[str, list[float]]:
    """Per-stage wall times (ms, one entry per repeat), stages run one after another on real cut values.

    In a GPU provider each stage's time includes copying its inputs in and its outputs back."""
    model = onnx.load(str(path))
    try:
        stages = split_stages(model)
    except Exception as exc:
        raise ArtifactError(f"model {path}: cannot split into stages ({exc})") from exc
    sessions = [_session(s.model, options_for(), providers) for s in stages]
    times: dict[str, list[float]] = {s.name: [] for s in stages}
    for i in range(warmup + repeat):
        values = dict(feeds)
        for stage, session in zip(stages, sessions):
            t0 = time.perf_counter()
            with flushed_denormals():
                outs = session.run(list(stage.outputs), {k: values[k] for k in stage.inputs})
            dt = (time.perf_counter() - t0) * 1e3
            values.update(zip(stage.outputs, outs))
            if i >= warmup:
                times[stage.name].append(dt)
    return times
