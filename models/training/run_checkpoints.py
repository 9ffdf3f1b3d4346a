"""A run's checkpoints: written whole or not at all, the options they record, and what another checkpoint must
be to start or continue a run.

``Trainer`` writes ``checkpoint.pth`` (weights, optimiser and int8 simulation state, metadata) and ``model.pth``
(official format) with `atomic_save`; ``--resume`` reads the options back (`saved_options`,
`recorded_options`) and refuses a checkpoint of another configuration or rig (`check_origin`);
``--init`` takes a checkpoint of fewer queries too (`grown_queries`); ``--init-backbone`` takes the image
backbone and neck of any architecture with the same backbone section (`backbone_state`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import CheckpointError
from fisheye_infer.tools.files import pending_file

from .options import TrainOptions

__all__ = [
    "BACKBONE_PREFIXES",
    "QUERY_TABLE",
    "atomic_save",
    "backbone_state",
    "check_origin",
    "grown_queries",
    "recorded_options",
    "saved_options",
]

#: What ``init_backbone`` loads: the image backbone and its neck, the same modules in every architecture.
BACKBONE_PREFIXES = ("img_backbone.", "img_neck.")
#: A query-based head's learned reference points, one row per query: what ``--init`` may grow.
QUERY_TABLE = "pts_bbox_head.reference_points.weight"


def saved_options(folder: Path) -> dict[str, Any]:
    """The options the run in ``folder`` was started with (its ``checkpoint.pth``), so that ``--resume``
    need repeat none of them.

    Args:
        folder (Path): the run folder.

    Returns:
        dict[str, Any]: ``TrainOptions`` field values by name; ``{}`` when the folder has no checkpoint yet.
    """
    path = folder / "checkpoint.pth"
    if not path.is_file():
        return {}
    # memory-mapped: only the metadata is read here; ``Trainer.resume`` loads the weights
    return recorded_options(torch.load(path, map_location="cpu", weights_only=True, mmap=True).get("meta", {}))


def recorded_options(meta: dict[str, Any]) -> dict[str, Any]:
    """The ``TrainOptions`` a checkpoint's ``meta`` records.

    Args:
        meta (dict[str, Any]): the checkpoint's metadata.

    Returns:
        dict[str, Any]: ``TrainOptions`` field values by name, with the defaults of the fields added after a
        run was made.
    """
    # runs made before fine-tuning, int8 simulation, backbone initialisation and lens jitter existed lack those fields
    saved = {
        "init": "",
        "qat": 0.0,
        "init_backbone": "",
        "freeze_backbone": False,
        "lens_jitter": 0.0,
        **meta.get("train_options", {}),
    }
    return {field.name: saved[field.name] for field in dataclasses.fields(TrainOptions) if field.name in saved}


def atomic_save(obj: Any, path: Path) -> None:
    """Write ``obj`` with ``torch.save``: the file appears whole or not at all, so a run killed mid-save
    leaves the previous one.

    Args:
        obj (Any): what to save.
        path (Path): where.
    """
    with pending_file(path) as pending:
        torch.save(obj, pending.path)
        pending.commit()


def check_origin(meta: dict[str, Any], config: Any, rig: Rig, what: str, recorded: bool) -> None:
    """Refuse a checkpoint whose ``meta`` names another configuration or rig than a run's.

    Args:
        meta (dict[str, Any]): the checkpoint's metadata.
        config (Any): the run's model configuration.
        rig (Rig): the run's rig.
        what (str): how the messages name the checkpoint.
        recorded (bool): both must be in ``meta``, as in the training loop's own checkpoints.

    Raises:
        CheckpointError: the checkpoint was trained with another configuration or for another rig.
    """
    mine = config.to_dict()
    if (recorded or "config" in meta) and meta.get("config") != mine:
        theirs = meta.get("config") or {}
        sections = sorted(k for k in {*mine, *theirs} if mine.get(k) != theirs.get(k))
        raise CheckpointError(
            f"{what} was trained with another model configuration (differs in: {', '.join(sections)})"
        )
    if (recorded or "rig_hash" in meta) and meta.get("rig_hash") != rig.hash:
        raise CheckpointError(
            f"{what} was trained for rig {meta.get('rig')!r} ({meta.get('rig_hash')}), not {rig.name!r} ({rig.hash})"
        )


def grown_queries(
    model: torch.nn.Module, config: Any, state_dict: dict[str, torch.Tensor], meta: dict[str, Any]
) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
    """A checkpoint of ``config`` but for fewer queries (``num_query``) as one of ``config``.

    Its reference points are the first of ``model``'s, the others keep their seeded ones, so a trained decoder
    takes more queries without starting over.

    Args:
        model (torch.nn.Module): the run's model, of ``config``.
        config (Any): the run's model configuration.
        state_dict (dict[str, torch.Tensor]): the checkpoint's weights.
        meta (dict[str, Any]): the checkpoint's metadata.

    Returns:
        tuple[dict[str, torch.Tensor], dict[str, Any]]: the grown weights and metadata; any other checkpoint as
        it is, for `check_origin` to judge.
    """
    mine, theirs = config.to_dict(), meta.get("config")
    wanted = mine.get("head", {}).get("num_query")
    if wanted is None or not isinstance(theirs, dict) or not isinstance(theirs.get("head"), dict):
        return state_dict, meta
    have = theirs["head"].get("num_query")
    grown = {**theirs, "head": {**theirs["head"], "num_query": wanted}}
    if not isinstance(have, int) or have >= wanted or grown != mine:
        return state_dict, meta
    table = model.state_dict()[QUERY_TABLE].clone()
    table[:have] = state_dict[QUERY_TABLE]
    return {**state_dict, QUERY_TABLE: table}, {**meta, "config": mine}


def backbone_state(model: torch.nn.Module, state_dict: dict[str, torch.Tensor], path: Path) -> dict[str, torch.Tensor]:
    """The image backbone and neck weights (``BACKBONE_PREFIXES``) of a checkpoint, checked against ``model``'s.

    Args:
        model (torch.nn.Module): the model they are for.
        state_dict (dict[str, torch.Tensor]): the checkpoint's weights, of any architecture.
        path (Path): the checkpoint, for the messages.

    Returns:
        dict[str, torch.Tensor]: the backbone and neck weights, for ``load_state_dict(..., strict=False)``.

    Raises:
        CheckpointError: a backbone key is missing or of another shape.
    """
    mine = {k: v for k, v in model.state_dict().items() if k.startswith(BACKBONE_PREFIXES)}
    theirs = {k: v for k, v in state_dict.items() if k.startswith(BACKBONE_PREFIXES)}
    missing = sorted(set(mine) - set(theirs))
    if missing:
        raise CheckpointError(f"--init-backbone: {path} has no {missing[0]} ({len(missing)} backbone keys missing)")
    for k, v in mine.items():
        if tuple(theirs[k].shape) != tuple(v.shape):
            theirs_shape, mine_shape = tuple(theirs[k].shape), tuple(v.shape)
            raise CheckpointError(
                f"--init-backbone: {path}: {k} is {theirs_shape}, this configuration's is {mine_shape}"
            )
    return theirs
