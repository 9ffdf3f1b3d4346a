"""Trace a detector to ONNX with its geometry tables as named, size-agnostic initializers.

The model is traced with ``torch.onnx.export(dynamo=True)`` and every ``geom.*`` table passed as
a graph input. The batch axis is symbolic, and so is the row count K_b of every pooling bucket:
the resulting graph contains no constant derived from a table's size, which is what lets
``rebake`` give the same graph any rig's tables. Afterwards the table inputs become named
initializers, and the normalisation's per-channel division is folded into the first
convolution's weights (``graph.fold_input_scale``; exact in real arithmetic, and the written file
is checked against PyTorch like the rest). The tracer sees example buckets of at least two rows
(a bucket may hold one row for a given rig, and torch.export specialises sizes 0 and 1): the extra
rows repeat the bucket's last row, and no cell reads them.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from collections.abc import Iterator, Mapping
from typing import Any

import numpy as np
import onnx
import torch
from torch import nn
from torch.export import Dim

from fisheye_infer.errors import ExportError
from fisheye_infer.geometry.tables import POOL_PIXELS, POOL_POINTS
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, RANKING_OUTPUTS

from .graph import check_standard_ops, fold_input_scale, inputs_to_initializers, rename_values, strip_shape_info

__all__ = ["OPSET", "TRACE_ROOT", "trace_to_onnx"]

OPSET = 18

#: The attribute the traced wrapper holds the detector under: every weight's initializer name and
#: every node's recorded module path (``pkg.torch.onnx.name_scopes``) starts with it.
TRACE_ROOT = "model"
_BUCKET_PREFIXES = (POOL_POINTS, POOL_PIXELS)


class _Graph(nn.Module):
    """The traced interface: (images, camera_valid, *tables) -> boxes, scores, labels, valid, and the
    ranking step's rank_scores, rank_indices (which the export check reads and the written file drops)."""

    def __init__(self, model: nn.Module, names: list[str]) -> None:
        super().__init__()
        setattr(self, TRACE_ROOT, model)
        self.names = names

    def forward(
        self, images: torch.Tensor, camera_valid: torch.Tensor, tables: tuple[torch.Tensor, ...]
    ) -> tuple[torch.Tensor, ...]:
        out = getattr(self, TRACE_ROOT)(images, camera_valid, tables=dict(zip(self.names, tables)))
        return tuple(out[k] for k in OUTPUTS + RANKING_OUTPUTS)


def _example_tables(tables: Mapping[str, np.ndarray]) -> dict[str, torch.Tensor]:
    examples = {}
    for name, value in tables.items():
        t = torch.from_numpy(np.ascontiguousarray(value))
        if name.startswith(_BUCKET_PREFIXES) and t.shape[0] < 2:
            extra = t[-1:].expand(2, -1) if t.shape[0] else torch.zeros((2, t.shape[1]), dtype=t.dtype)
            t = torch.cat([t, extra])
        examples[name] = t
    return examples


def _dynamic_shapes(names: list[str]) -> dict[str, Any]:
    batch = Dim("batch", min=1, max=1024)
    bucket_dims: dict[str, Dim] = {}
    table_shapes = []
    for name in names:
        if name.startswith(_BUCKET_PREFIXES):
            index = name.rsplit(".", 1)[1]
            bucket_dims.setdefault(index, Dim(f"cells_{index}", min=0, max=1 << 24))
            table_shapes.append({0: bucket_dims[index]})
        else:
            table_shapes.append({})  # static
    return {"images": {0: batch}, "camera_valid": {0: batch}, "tables": tuple(table_shapes)}


def trace_to_onnx(
    model: nn.Module, tables: Mapping[str, np.ndarray], image_hw: tuple[int, int], num_cameras: int
) -> onnx.ModelProto:
    """ONNX model of ``model`` with ``tables`` as initializers named ``geom.*``; its outputs are
    ``OUTPUTS`` then ``RANKING_OUTPUTS`` (``graph.without_outputs`` makes the file to write)."""
    names = list(tables)
    examples = _example_tables(tables)
    h, w = image_hw
    images = torch.zeros((2, num_cameras, h, w, 3), dtype=torch.uint8)
    valid = torch.ones((2, num_cameras), dtype=torch.bool)
    graph = _Graph(model.eval(), names)
    log = io.StringIO()
    try:
        with warnings.catch_warnings(), contextlib.redirect_stdout(log), _quiet_loggers():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(
                graph,
                (images, valid, tuple(examples[n] for n in names)),
                dynamo=True,
                opset_version=OPSET,
                external_data=False,
                dynamic_shapes=_dynamic_shapes(names),
                verbose=False,
            )
    except Exception as exc:
        raise ExportError(f"tracing {type(model).__name__} to ONNX failed: {exc}\n{log.getvalue()[-2000:]}") from exc
    if program is None:  # only an export to a file returns nothing
        raise ExportError(f"tracing {type(model).__name__} to ONNX returned no program")
    proto = program.model_proto
    traced_inputs = [i.name for i in proto.graph.input]
    if len(traced_inputs) != 2 + len(names):
        raise ExportError(
            f"the traced graph has inputs {traced_inputs}; expected images, camera_valid and {len(names)} tables"
        )
    rename_values(proto, dict(zip(traced_inputs, [INPUT_IMAGES, INPUT_CAMERA_VALID, *names])))
    rename_values(proto, dict(zip([o.name for o in proto.graph.output], OUTPUTS + RANKING_OUTPUTS)))
    inputs_to_initializers(proto, tables)
    fold_input_scale(proto)  # the normalisation's division, into the first convolution's weights
    strip_shape_info(proto)
    check_standard_ops(proto, OPSET)
    return proto


@contextlib.contextmanager
def _quiet_loggers() -> Iterator[None]:
    """The exporter logs progress and optimiser notes at WARNING; keep the user's terminal readable."""
    loggers = [
        logging.getLogger(n)
        for n in ("torch.onnx", "torch.export", "torch._dynamo", "onnxscript", "torch.fx.experimental.symbolic_shapes")
    ]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.ERROR)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
