"""What a training step minimises, per architecture: the official losses of FisheyeBEVDet (and of the BEVDet
baselines, which share its head and differ in the lift) and of FisheyePETR (and of the PETR baselines, which
share its decoder and differ in the keys).

An objective knows its model's outputs and initialisation, nothing of the optimiser or the run
folder, so ``loop.Trainer`` trains every architecture the same way:

    objective = objective_for(model, options)
    terms = objective(batch, device)      # terms["loss"].backward(); every name in objective.terms
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import torch
from torch import nn

from ..fisheye_bevdet import FisheyeBEVDet
from ..fisheye_petr import FisheyePETR
from ..view_transform import FisheyeLSS
from .batches import Batch, collate
from .depth import DepthTargets, depth_loss
from .lens_jitter import StepLenses
from .losses import TransFusionLoss
from .options import TrainOptions
from .petr_loss import PETRLoss
from .targets import HeadGrid

__all__ = ["Objective", "BEVDetObjective", "PETRObjective", "objective_for", "HEATMAP_PRIOR", "CLASS_PRIOR"]

#: Initial bias of both TransFusion heatmap classifiers (the official init: sigmoid(-2.19) = 0.1).
HEATMAP_PRIOR = -2.19
#: Initial bias of PETR's class branch (mmdet's ``bias_init_with_prob(0.01)``, as the official head).
CLASS_PRIOR = float(-np.log((1 - 0.01) / 0.01))


class Objective(Protocol):
    """The losses of one architecture: the terms it logs, the frames' depth targets it needs (if any) and the
    BEV square whose objects are labelled (x0, y0, x1, y1)."""

    terms: tuple[str, ...]
    depth_targets: DepthTargets | None
    bev_range: tuple[float, float, float, float]

    def init(self, seed: int) -> None:
        """Seeded initial weights with the official head priors."""

    def __call__(self, batch: Batch, device: torch.device) -> dict[str, torch.Tensor]:
        """One forward over a step's frames -> ``loss`` and every name of ``terms``."""

    def settle(self) -> None:
        """Bring what the model caches for inference up to date with its trained weights."""


def _seeded(model: nn.Module, seed: int) -> None:
    from fisheye_infer.models.seeded_checkpoint import init_weights

    init_weights(model, seed)


def _tensors(tables: dict[str, np.ndarray], device: torch.device) -> dict[str, torch.Tensor]:
    return {name: torch.from_numpy(table).to(device) for name, table in tables.items()}


def _images(batch: Batch, device: torch.device) -> tuple[torch.Tensor, list[np.ndarray], list[np.ndarray]]:
    images, boxes, labels = collate(batch.samples)
    return torch.from_numpy(images).to(device), boxes, labels


class _DepthProbe:
    """Keeps the depth head's latest output (a forward hook), so the depth loss reads what the forward computed."""

    def __init__(self, view_transform: FisheyeLSS) -> None:
        self.num_depth = view_transform.num_depth
        self.logits: torch.Tensor | None = None
        view_transform.depthnet.register_forward_hook(self._keep)

    def _keep(self, module: nn.Module, inputs: Any, output: torch.Tensor) -> None:
        self.logits = output

    def probs(self) -> torch.Tensor:
        """M x D x H x W softmax depth of the last forward."""
        if self.logits is None:
            raise RuntimeError("the depth probe has seen no forward pass yet")
        return torch.softmax(self.logits[:, : self.num_depth], dim=1)


class BEVDetObjective:
    """TransFusion's heatmap, classification and box losses (``losses.py``), plus the weighted depth loss against
    the targets of the model's own lift (fisheye, pinhole, perspective or cylindrical)."""

    terms: tuple[str, ...] = ("loss", "loss_heatmap", "loss_cls", "loss_bbox", "loss_depth", "matched_iou")

    def __init__(self, model: FisheyeBEVDet, depth_weight: float) -> None:
        self.model, self.depth_weight = model, depth_weight
        grid = HeadGrid.from_head(model.config.head)
        self.loss = TransFusionLoss(model.bbox_head, grid)
        (x0, y0), (dx, dy) = grid.pc_range, grid.span
        self.bev_range = (x0, y0, x0 + dx, y0 + dy)
        self.depth_targets: DepthTargets | None = DepthTargets(model.view_transform.geometry)
        self.depth_probe = _DepthProbe(model.view_transform)

    def init(self, seed: int) -> None:
        _seeded(self.model, seed)
        head = self.model.bbox_head
        with torch.no_grad():
            for branch in (head.heatmap_head, *(pred.get_submodule("heatmap") for pred in head.prediction_heads)):
                _last_bias(branch).fill_(HEATMAP_PRIOR)

    def __call__(self, batch: Batch, device: torch.device) -> dict[str, torch.Tensor]:
        images, boxes, labels = _images(batch, device)
        tables = None if batch.lenses is None else _tensors(batch.lenses.tables, device)
        terms = self.loss(self.model.forward_raw(images, tables=tables), boxes, labels)
        assert batch.depth is not None  # this objective's batches carry depth targets
        terms["loss_depth"] = depth_loss(self.depth_probe.probs(), torch.from_numpy(batch.depth).to(device))
        if self.depth_weight:
            terms["loss"] = terms["loss"] + self.depth_weight * terms["loss_depth"]
        return terms

    def settle(self) -> None:
        """Nothing to do: FisheyeBEVDet caches no weight-derived tables."""


