"""Which nodes of an fp32 graph the int8 file quantizes: its scope, found by graph position.

    nodes = int8_nodes(onnx.load("model.onnx"))          # what int8 covers, in graph order
    quantized_scope(model, "trunk")                      # the one-line summary the int8 file records

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
layer norms and the box decoding, and the modules named in ``keep_float``: those the int8 search
chooses (``int8_search``, starting from the architecture's ``int8_float``), or a user's.

The regions are found by graph position, initializer names and each node's recorded module path,
not by node names (which change with the exporter). Kept apart from ``quantize``, which runs ONNX
Runtime's quantizer on what this chooses: the choice is a question about the graph alone, asked
again to describe the file (``quantized_scope``) and to check that QAT simulates the same layers.
"""

from __future__ import annotations

import ast
from collections.abc import Sequence

import onnx

from fisheye_infer.errors import ArtifactError, ExportError
from fisheye_infer.export import graph_stages
from fisheye_infer.export.graph_stages import name_nodes
from fisheye_infer.geometry.tables import PREFIX as GEOMETRY_PREFIX
from fisheye_infer.precision import under_module

from .options import SCOPES
from .trace import TRACE_ROOT

__all__ = [
    "SCOPES",
    "TRUNK_OPS",
    "WEIGHTED_OPS",
    "image_region",
    "int8_layer_modules",
    "int8_nodes",
    "module_of",
    "quantized_scope",
]

#: Layers with weights, which ``network`` quantizes beyond the trunk when their weight is an initializer.
WEIGHTED_OPS = ("Conv", "ConvTranspose", "MatMul", "Gemm")

#: Trunk ops that get QDQ pairs: compute, not data movement (a Reshape or Concat costs the same in
#: either precision, and each op type listed makes ORT's calibration record every node of that type
#: in the graph, the view transform's large tensors included).
TRUNK_OPS = ("Conv", "Relu", "Add", "MaxPool", "Resize")


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


def int8_layer_modules(model: onnx.ModelProto, scope: str = "network", keep_float: Sequence[str] = ()) -> list[str]:
    """The module (``module_of``) of each weighted layer ``int8_nodes`` covers, in graph order: what the int8
    search groups into candidates to keep float32 (the input is left as it is)."""
    model = _named(model)
    nodes = set(int8_nodes(model, scope, keep_float))
    weights = {i.name for i in model.graph.initializer}
    return [module_of(n, weights) for n in model.graph.node if n.name in nodes and n.op_type in WEIGHTED_OPS]


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
    """``model`` when every node has a unique name already, else a copy with every node named (the input is
    left as it is)."""
    names = [n.name for n in model.graph.node]
    if all(names) and len(set(names)) == len(names):
        return model
    copy = onnx.ModelProto()
    copy.CopyFrom(model)
    name_nodes(copy)
    return copy
