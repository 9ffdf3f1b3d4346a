"""A virtual-camera front end in an exported graph: the robot's raw images in, the training cameras' images out.

    attach_front(proto, front, training_hw)     # the graph's images input becomes the robot's padded images
    detach_front(proto)                         # back to the graph that takes the training cameras' images

The graph's ``images`` input (B, N, Ht, Wt, 3) uint8 becomes an internal value computed from a new ``images``
input (B, N, Hp, Wp, 3) uint8, the robot's images padded to the largest camera
(:mod:`fisheye_infer.geometry.virtual`): a Gather of each output pixel's four taps, one batched MatMul with their
weights, the fill added, and rounding to uint8 as cv2.remap rounds (``floor(x + 0.5)``; every product and sum is
exact in float32). Standard ops only; the nodes are named under ``NODE_PREFIX`` so that a file can be re-targeted.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.errors import ArtifactError
from fisheye_infer.geometry.virtual import VIRTUAL, VIRTUAL_FILL, VIRTUAL_INDEX, VIRTUAL_WEIGHT, VirtualFront
from fisheye_infer.runtime.artifact import INPUT_IMAGES

from .graph import rename_values

__all__ = ["NODE_PREFIX", "TRAINING_IMAGES", "attach_front", "detach_front", "has_front"]

NODE_PREFIX = "virtual_front/"
#: The internal value that holds the training cameras' images once a front end feeds the network.
TRAINING_IMAGES = "virtual_front/training_images"


def has_front(proto: onnx.ModelProto) -> bool:
    """Whether ``proto`` already starts with a virtual-camera front end."""
    return any(node.output and node.output[0] == TRAINING_IMAGES for node in proto.graph.node)


def _images_input(proto: onnx.ModelProto) -> onnx.ValueInfoProto:
    for value in proto.graph.input:
        if value.name == INPUT_IMAGES:
            return value
    raise ArtifactError(f"the graph has no '{INPUT_IMAGES}' input")


def _set_shape(value: onnx.ValueInfoProto, batch: onnx.TensorShapeProto.Dimension, dims: tuple[int, ...]) -> None:
    shape = value.type.tensor_type.shape
    del shape.dim[:]
    shape.dim.add().CopyFrom(batch)
    for d in dims:
        shape.dim.add().dim_value = d


def attach_front(proto: onnx.ModelProto, front: VirtualFront) -> None:
    """Put ``front`` before the network of ``proto`` (in place); an existing front end is replaced.

    Args:
        proto: An exported graph (its ``images`` input: the training cameras' images).
        front: The tables and padded size of :func:`~fisheye_infer.geometry.virtual.virtual_front`.
    """
    if has_front(proto):
        detach_front(proto)
    graph = proto.graph
    images = _images_input(proto)
    batch = onnx.TensorShapeProto.Dimension()
    batch.CopyFrom(images.type.tensor_type.shape.dim[0])
    n, ht, wt = (d.dim_value for d in images.type.tensor_type.shape.dim[1:4])
    pw, ph = front.padded_size
    pixels = front.tables[VIRTUAL_WEIGHT].shape[0]
    if pixels != n * ht * wt:
        raise ArtifactError(f"virtual cameras: the tables resample {pixels} pixels, the graph takes {n}x{ht}x{wt}")
    rename_values(proto, {INPUT_IMAGES: TRAINING_IMAGES})
    kept = [v for v in graph.input if v.name != TRAINING_IMAGES]
    new_input = helper.make_tensor_value_info(INPUT_IMAGES, TensorProto.UINT8, None)
    _set_shape(new_input, batch, (n, ph, pw, 3))
    del graph.input[:]
    graph.input.extend([new_input, *kept])
    p = NODE_PREFIX
    consts = {
        f"{p}flat_shape": np.array([0, -1, 3], np.int64),
        f"{p}taps_shape": np.array([0, pixels, 4, 3], np.int64),
        f"{p}image_shape": np.array([0, n, ht, wt, 3], np.int64),
        f"{p}half": np.array(0.5, np.float32),
    }
    graph.initializer.extend(numpy_helper.from_array(np.ascontiguousarray(a), name) for name, a in consts.items())
    graph.initializer.extend(numpy_helper.from_array(np.ascontiguousarray(a), name) for name, a in front.tables.items())
    nodes = [
        helper.make_node("Reshape", [INPUT_IMAGES, f"{p}flat_shape"], [f"{p}flat"], name=f"{p}flatten"),
        helper.make_node("Gather", [f"{p}flat", VIRTUAL_INDEX], [f"{p}taps"], name=f"{p}gather", axis=1),
        helper.make_node("Reshape", [f"{p}taps", f"{p}taps_shape"], [f"{p}taps4"], name=f"{p}group_taps"),
        helper.make_node("Cast", [f"{p}taps4"], [f"{p}tapsf"], name=f"{p}to_float", to=TensorProto.FLOAT),
        helper.make_node("MatMul", [VIRTUAL_WEIGHT, f"{p}tapsf"], [f"{p}sum"], name=f"{p}weigh"),
        helper.make_node("Add", [f"{p}sum", VIRTUAL_FILL], [f"{p}filled"], name=f"{p}fill"),
        helper.make_node("Add", [f"{p}filled", f"{p}half"], [f"{p}shifted"], name=f"{p}round_half_up"),
        helper.make_node("Floor", [f"{p}shifted"], [f"{p}rounded"], name=f"{p}floor"),
        helper.make_node("Cast", [f"{p}rounded"], [f"{p}pixels"], name=f"{p}to_uint8", to=TensorProto.UINT8),
        helper.make_node("Reshape", [f"{p}pixels", f"{p}image_shape"], [TRAINING_IMAGES], name=f"{p}images"),
    ]
    body = list(graph.node)
    del graph.node[:]
    graph.node.extend([*nodes, *body])


def detach_front(proto: onnx.ModelProto) -> None:
    """Remove the front end of ``proto`` (in place): its ``images`` input takes the training cameras' images again.

    Args:
        proto: A graph with a front end (:func:`attach_front`).

    Raises:
        ArtifactError: ``proto`` has no front end.
    """
    if not has_front(proto):
        raise ArtifactError("the graph has no virtual-camera front end")
    graph = proto.graph
    images = _images_input(proto)
    image_shape = next(i for i in graph.initializer if i.name == f"{NODE_PREFIX}image_shape")
    n, ht, wt = (int(d) for d in numpy_helper.to_array(image_shape)[1:4])
    batch = onnx.TensorShapeProto.Dimension()
    batch.CopyFrom(images.type.tensor_type.shape.dim[0])
    kept_nodes = [node for node in graph.node if not node.name.startswith(NODE_PREFIX)]
    del graph.node[:]
    graph.node.extend(kept_nodes)
    kept_inits = [i for i in graph.initializer if not i.name.startswith((NODE_PREFIX, VIRTUAL))]
    del graph.initializer[:]
    graph.initializer.extend(kept_inits)
    _set_shape(images, batch, (n, ht, wt, 3))
    rename_values(proto, {TRAINING_IMAGES: INPUT_IMAGES})
