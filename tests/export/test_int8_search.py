"""The int8 search: ``--int8`` alone keeps float32 the modules whose int8 error costs the boxes, until the file
passes its comparison with the fp32 file, and refuses with the table of its trials when nothing passes."""

from __future__ import annotations

from pathlib import Path

import onnx
import pytest

pytest.importorskip("torch")

from fisheye_infer.export.exporter import export, export_int8
from fisheye_infer.export.int8_scope import int8_layer_modules
from fisheye_infer.export.int8_search import MAX_CANDIDATES, candidate_modules
from fisheye_infer.export.options import Comparison, Int8Options
from fisheye_infer.export.quantize import architecture_float
from fisheye_infer.precision import under_module
from fisheye_infer.runtime.artifact import read_meta

#: The channel of ``pts_backbone.blocks.0``'s inner activation made wide, and by how much.
WIDE_CHANNEL, WIDE_FACTOR = 0, 1000.0
#: The layer that reads it: in int8 its input's one scale must cover that channel, and the others round to 0.
SENSITIVE_LAYER = "pts_backbone.blocks.0.3"
#: A gate between the two regimes of the reduced FisheyeBEVDet (seeded weights keep near-tied scores, so
#: even its undamaged int8 file keeps well under 95%): its int8 file keeps about 40% of the fp32 top-50,
#: with the wide channel quantized about 8%, with it float32 again about 35%.
GATE = 0.25


