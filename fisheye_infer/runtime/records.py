"""The one result-record format shared by the runtime, results files and the evaluator.

A record is a nuScenes-style detection dict, the layout the Fisheye3DOD evaluator converts
every box into before matching:

    {"translation": [x, y, z_centre],      # lidar frame, metres, GRAVITY centre
     "size": [w, l, h],                    # nuScenes order: width, length, height
     "rotation": [qw, qx, qy, qz],         # yaw about +z: (cos(yaw/2), 0, 0, sin(yaw/2))
     "detection_name": "Car",
     "detection_score": 0.87}              # ground truth carries -1.0

Three box layouts meet here, and the conversions between them live in this module only:

- runtime boxes (detector output, §5.4): ``x, y, z_bottom, l, w, h, yaw``, z at the bottom face;
- label boxes (``label_3d/*.json``, §3.2): ``x, y, z, l, w, h, yaw``, z at the gravity centre,
  so ``z_bottom = z - h / 2``;
- records: gravity centre, sizes reordered to (w, l, h), yaw as a quaternion.

Keeping one conversion avoids the half-height and (l, w) swaps that silently cost accuracy
when a runtime and an evaluator each convert on their own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from fisheye_infer.errors import FrameError

__all__ = [
    "CLASSES",
    "GT_SCORE",
    "RECORD_FIELDS",
    "bottom_to_gravity",
    "gravity_to_bottom",
    "yaw_to_quaternion",
    "quaternion_to_yaw",
    "boxes_to_records",
    "records_to_arrays",
    "record_columns",
]

#: Fisheye3DOD classes in label-id order (ids 0..5).
CLASSES: tuple[str, ...] = ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")
#: The score Fisheye3DOD gives ground-truth records.
GT_SCORE = -1.0
RECORD_FIELDS = ("translation", "size", "rotation", "detection_name", "detection_score")


def _boxes(boxes: np.ndarray, name: str = "boxes") -> np.ndarray:
    arr = np.asarray(boxes, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 7:
        raise ValueError(f"{name}: expected shape (K, 7) as x, y, z, l, w, h, yaw; got {arr.shape}")
    return arr


def bottom_to_gravity(boxes: np.ndarray) -> np.ndarray:
    """Runtime boxes (z at the bottom face) -> label boxes (z at the gravity centre), float64."""
    out = _boxes(boxes).copy()
    out[:, 2] += out[:, 5] / 2
    return out


def gravity_to_bottom(boxes: np.ndarray) -> np.ndarray:
    """Label boxes (z at the gravity centre) -> runtime boxes (z at the bottom face), float64."""
    out = _boxes(boxes).copy()
    out[:, 2] -= out[:, 5] / 2
    return out


def yaw_to_quaternion(yaw: np.ndarray) -> np.ndarray:
    """(K,) yaw about +z -> (K, 4) unit quaternions (w, x, y, z)."""
    half = np.asarray(yaw, dtype=np.float64) / 2
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, zeros, np.sin(half)], axis=-1)


def quaternion_to_yaw(q: np.ndarray) -> np.ndarray:
    """(K, 4) quaternions (w, x, y, z) -> (K,) yaw in [-pi, pi].

    As nuScenes measures it: rotate the unit x axis by the (normalised) quaternion and take
    the azimuth of the result, so a quaternion that is not a pure z rotation still gives the
    heading of the box's front in the x-y plane.
    """
    arr = np.asarray(q, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"rotation: expected shape (K, 4) as w, x, y, z; got {arr.shape}")
    norm = np.linalg.norm(arr, axis=1, keepdims=True)
    w, x, y, z = (arr / np.where(norm == 0, 1.0, norm)).T
    return np.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z))


def boxes_to_records(
    boxes: np.ndarray,
    scores: np.ndarray | None,
    labels: np.ndarray,
    class_names: Sequence[str] = CLASSES,
) -> list[dict[str, Any]]:
    """Runtime boxes -> nuScenes-style detection records, as the evaluator and results files hold them.

    Ground-truth label boxes (gravity-centred) go through ``gravity_to_bottom`` first.

    Args:
        boxes (np.ndarray): `(K, 7)` ``x, y, z_bottom, l, w, h, yaw``, lidar frame, metres and radians.
        scores (np.ndarray | None): `(K,)` confidences; None marks ground truth: every record gets
            ``GT_SCORE`` (-1.0), as the official evaluator stores it.
        labels (np.ndarray): `(K,)` integer class indices into ``class_names``.
        class_names (Sequence[str]): Class names in label order (default: the six Fisheye3DOD classes).

    Returns:
        list[dict[str, Any]]: K records with ``translation`` (box centre, m), ``size`` (w, l, h, m),
            ``rotation`` (w, x, y, z quaternion of the yaw), ``detection_name`` and ``detection_score``.

    Raises:
        ValueError: A shape disagrees with ``boxes``, a label is out of range, or a value is NaN or infinite.
    """
    b = _boxes(boxes)
    k = len(b)
    lab = np.asarray(labels)
    if lab.shape != (k,):
        raise ValueError(f"labels: expected shape ({k},) to match boxes, got {lab.shape}")
    if k and (not np.issubdtype(lab.dtype, np.integer) or lab.min() < 0 or lab.max() >= len(class_names)):
        raise ValueError(
            f"labels: expected integers in [0, {len(class_names)}), got {lab.dtype} {lab.min()}..{lab.max()}"
        )
    if scores is None:
        sc = np.full(k, GT_SCORE)
    else:
        sc = np.asarray(scores, dtype=np.float64)
        if sc.shape != (k,):
            raise ValueError(f"scores: expected shape ({k},) to match boxes, got {sc.shape}")
    if not np.all(np.isfinite(b)) or not np.all(np.isfinite(sc)):
        raise ValueError("boxes/scores: contain NaN or infinity")
    translation = bottom_to_gravity(b)[:, :3].tolist()
    size = b[:, [4, 3, 5]].tolist()
    rotation = yaw_to_quaternion(b[:, 6]).tolist()
    names = [class_names[i] for i in lab.tolist()]
    return [
        {"translation": t, "size": s, "rotation": r, "detection_name": n, "detection_score": float(c)}
        for t, s, r, n, c in zip(translation, size, rotation, names, sc.tolist())
    ]


def _column(records: Sequence[Mapping[str, Any]], field: str, width: int | None) -> np.ndarray | None:
    """One field of every record as a float array, or None if some record breaks the shape."""
    try:
        items = [r[field] for r in records]
        values = np.array(items)
    except (KeyError, TypeError, ValueError):
        return None
    if width is None and bool in set(map(type, items)):  # numpy would read True as 1.0
        return None
    expected = (len(records), width) if width else (len(records),)
    if values.shape != expected or values.dtype.kind not in "fiu":  # strings, bools, objects are refused
        return None
    return values.astype(np.float64, copy=False)


def _diagnose(records: Sequence[Any], class_names: Sequence[str], source: str, scored: bool = True) -> FrameError:
    """Walk the records one by one to name the first bad index and field; only called on failure."""
    fields = RECORD_FIELDS if scored else RECORD_FIELDS[:-1]
    for i, r in enumerate(records):
        where = f"{source}, record {i}"
        if not isinstance(r, Mapping):
            return FrameError(f"{where}: expected an object with {', '.join(fields)}, got {type(r).__name__}")
        for field in fields:
            if field not in r:
                return FrameError(f"{where}: missing field '{field}'")
        for field, width in (("translation", 3), ("size", 3), ("rotation", 4)):
            value = r[field]
            ok = isinstance(value, (list, tuple)) and len(value) == width
            ok = ok and all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)
            if not ok:
                return FrameError(f"{where}: '{field}' must be {width} finite numbers, got {value!r}")
        if any(v <= 0 for v in r["size"]):
            return FrameError(f"{where}: 'size' must be positive (w, l, h), got {r['size']!r}")
        if all(v == 0 for v in r["rotation"]):
            return FrameError(f"{where}: 'rotation' is the zero quaternion")
        name = r["detection_name"]
        if name not in class_names:
            return FrameError(f"{where}: 'detection_name' {name!r} is not one of {', '.join(class_names)}")
        if not scored:
            continue
        score = r["detection_score"]
        if not isinstance(score, (int, float)) or isinstance(score, bool) or not math.isfinite(score):
            return FrameError(f"{where}: 'detection_score' must be a finite number, got {score!r}")
    return FrameError(f"{source}: records are malformed")


def record_columns(
    records: Sequence[Mapping[str, Any]],
    class_names: Sequence[str] = CLASSES,
    *,
    source: str = "records",
    scored: bool = True,
) -> dict[str, np.ndarray]:
    """K records -> the evaluator's columns, without touching the numbers.

    ``translation`` (K, 3) gravity centre, ``size`` (K, 3) as (w, l, h), ``yaw`` (K,),
    ``score`` (K,) float64 and ``label`` (K,) int64. Validation is vectorised; only when it
    fails are the records walked one by one to name the bad index and field.
    ``scored=False`` reads ground truth: ``detection_score`` is ignored (it may be absent) and
    every score is ``GT_SCORE``.
    """
    if not isinstance(records, Sequence) or isinstance(records, (str, bytes)):
        raise FrameError(f"{source}: expected a list of records, got {type(records).__name__}")
    k = len(records)
    if k == 0:
        return {
            "translation": np.zeros((0, 3)),
            "size": np.zeros((0, 3)),
            "yaw": np.zeros(0),
            "score": np.zeros(0),
            "label": np.zeros(0, np.int64),
        }
    lookup = {name: i for i, name in enumerate(class_names)}
    try:
        translation = _column(records, "translation", 3)
        size = _column(records, "size", 3)
        rotation = _column(records, "rotation", 4)
        score = _column(records, "detection_score", None) if scored else np.full(k, GT_SCORE)
        label = np.array([lookup.get(r["detection_name"], -1) for r in records], dtype=np.int64)
    except (KeyError, TypeError):
        raise _diagnose(records, class_names, source, scored) from None
    if translation is None or size is None or rotation is None or score is None:
        raise _diagnose(records, class_names, source, scored)
    finite = all(np.all(np.isfinite(c)) for c in (translation, size, rotation, score))
    if not finite or np.any(label < 0) or np.any(size <= 0) or np.any(~rotation.any(axis=1)):
        raise _diagnose(records, class_names, source, scored)
    return {
        "translation": translation,
        "size": size,
        "yaw": quaternion_to_yaw(rotation),
        "score": score,
        "label": label,
    }


def records_to_arrays(
    records: Sequence[Mapping[str, Any]],
    class_names: Sequence[str] = CLASSES,
    *,
    source: str = "records",
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """K records -> runtime boxes (K, 7) bottom-centred float64, scores (K,) float64, labels (K,) int64.

    The inverse of ``boxes_to_records`` (yaw comes back in [-pi, pi]). Fields other than the
    five of ``RECORD_FIELDS`` (``sample_token``, ``velocity``, ...) are ignored, so nuScenes
    results files load as they are. A malformed record raises ``FrameError`` naming
    ``source``, the record index and the field.
    """
    cols = record_columns(records, class_names, source=source)
    size = cols["size"]
    boxes = np.empty((len(size), 7))
    boxes[:, :3] = cols["translation"]
    boxes[:, 3] = size[:, 1]
    boxes[:, 4] = size[:, 0]
    boxes[:, 5] = size[:, 2]
    boxes[:, 2] -= boxes[:, 5] / 2
    boxes[:, 6] = cols["yaw"]
    return boxes, cols["score"], cols["label"]
