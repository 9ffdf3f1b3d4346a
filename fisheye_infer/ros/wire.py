"""Protobuf's wire format written from numpy arrays, for messages with thousands of small repeated entries.

    points = entries(3, POINT2, uv)                     # (P, 20) uint8: each pixel as a Point2 in field 3
    data = length_delimited(2, heads, head_of, points, starts)   # repeated field 2 of messages, encoded
    cameras = length_delimited_parts(2, heads, head_of, points, starts, parts)   # the same, cut between messages

A ``foxglove.ImageAnnotations`` of a hundred boxes holds some 40,000 ``Point2`` entries; building each as a
protobuf object costs a Python call per point. Here each entry of doubles (a ``Point2``, a ``CubePrimitive``)
is a fixed record (field keys and lengths around the doubles) written by numpy, and each message of a
repeated field is the encoding of its other fields (``heads``, serialised once by protobuf itself) followed
by its entries. Protobuf reads a
message's fields in any order and appends the entries of a repeated field wherever they occur, so the bytes
parse to the same message as one built field by field.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np

__all__ = [
    "COLOR",
    "POINT2",
    "Layout",
    "QUATERNION",
    "VECTOR3",
    "entries",
    "key",
    "length_delimited",
    "length_delimited_parts",
    "varint",
]

#: A message of doubles: its fields in order, each ``(number, None)`` for a double or ``(number, layout)``.
Layout = tuple[tuple[int, "Layout | None"], ...]
#: Foxglove's ``Point2`` (x, y), ``Vector3`` (x, y, z), ``Quaternion`` (x, y, z, w) and ``Color`` (r, g, b, a).
POINT2: Layout = ((1, None), (2, None))
VECTOR3: Layout = ((1, None), (2, None), (3, None))
QUATERNION: Layout = ((1, None), (2, None), (3, None), (4, None))
COLOR: Layout = QUATERNION
_LENGTH_DELIMITED = 2
_FIXED64 = 1


def key(field: int, wire_type: int = _LENGTH_DELIMITED) -> bytes:
    """A field's key (its number and wire type) as protobuf encodes it.

    Args:
        field (int): the field number, 1 or more.
        wire_type (int): protobuf's wire type (2: length-delimited).

    Returns:
        bytes: the key's varint.
    """
    return varint(field << 3 | wire_type)


def varint(value: int) -> bytes:
    """A non-negative integer as a protobuf varint.

    Args:
        value (int): 0 or more.

    Returns:
        bytes: seven bits a byte, least significant first, the high bit set on all but the last.
    """
    out = bytearray()
    while value > 0x7F:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)
    return bytes(out)


def _varints(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Non-negative integers as varints: an (N, W) uint8 array of their bytes (W the longest) and their lengths."""
    values = np.asarray(values, np.int64)
    widths = np.ones(len(values), np.int64)
    width = 1
    while (values >> 7 * width).any():
        widths += (values >> 7 * width) > 0
        width += 1
    out = np.empty((len(values), width), np.uint8)
    for j in range(width):
        out[:, j] = (values >> 7 * j) & 0x7F | np.where(widths > j + 1, 0x80, 0)
    return out, widths


def _template(layout: Layout) -> tuple[bytes, list[int]]:
    """A message of ``layout`` with every double 0: its bytes, and where each double goes in them."""
    body = bytearray()
    offsets: list[int] = []
    for number, inner in layout:
        if inner is None:
            body += key(number, _FIXED64)
            offsets.append(len(body))
            body += bytes(8)
        else:
            nested, nested_offsets = _template(inner)
            body += key(number) + varint(len(nested))
            offsets += [len(body) + o for o in nested_offsets]
            body += nested
    return bytes(body), offsets


def entries(field: int, layout: Layout, values: np.ndarray) -> np.ndarray:
    """Messages of doubles (and messages of doubles) as the entries of a repeated field, one a row.

    Args:
        field (int): the repeated field's number.
        layout (Layout): the message's fields in order, each ``(number, None)`` for a double or
            ``(number, layout)`` for a message, e.g. ``((1, None), (2, None))`` for a ``Point2``.
        values (np.ndarray): (N, D) the doubles of each message in the layout's order, depth first.

    Returns:
        np.ndarray: (N, R) uint8, each row the field's key, the message's length and the message.

    Raises:
        ValueError: ``values`` without one column per double of the layout.
    """
    template, doubles, names = _entry(field, layout)
    if values.ndim != 2 or values.shape[1] != len(names):
        raise ValueError(f"values: expected (N, {len(names)}) for the layout's doubles, got {values.shape}")
    out = np.empty((len(values), len(template)), np.uint8)
    out[:] = template
    records = out.reshape(-1).view(doubles)
    for i, name in enumerate(names):
        records[name] = values[:, i]
    return out


