"""FisheyePETR's decoder at inference: the first layer's self-attention reads only weights, so the model keeps it
and an exported graph holds it as a constant."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import onnx
import pytest
from small_configs import small_configs

torch = pytest.importorskip("torch")

from fisheye_infer.models.petr_transformer import QUERY_CHUNK, PETRTransformer, key_padding_bias  # noqa: E402


def _transformer() -> PETRTransformer:
    torch.manual_seed(3)
    transformer = PETRTransformer(num_layers=2, embed_dims=32, num_heads=4, ffn_dims=64)
    with torch.no_grad():
        for p in transformer.parameters():
            p.add_(0.1 * torch.randn_like(p))  # biases away from zero: the zero targets' attention is not zero
    return transformer


@pytest.mark.parametrize("mode", ["inference, cached", "inference", "training"])
def test_every_frame_gets_the_decoder_of_zero_targets(mode: str) -> None:
    """A batch of 3: each frame's output is that of the decoder run from B x Q x C zero targets."""
    transformer = _transformer().train(mode == "training")
    memory, query_pos, key_pos = torch.randn(3, 11, 32), torch.randn(7, 32), torch.randn(1, 11, 32)
    bias = key_padding_bias(torch.rand(3, 11) < 0.3)
    cached = mode == "inference, cached"
    if cached:
        transformer.cache_first_self_attention(query_pos)
        assert transformer.first_self_attention.shape == (1, 7, 32)
    with torch.no_grad():
        got = transformer(memory, query_pos, key_pos, bias, return_intermediate=True, cached=cached)
        zeros = torch.zeros(3, 7, 32)
        want = transformer.decoder(zeros, memory, query_pos[None], key_pos, bias, return_intermediate=True)
    assert got.shape == (2, 3, 7, 32)
    torch.testing.assert_close(got, want, rtol=1e-6, atol=1e-6)


def test_the_exported_graph_holds_the_first_self_attention(small_exports: Callable[[str], Any]) -> None:
    """The reduced FisheyePETR (2 layers, 40 queries): one self-attention's softmaxes fewer than 2 per layer, and
    the (1, Q, C) constant in their place."""
    head = small_configs()["fisheye-petr"][0].head
    model = onnx.load(small_exports("fisheye-petr").onnx)
    chunks = math.ceil(head.num_query / QUERY_CHUNK)
    assert sum(node.op_type == "Softmax" for node in model.graph.node) == (2 * head.num_layers - 1) * chunks
    shapes = {i.name: tuple(i.dims) for i in model.graph.initializer}
    assert shapes["model.pts_bbox_head.transformer.first_self_attention"] == (1, head.num_query, head.embed_dims)