@pytest.fixture(scope="module")
def sensitive_export(small_export, small_bevdet_config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The reduced FisheyeBEVDet with one channel of ``pts_backbone.blocks.0``'s inner activation scaled up
    ``WIDE_FACTOR`` times (its BatchNorm's scale and shift) and the next convolution's weights for that channel
    scaled down as much: the same function in float32, one module that int8 cannot represent."""
    import torch

    folder = tmp_path_factory.mktemp("sensitive")
    checkpoint = torch.load(small_export.ckpt, weights_only=False)
    state = checkpoint["state_dict"]
    for field in ("weight", "bias"):
        state[f"pts_backbone.blocks.0.1.{field}"][WIDE_CHANNEL] *= WIDE_FACTOR
    state[f"{SENSITIVE_LAYER}.weight"][:, WIDE_CHANNEL] /= WIDE_FACTOR
    torch.save(checkpoint, folder / "sensitive.pth")
    result = export(
        folder / "sensitive.pth",
        folder / "sensitive.onnx",
        config=small_bevdet_config,
        rig=read_meta(small_export.onnx).rig,
        frames=1,
        progress=lambda _: None,
    )
    assert result.path is not None
    return result.path


def _search(path: Path, out: Path, min_kept: float):
    return export_int8(
        path,
        out,
        options=Int8Options(calib_frames=2),
        comparison=Comparison(frames=4, min_kept=min_kept),
        progress=lambda _: None,
    )


def test_candidates_split_the_largest_module_first_within_the_limit() -> None:
    layers = [
        "img_backbone.conv1",
        *(f"img_backbone.layer1.{b}.conv{c}" for b in range(2) for c in (1, 2)),
        *(f"img_backbone.layer2.{b}.conv{c}" for b in range(2) for c in (1, 2)),
        "img_neck.lateral_convs.0.conv",
        "img_neck.fpn_convs.0.conv",
        "view_transform.depthnet",
        "bbox_head.shared_conv",
    ]
    assert candidate_modules(layers, limit=4) == ["img_backbone", "img_neck", "view_transform", "bbox_head"]
    assert candidate_modules(layers, limit=6) == [
        "img_backbone.conv1",
        "img_backbone.layer1",
        "img_backbone.layer2",
        "img_neck",
        "view_transform",
        "bbox_head",
    ]
    # then the largest of equals first in graph order: layer1 into its two blocks
    assert candidate_modules(layers, limit=7)[1:3] == ["img_backbone.layer1.0", "img_backbone.layer1.1"]
    alone = candidate_modules(layers, limit=100)  # with room enough, every layer alone, in graph order
    assert len(alone) == len(layers) and all(under_module(m, g) for m, g in zip(layers, alone, strict=True))


def test_candidates_keep_graph_order_and_leave_out_layers_of_no_module() -> None:
    assert candidate_modules(["b.x", "", "a.y", "b.z"], limit=1) == ["b", "a"]  # never fewer than the top level
    assert candidate_modules(["b.x", "", "a.y", "b.z"], limit=2) == ["b", "a"]
    assert candidate_modules(["m.only.deep.layer", "m.only.deep.other"], limit=5) == [
        "m.only.deep.layer",
        "m.only.deep.other",
    ]


def test_a_file_that_passes_at_the_start_keeps_the_architectures_float_modules(small_export, tmp_path: Path) -> None:
    result = _search(small_export.onnx, tmp_path / "m.int8.onnx", GATE)
    search = read_meta(result.path).quantization.search
    assert result.path is not None and search is not None and search.chosen == 0 and len(search.trials) == 1
    assert result.meta.quantization.float_modules == architecture_float(small_export.onnx)
    assert "the int8 search" in result.meta.quantization.scope and "trial 1 of 1" in result.summary()


def test_the_search_keeps_exactly_the_sensitive_module_float_and_passes(sensitive_export: Path, tmp_path: Path) -> None:
    start = architecture_float(sensitive_export)
    candidates = candidate_modules(int8_layer_modules(onnx.load(str(sensitive_export)), "network", start))
    assert len(candidates) <= MAX_CANDIDATES
    sensitive = next(c for c in candidates if under_module(SENSITIVE_LAYER, c))

    result = _search(sensitive_export, tmp_path / "m.int8.onnx", GATE)

    assert result.path is not None and result.parity.passed
    meta = read_meta(result.path)
    search = meta.quantization.search
    assert search is not None and search.chosen is not None
    assert not search.trials[0].passed  # the start: every module but the architecture's float ones in int8
    assert [t.float_modules[len(start) :] for t in search.trials if t.step == "sensitivity"] == [
        (c,) for c in candidates
    ]
    chosen = search.trials[search.chosen]
    assert chosen.float_modules == (*start, sensitive) and meta.quantization.float_modules == chosen.float_modules
    assert [t.float_modules for t in search.trials if t.step == "sensitivity" and t.passed] == [(*start, sensitive)]
    assert meta.parity.top_matched_fraction == chosen.top_matched_fraction >= GATE
    assert search.speedup is not None and search.speedup > 0 and search.cpu
    layers = int8_layer_modules(onnx.load(str(sensitive_export)), "network", chosen.float_modules)
    assert layers and not any(under_module(m, sensitive) for m in layers)  # the written file's int8 layers
    assert f"start + {sensitive}" in result.summary()


@pytest.mark.slow  # every trial of the search: make test-fast leaves it out
def test_a_gate_that_cannot_be_met_is_refused_with_the_table_of_trials(sensitive_export: Path, tmp_path: Path) -> None:
    """``--int8 --min-kept 1``: every trial in the summary, the trunk scope last; no int8 file, the fp32 file as it
    was (``export`` refusing with that summary and keeping its fp32 file: ``test_quantize``)."""
    out = tmp_path / "m.int8.onnx"
    before = sensitive_export.read_bytes()
    refused = _search(sensitive_export, out, min_kept=1.0)
    assert not refused.parity.passed and refused.path is None
    message = refused.summary()
    rows = [line.split() for line in message.splitlines() if line[:7].strip().isdigit()]
    assert "int8 search: no trial passed" in message and "need 100%" in message
    assert [r[1] for r in rows][0] == "start" and rows[-1][1] == "trunk" and rows[-1][2] == "trunk"
    assert sum(r[1] == "sensitivity" for r in rows) >= 2 and [int(r[0]) for r in rows] == list(range(1, len(rows) + 1))
    assert not out.exists() and sensitive_export.read_bytes() == before