@lru_cache(maxsize=64)
def _entry(field: int, layout: Layout) -> tuple[np.ndarray, np.dtype, tuple[str, ...]]:
    """An entry of ``layout`` in field ``field`` with every double 0, a record type of its doubles in place, and
    their names in it."""
    body, offsets = _template(layout)
    head = key(field) + varint(len(body))
    names = tuple(f"d{i}" for i in range(len(offsets)))
    places = [len(head) + o for o in offsets]
    size = len(head) + len(body)
    doubles = np.dtype({"names": names, "formats": ["<f8"] * len(names), "offsets": places, "itemsize": size})
    return np.frombuffer(head + body, np.uint8), doubles, names


def length_delimited(
    field: int, heads: Sequence[bytes], head_of: np.ndarray, entries: np.ndarray, starts: np.ndarray
) -> bytes:
    """Messages as the entries of a repeated field ``field``: message ``i`` is ``heads[head_of[i]]`` followed by
    rows ``starts[i]:starts[i + 1]`` of ``entries``.

    Args:
        field (int): the repeated field's number.
        heads (Sequence[bytes]): encoded fields the messages share (each a protobuf ``SerializeToString()``).
        head_of (np.ndarray): (L,) int, the head of each message.
        entries (np.ndarray): (E, R) uint8, encoded rows of R bytes each (``entries``, or R = 1 for bytes).
        starts (np.ndarray): (L + 1,) int, each message's first row in ``entries``, ending with E.

    Returns:
        bytes: the L messages, each its field key, length and body.
    """
    return length_delimited_parts(field, heads, head_of, entries, starts, np.array([0, len(head_of)]))[0]


def length_delimited_parts(
    field: int,
    heads: Sequence[bytes],
    head_of: np.ndarray,
    entries: np.ndarray,
    starts: np.ndarray,
    parts: np.ndarray,
) -> list[bytes]:
    """``length_delimited`` of all the messages at once, cut into parts: part ``j`` holds messages
    ``parts[j]:parts[j + 1]`` (e.g. one part per camera's message).

    Args:
        field (int): the repeated field's number.
        heads (Sequence[bytes]): encoded fields the messages share.
        head_of (np.ndarray): (L,) int, the head of each message.
        entries (np.ndarray): (E, R) uint8, encoded rows of R bytes each.
        starts (np.ndarray): (L + 1,) int, each message's first row in ``entries``, ending with E.
        parts (np.ndarray): (G + 1,) int, non-decreasing message indices from 0 to L.

    Returns:
        list[bytes]: the G parts, each its messages encoded one after another.
    """
    if len(head_of) == 0:
        return [b""] * (len(parts) - 1)
    tag = np.frombuffer(key(field), np.uint8)
    counts = np.diff(starts)
    head_sizes = np.array([len(h) for h in heads], np.int64)
    lengths, widths = _varints(head_sizes[head_of] + counts * entries.shape[1])
    # each message's prefix (key, length, head) as a row of a table, then all of them in order
    prefix_sizes = len(tag) + widths + head_sizes[head_of]
    table = np.zeros((len(head_of), len(tag) + lengths.shape[1] + int(head_sizes.max())), np.uint8)
    table[:, : len(tag)] = tag
    table[:, len(tag) : len(tag) + lengths.shape[1]] = lengths
    widest = int(head_sizes.max())
    padded_heads = np.frombuffer(b"".join(h.ljust(widest, b"\x00") for h in heads), np.uint8).reshape(
        len(heads), widest
    )
    for width in range(1, lengths.shape[1] + 1):
        rows = np.flatnonzero(widths == width)
        table[rows, len(tag) + width : len(tag) + width + padded_heads.shape[1]] = padded_heads[head_of[rows]]
    prefixes = table[np.arange(table.shape[1]) < prefix_sizes[:, None]]
    # the prefixes go in before each message's entries, which follow one another as they do in ``entries``
    before = np.zeros(len(head_of) + 1, np.int64)
    np.cumsum(prefix_sizes, out=before[1:])
    at = starts * entries.shape[1] + before  # where each message begins in the output, then its end
    is_prefix = np.zeros(len(prefixes) + entries.size, bool)
    is_prefix[np.arange(len(prefixes)) + np.repeat(at[:-1] - before[:-1], prefix_sizes)] = True
    out = np.empty(len(is_prefix), np.uint8)
    out[is_prefix] = prefixes
    out[~is_prefix] = entries.reshape(-1)
    bounds = at[np.asarray(parts)].tolist()
    return [out[a:b].tobytes() for a, b in zip(bounds[:-1], bounds[1:])]
