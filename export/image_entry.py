"""The network's image entry, as ``models.normalise.normalise_frames`` exports it, handed over to a front end.

    entry = find_image_entry(proto, "images", 320, 320)   # None where the graph starts otherwise
    take_image_entry(proto, entry)                        # its nodes and constants out, kept in the metadata
    restore_image_entry(proto)                            # back where they were, to the byte

An exported fisheye network starts ``Cast`` (uint8 -> float32) -> ``Reshape`` (B*N, H, W*3) -> ``Sub`` (the mean
tiled along a row) -> ``Reshape`` (B*N, H, W, 3) -> ``Transpose`` (B*N, 3, H, W). A front end that computes the
images channels-first subtracts the mean on its planes and writes the entry's output itself, so the images are
laid out once instead of turned channels-last and back.
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from .graph import GRAPH_OUTPUT_READER, readers_of

__all__ = ["IMAGE_ENTRY_KEY", "ImageEntry", "find_image_entry", "restore_image_entry", "take_image_entry"]

#: The metadata entry that keeps a taken image entry (its nodes and constants) for ``restore_image_entry``.
IMAGE_ENTRY_KEY = "fisheye_infer.image_entry"

_CHAIN = ("Cast", "Reshape", "Sub", "Reshape", "Transpose")


@dataclass(frozen=True)
class ImageEntry:
    """An image entry found in a graph.

    Attributes:
        nodes: The entry's five nodes (cast, row view, mean subtraction, pixel view, transposition), in order.
        mean: (3,) float32, the mean subtracted from each input channel.
        output: The (B*N, 3, H, W) float32 value the network reads after the entry.
    """

    nodes: tuple[onnx.NodeProto, ...]
    mean: np.ndarray
    output: str


def _constant(graph: onnx.GraphProto, name: str) -> np.ndarray | None:
    return next((numpy_helper.to_array(i) for i in graph.initializer if i.name == name), None)


def _attr(node: onnx.NodeProto, name: str) -> object:
    return next((onnx.helper.get_attribute_value(a) for a in node.attribute if a.name == name), None)


def find_image_entry(proto: onnx.ModelProto, images: str, height: int, width: int) -> ImageEntry | None:
    """The image entry that reads ``images`` (B, N, ``height``, ``width``, 3), or None where the graph starts with
    anything else (a resampling front end, fp16, another layout).

    Args:
        proto: An exported graph.
        images: The name of its camera images.
        height: The images' height.
        width: The images' width.

    Returns:
        ImageEntry | None: The entry, when each of its values has its next node as its one reader.
    """
    graph = proto.graph
    readers = readers_of(graph)
    nodes: list[onnx.NodeProto] = []
    value = images
    for op in _CHAIN:
        found = readers.get(value, [])
        if len(found) != 1 or found[0] is GRAPH_OUTPUT_READER or found[0].op_type != op:
            return None
        node = found[0]
        if node.input[0] != value:
            return None
        nodes.append(node)
        value = node.output[0]
    cast, rows, sub, pixels, transpose = nodes
    row_shape, pixel_shape = _constant(graph, rows.input[1]), _constant(graph, pixels.input[1])
    tiled = _constant(graph, sub.input[1])
    if (
        _attr(cast, "to") != TensorProto.FLOAT
        or row_shape is None
        or row_shape.tolist() != [-1, height, width * 3]
        or pixel_shape is None
        or pixel_shape.tolist() != [-1, height, width, 3]
        or tiled is None
        or tiled.dtype != np.float32
        or tiled.shape != (width * 3,)
        or not np.array_equal(tiled, np.tile(tiled[:3], width))
        or _attr(transpose, "perm") != [0, 3, 1, 2]
    ):
        return None
    return ImageEntry(nodes=tuple(nodes), mean=tiled[:3].copy(), output=transpose.output[0])


def take_image_entry(proto: onnx.ModelProto, entry: ImageEntry) -> None:
    """Remove ``entry``'s nodes and the constants only they read from ``proto`` (in place), kept in its metadata
    under ``IMAGE_ENTRY_KEY``; the entry's output is left for another node to write."""
    graph = proto.graph
    written = {n.output[0] for n in entry.nodes}
    node_at = [i for i, n in enumerate(graph.node) if n.output and n.output[0] in written]
    readers = readers_of(graph)
    names = {
        name for n in entry.nodes for name in n.input if all(r.output and r.output[0] in written for r in readers[name])
    }
    init_at = [i for i, init in enumerate(graph.initializer) if init.name in names]
    kept = onnx.GraphProto(
        node=[graph.node[i] for i in node_at],
        initializer=[graph.initializer[i] for i in init_at],
        doc_string=json.dumps({"nodes": node_at, "initializers": init_at}),
    )
    for i in reversed(node_at):
        del graph.node[i]
    for i in reversed(init_at):
        del graph.initializer[i]
    proto.metadata_props.add(key=IMAGE_ENTRY_KEY, value=base64.b64encode(kept.SerializeToString()).decode("ascii"))


def restore_image_entry(proto: onnx.ModelProto) -> bool:
    """Put a taken image entry back (in place), each node and constant where it was.

    Returns:
        bool: Whether ``proto`` kept one.
    """
    prop = next((p for p in proto.metadata_props if p.key == IMAGE_ENTRY_KEY), None)
    if prop is None:
        return False
    kept = onnx.GraphProto.FromString(base64.b64decode(prop.value))
    places = json.loads(kept.doc_string)
    graph = proto.graph
    for i, node in zip(places["nodes"], kept.node):
        graph.node.insert(i, node)
    for i, init in zip(places["initializers"], kept.initializer):
        graph.initializer.insert(i, init)
    proto.metadata_props.remove(prop)
    return True
