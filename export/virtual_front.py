"""A virtual-camera front end in an exported graph: the robot's raw images in, the training cameras' images out.

    attach_front(proto, front)                  # the graph's images input becomes the robot's padded images
    detach_front(proto)                         # back to the graph that takes the training cameras' images

The graph's ``images`` input (B, N, Ht, Wt, 3) uint8 is replaced by a new ``images`` input (B, N, Hp, Wp, 3)
uint8, the robot's images padded to the largest camera (``fisheye_infer.geometry.virtual``): the images cast to
float32 and made planar, one plane per channel and camera (B, 3*N, Hp*Wp); per channel, every tap of every output
pixel read by a GatherElements over the N camera planes (ONNX Runtime gathers the planes on its threads; the index
table is broadcast over the batch by adding zeros of shape (B, 1, 1), which runs on the session's threads where an
Expand runs on one), the four taps weighed (Mul) and summed (a MatMul by a row of ones, several times faster in ONNX
Runtime than a ReduceSum over the taps); then the fill added with cv2.remap's rounding offset and the sum rounded
down (``floor(x + 0.5)``, as cv2.remap rounds; every product and sum is exact in float32).

Where the network starts with the image entry that ``models.normalise.normalise_frames`` exports (cast, mean
subtracted, channels-first; ``image_entry``), the front end takes it over: it subtracts the mean on its planes and
writes the entry's (B*N, 3, Ht, Wt) output, and the entry's nodes are kept in the metadata for ``detach_front``.
Elsewhere the result is laid out as the training images (B, N, Ht, Wt, 3) float32 (whole numbers 0-255) for the
network's own cast to float. TensorRT takes UINT8 only at a network's edge, so the front end casts first. Every
elementwise step runs over long rows of one channel and tap (ONNX Runtime's broadcasting and Gather are slow on
short inner rows). Standard ops only; the nodes are named under ``NODE_PREFIX`` so that a file can be re-targeted.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.errors import ArtifactError
from fisheye_infer.geometry.virtual import VIRTUAL, VIRTUAL_FILL, VIRTUAL_INDEX, VIRTUAL_WEIGHT, VirtualFront
from fisheye_infer.runtime.artifact import INPUT_IMAGES

from .graph import rename_values
from .image_entry import find_image_entry, restore_image_entry, take_image_entry

__all__ = ["NODE_PREFIX", "TRAINING_IMAGES", "attach_front", "detach_front", "has_front"]

NODE_PREFIX = "virtual_front/"
#: The internal value that holds the training cameras' images once a front end feeds the network.
TRAINING_IMAGES = "virtual_front/training_images"


def has_front(proto: onnx.ModelProto) -> bool:
    """Whether ``proto`` already starts with a virtual-camera front end."""
    return any(node.name.startswith(NODE_PREFIX) for node in proto.graph.node)


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


_FLOAT_TYPES = (TensorProto.FLOAT, TensorProto.FLOAT16, TensorProto.BFLOAT16)


def _check_consumers(graph: onnx.GraphProto, name: str) -> None:
    """Refuse a graph that reads ``name`` (its camera images) other than by a cast to a float type or its shape:
    the front end hands the network float32 images."""
    for node in graph.node:
        if name not in node.input:
            continue
        to = next((a.i for a in node.attribute if a.name == "to"), None)
        if not (node.op_type == "Shape" or (node.op_type == "Cast" and to in _FLOAT_TYPES)):
            raise ArtifactError(
                f"virtual cameras: node {node.name!r} ({node.op_type}) reads the camera images as they are; "
                "the front end needs a network that casts them to float first"
            )


def attach_front(proto: onnx.ModelProto, front: VirtualFront) -> None:
    """Put ``front`` before the network of ``proto`` (in place); an existing front end is replaced.

    Args:
        proto: An exported graph (its ``images`` input: the training cameras' images).
        front: The tables and padded size of [`virtual_front`][fisheye_infer.geometry.virtual.virtual_front].

    Raises:
        ArtifactError: The graph has no ``images`` input, its images are not the size the tables resample to, or a
            node reads them other than by a cast to float or their shape (``proto`` is left as it was).
    """
    if has_front(proto):
        detach_front(proto)
    graph = proto.graph
    images = _images_input(proto)
    batch = onnx.TensorShapeProto.Dimension()
    batch.CopyFrom(images.type.tensor_type.shape.dim[0])
    n, ht, wt = (d.dim_value for d in images.type.tensor_type.shape.dim[1:4])
    pw, ph = front.padded_size
    hw = ht * wt
    shape = front.tables[VIRTUAL_WEIGHT].shape
    if shape != (n, 4, hw):
        raise ArtifactError(
            f"virtual cameras: the weight table is {shape} (cameras, taps, pixels); the graph takes {n} images of "
            f"{ht}x{wt}, so ({n}, 4, {hw})"
        )
    _check_consumers(graph, INPUT_IMAGES)
    entry = find_image_entry(proto, INPUT_IMAGES, ht, wt)
    if entry is not None:
        take_image_entry(proto, entry)
    else:
        rename_values(proto, {INPUT_IMAGES: TRAINING_IMAGES})
    kept = [v for v in graph.input if v.name not in (INPUT_IMAGES, TRAINING_IMAGES)]
    new_input = helper.make_tensor_value_info(INPUT_IMAGES, TensorProto.UINT8, None)
    _set_shape(new_input, batch, (n, ph, pw, 3))
    del graph.input[:]
    graph.input.extend([new_input, *kept])
    p = NODE_PREFIX
    fill = front.tables[VIRTUAL_FILL] + np.float32(0.5)
    consts = {
        f"{p}flat_shape": np.array([0, -1, 3], np.int64),
        f"{p}camera_planes": np.array([0, 3 * n, ph * pw], np.int64),
        f"{p}split": np.array([n, n, n], np.int64),
        f"{p}batch_tail": np.array([1, 1], np.int64),
        f"{p}first": np.array([0], np.int64),
        f"{p}second": np.array([1], np.int64),
        f"{p}taps_shape": np.array([0, n, 4, hw], np.int64),
        f"{p}sum_taps": np.ones((1, 4), np.float32),
    }
    if entry is not None:  # (B, N, 3, H*W) planes, the mean subtracted, as the network's first convolution reads them
        consts |= {
            f"{p}rounding": fill.reshape(n, 1, hw),
            f"{p}mean": entry.mean.reshape(3, 1),
            f"{p}planar_shape": np.array([-1, 3, ht, wt], np.int64),
        }
    else:  # (B, N, Ht, Wt, 3) images for the network's own cast
        consts |= {
            f"{p}rounding": fill,
            f"{p}channel_shape": np.array([0, 1, n, hw], np.int64),
            f"{p}planar_shape": np.array([0, 3, n, ht, wt], np.int64),
        }
    graph.initializer.extend(numpy_helper.from_array(np.ascontiguousarray(a), name) for name, a in consts.items())
    graph.initializer.extend(
        numpy_helper.from_array(np.ascontiguousarray(a), name)
        for name, a in front.tables.items()
        if name != VIRTUAL_FILL  # added with the rounding offset, as ``rounding``
    )
    nodes = _taps(n)
    nodes += _planar_tail(entry.output) if entry is not None else _channels_last_tail()
    body = list(graph.node)
    del graph.node[:]
    graph.node.extend([*nodes, *body])


def _taps(n: int) -> list[onnx.NodeProto]:
    """The robot's images to each channel's tap sums, ``{p}summed{c}`` (B, N, 1, H*W)."""
    p = NODE_PREFIX
    channel = [f"{p}channel{c}" for c in range(3)]
    nodes = [
        helper.make_node("Cast", [INPUT_IMAGES], [f"{p}float"], name=f"{p}to_float", to=TensorProto.FLOAT),
        helper.make_node("Reshape", [f"{p}float", f"{p}flat_shape"], [f"{p}flat"], name=f"{p}flatten"),
        helper.make_node("Transpose", [f"{p}flat"], [f"{p}planar"], name=f"{p}to_planar", perm=[0, 2, 1]),
        helper.make_node("Reshape", [f"{p}planar", f"{p}camera_planes"], [f"{p}planes"], name=f"{p}planes"),
        helper.make_node("Split", [f"{p}planes", f"{p}split"], channel, name=f"{p}split", axis=1),
        helper.make_node("Shape", [f"{p}float"], [f"{p}input_shape"], name=f"{p}input_shape"),
        helper.make_node(
            "Slice", [f"{p}input_shape", f"{p}first", f"{p}second", f"{p}first"], [f"{p}batch"], name=f"{p}batch"
        ),
        helper.make_node(
            "Concat", [f"{p}batch", f"{p}batch_tail"], [f"{p}batch_shape"], name=f"{p}batch_shape", axis=0
        ),
        helper.make_node(
            "ConstantOfShape",
            [f"{p}batch_shape"],
            [f"{p}batch_zeros"],
            name=f"{p}batch_zeros",
            value=helper.make_tensor("zero", TensorProto.INT32, [1], [0]),
        ),
        helper.make_node("Add", [VIRTUAL_INDEX, f"{p}batch_zeros"], [f"{p}index"], name=f"{p}index_per_frame"),
    ]
    for c in range(3):
        nodes += [
            helper.make_node(
                "GatherElements", [channel[c], f"{p}index"], [f"{p}taps{c}"], name=f"{p}gather{c}", axis=2
            ),
            helper.make_node("Reshape", [f"{p}taps{c}", f"{p}taps_shape"], [f"{p}taps4_{c}"], name=f"{p}group{c}"),
            helper.make_node("Mul", [f"{p}taps4_{c}", VIRTUAL_WEIGHT], [f"{p}weighed{c}"], name=f"{p}weigh{c}"),
            helper.make_node("MatMul", [f"{p}sum_taps", f"{p}weighed{c}"], [f"{p}summed{c}"], name=f"{p}sum{c}"),
        ]
    return nodes


def _planar_tail(output: str) -> list[onnx.NodeProto]:
    """Tap sums -> the network's channels-first input ``output``: filled, rounded, the mean subtracted."""
    p = NODE_PREFIX
    return [
        helper.make_node("Concat", [f"{p}summed{c}" for c in range(3)], [f"{p}sum"], name=f"{p}channels", axis=2),
        helper.make_node("Add", [f"{p}sum", f"{p}rounding"], [f"{p}shifted"], name=f"{p}fill_and_round"),
        helper.make_node("Floor", [f"{p}shifted"], [f"{p}rounded"], name=f"{p}floor"),
        helper.make_node("Sub", [f"{p}rounded", f"{p}mean"], [f"{p}centred"], name=f"{p}centre"),
        helper.make_node("Reshape", [f"{p}centred", f"{p}planar_shape"], [output], name=f"{p}views"),
    ]


def _channels_last_tail() -> list[onnx.NodeProto]:
    """Tap sums -> the training cameras' images (B, N, Ht, Wt, 3), filled and rounded."""
    p = NODE_PREFIX
    nodes = [
        helper.make_node("Reshape", [f"{p}summed{c}", f"{p}channel_shape"], [f"{p}sum{c}"], name=f"{p}as_channel{c}")
        for c in range(3)
    ]
    return [
        *nodes,
        helper.make_node("Concat", [f"{p}sum{c}" for c in range(3)], [f"{p}sum"], name=f"{p}channels", axis=1),
        helper.make_node("Add", [f"{p}sum", f"{p}rounding"], [f"{p}shifted"], name=f"{p}fill_and_round"),
        helper.make_node("Floor", [f"{p}shifted"], [f"{p}rounded"], name=f"{p}floor"),
        helper.make_node("Reshape", [f"{p}rounded", f"{p}planar_shape"], [f"{p}views"], name=f"{p}views"),
        helper.make_node("Transpose", [f"{p}views"], [TRAINING_IMAGES], name=f"{p}images", perm=[0, 2, 3, 4, 1]),
    ]


def detach_front(proto: onnx.ModelProto) -> None:
    """Remove the front end of ``proto`` (in place): its ``images`` input takes the training cameras' images again.

    Args:
        proto: A graph with a front end (`attach_front`).

    Raises:
        ArtifactError: ``proto`` has no front end.
    """
    if not has_front(proto):
        raise ArtifactError("the graph has no virtual-camera front end")
    graph = proto.graph
    images = _images_input(proto)
    n = images.type.tensor_type.shape.dim[1].dim_value  # the robot's cameras stand in the model's, one for one
    image_shape = next(i for i in graph.initializer if i.name == f"{NODE_PREFIX}planar_shape")
    ht, wt = (int(d) for d in numpy_helper.to_array(image_shape)[-2:])
    batch = onnx.TensorShapeProto.Dimension()
    batch.CopyFrom(images.type.tensor_type.shape.dim[0])
    kept_nodes = [node for node in graph.node if not node.name.startswith(NODE_PREFIX)]
    del graph.node[:]
    graph.node.extend(kept_nodes)
    kept_inits = [i for i in graph.initializer if not i.name.startswith((NODE_PREFIX, VIRTUAL))]
    del graph.initializer[:]
    graph.initializer.extend(kept_inits)
    _set_shape(images, batch, (n, ht, wt, 3))
    if not restore_image_entry(proto):
        rename_values(proto, {TRAINING_IMAGES: INPUT_IMAGES})