class PETRObjective:
    """PETR's focal classification and L1 box losses on every decoder layer (``petr_loss.py``)."""

    terms: tuple[str, ...] = PETRLoss.terms

    def __init__(self, model: FisheyePETR) -> None:
        self.model = model
        self.loss = PETRLoss(model.pts_bbox_head)
        self.depth_targets: DepthTargets | None = None
        pc = model.config.head.point_cloud_range
        self.bev_range = (pc[0], pc[1], pc[3], pc[4])

    def init(self, seed: int) -> None:
        """The image trunk as FisheyeBEVDet's (seeded fan-in weights); the head as the official one: PyTorch's
        default initialisation of its layers (made under the run's seed), Xavier-uniform weights in the
        transformer, reference points uniform in [0, 1] and the class prior.

        The head's scale matters: with fan-in weights the keys and the image features come out several times
        larger, the cross-attention softmax saturates and every query ends up with the same output."""
        _seeded(self.model.img_backbone, seed)
        _seeded(self.model.img_neck, seed)
        head = self.model.pts_bbox_head
        gen = torch.Generator().manual_seed(int(seed))
        with torch.no_grad():
            for param in head.transformer.parameters():
                if param.dim() > 1:
                    nn.init.xavier_uniform_(param, generator=gen)
            head.reference_points.weight.copy_(torch.rand(head.reference_points.weight.shape, generator=gen))
            _last_bias(head.cls_branches[0]).fill_(CLASS_PRIOR)
        head.refresh_embeddings()

    def __call__(self, batch: Batch, device: torch.device) -> dict[str, torch.Tensor]:
        images, boxes, labels = _images(batch, device)
        head = self.model.pts_bbox_head
        feats = self.model.image_features(images)
        tables, positions = self.step_tables(batch.lenses, device)
        outs = head.forward_decoder(feats, return_intermediate=True, tables=tables, positions=positions)
        cls, codes = head.predict(outs)  # L x B x Q x K, L x B x Q x 8
        return self.loss(cls, codes, boxes, labels)

    def step_tables(
        self, lenses: StepLenses | None, device: torch.device
    ) -> tuple[dict[str, torch.Tensor] | None, tuple[torch.Tensor, torch.Tensor]]:
        """A step's decoder tables (None: the installed ones) and trainable (key, query) embeddings; with a step's
        moved ``lenses``, their warp taps, their key mask and that mask's key embedding."""
        head = self.model.pts_bbox_head
        if lenses is None:
            return None, head.trainable_positions()
        return {**head.tables(), **_tensors(lenses.tables, device)}, head.trainable_positions(~lenses.inside_lens)

    def settle(self) -> None:
        """The key and query embeddings and the first self-attention the inference path caches, from the trained
        weights."""
        self.model.pts_bbox_head.refresh_embeddings()


def objective_for(model: nn.Module, options: TrainOptions) -> Objective:
    """The objective of ``model``'s architecture."""
    if isinstance(model, FisheyeBEVDet):
        return BEVDetObjective(model, options.depth_weight)
    if isinstance(model, FisheyePETR):
        return PETRObjective(model)
    raise TypeError(f"no training objective for {type(model).__name__}")


def _last_bias(branch: nn.Module) -> torch.Tensor:
    """The bias of a classifier branch's last layer: where the prior goes."""
    last = list(branch.children())[-1]
    if not isinstance(last, (nn.Conv1d, nn.Conv2d, nn.Linear)) or last.bias is None:
        raise TypeError(f"a classifier branch ends in {type(last).__name__}, not a layer with a bias")
    return last.bias
