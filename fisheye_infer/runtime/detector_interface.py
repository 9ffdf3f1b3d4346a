"""What a detector's graph must be, and what a caller is told about it (``DetectorInfo``).

``check_interface`` and ``check_output_shapes`` refuse a graph (local or served) whose inputs, outputs
or static shapes are not the fisheye-infer interface its metadata describes; ``describe`` turns the
metadata into the ``DetectorInfo`` that ``Detector.info`` and ``TritonDetector.info`` hold.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, ArtifactMeta

__all__ = ["DetectorInfo", "check_interface", "check_output_shapes", "describe"]


@dataclass(frozen=True)
class DetectorInfo:
    """What a caller needs to feed the model and read its output (``Detector.info``).

    Attributes:
        architecture (str): The model's architecture (``fisheye_bevdet``, ``fisheye_petr``).
        model_id (str): Architecture, rig hash and checkpoint digest: names this file's behaviour.
        classes (tuple[str, ...]): Class names, in label order.
        cameras (tuple[str, ...]): Camera names, in the order the model takes them.
        image_size (tuple[int, int]): (width, height) of the images input, pixels (the largest camera's
            behind virtual cameras).
        camera_sizes (tuple[tuple[int, int], ...]): (width, height) of each camera's images, in camera order.
        colour_order (str): ``"BGR"`` or ``"RGB"``: the channel order decoded arrays must have.
        num_boxes (int): Boxes the graph returns per frame, before the validity mask.
        rig (Rig): The camera rig baked into the file.
        providers (tuple[str, ...]): The ONNX Runtime execution providers the session got, in priority order.
        meta (ArtifactMeta): The file's full metadata
            ([`ArtifactMeta`][fisheye_infer.runtime.artifact.ArtifactMeta]).
    """

    architecture: str
    model_id: str
    classes: tuple[str, ...]
    cameras: tuple[str, ...]
    image_size: tuple[int, int]  # (width, height) of the images input (the largest camera's behind virtual cameras)
    camera_sizes: tuple[tuple[int, int], ...]  # (width, height) of each camera's images, in camera order
    colour_order: str
    num_boxes: int
    rig: Rig
    providers: tuple[str, ...]
    meta: ArtifactMeta


def check_interface(
    inputs: Mapping[str, Sequence[object]], outputs: Sequence[str], meta: ArtifactMeta, source: str
) -> None:
    """Refuse a graph (local or served) whose inputs and outputs are not the fisheye-infer interface.

    ``inputs`` maps input name -> shape with the batch axis first; the images input must be
    ``(B, N, H, W, 3)`` for the metadata's cameras and image size.
    """
    if set(inputs) != {INPUT_IMAGES, INPUT_CAMERA_VALID} or list(outputs) != list(OUTPUTS):
        raise ArtifactError(
            f"{source}: graph inputs {sorted(inputs)} / outputs {list(outputs)} are not the fisheye-infer interface"
        )
    shape = list(inputs[INPUT_IMAGES])
    width, height = meta.image_size
    if shape[1:] != [len(meta.cameras), height, width, 3]:
        raise ArtifactError(
            f"{source}: images input is {shape}, metadata says (B, {len(meta.cameras)}, {height}, {width}, 3)"
        )


def check_output_shapes(outputs: Mapping[str, Sequence[object]], meta: ArtifactMeta, source: str) -> None:
    """Refuse metadata that its graph's static output shapes (batch axis first) contradict."""
    for name, shape in outputs.items():
        boxes = shape[1] if len(shape) > 1 else None
        if isinstance(boxes, int) and boxes > 0 and boxes != meta.num_boxes:
            raise ArtifactError(
                f"{source}: num_boxes: metadata says {meta.num_boxes}, the graph's '{name}' output has {boxes}"
            )
        if (
            name == "boxes"
            and shape
            and isinstance(shape[-1], int)
            and shape[-1] > 0
            and shape[-1] != len(meta.box_layout)
        ):
            raise ArtifactError(
                f"{source}: box_layout: metadata names {len(meta.box_layout)} values per box, "
                f"the graph's 'boxes' output has {shape[-1]}"
            )


def describe(meta: ArtifactMeta, providers: Sequence[str]) -> DetectorInfo:
    return DetectorInfo(
        architecture=meta.architecture,
        model_id=meta.model_id,
        classes=meta.classes,
        cameras=meta.cameras,
        image_size=meta.image_size,
        camera_sizes=meta.camera_sizes(),
        colour_order=meta.colour_order,
        num_boxes=meta.num_boxes,
        rig=meta.rig,
        providers=tuple(providers),
        meta=meta,
    )
