"""``benchmarks/attention_forms.py``: each form of the decoder's attention computes the exported form's attention."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import attention_forms  # noqa: E402

if onnx.defs.onnx_opset_version() < attention_forms.ATTENTION_OPSET:
    pytest.skip(f"onnx {onnx.__version__} has no opset {attention_forms.ATTENTION_OPSET}", allow_module_level=True)


def _softmax(x: np.ndarray) -> np.ndarray:
    e = np.exp(x - x.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


@pytest.mark.parametrize("biased", [False, True])
def test_every_form_is_the_attention_of_its_inputs(biased: bool) -> None:
    """Against numpy's softmax(q k^T) v on queries in chunks of 100 (250 queries: a short last chunk), the key bias
    masking its keys exactly; float forms to float32 rounding, the int8 products within 10 % of the largest value."""
    shapes = attention_forms.Shapes("test", heads=2, queries=250, keys=300, size=8, biased=biased)
    feeds = shapes.feeds(seed=1)
    q, k, v = (feeds[n].astype(np.float64) for n in ("q", "k", "v"))
    expected = _softmax(q @ k.transpose(0, 1, 3, 2)) @ v
    if biased:
        masked = feeds["k"][0, 0, :, -1] < 0
        assert 0 < masked.sum() < shapes.keys
        unmasked = _softmax(q[..., :-1] @ k[..., :-1].transpose(0, 1, 3, 2) - 1e30 * masked) @ v
        np.testing.assert_allclose(expected, unmasked, atol=1e-12)
    for name, model in attention_forms.forms(shapes).items():
        got = ort.InferenceSession(model, providers=["CPUExecutionProvider"]).run(None, feeds)[0]
        assert got.shape == (1, 2, 250, 8), name
        within = 0.1 * np.abs(expected).max() if name == "int8 products" else 1e-5
        np.testing.assert_allclose(got, expected, atol=within, err_msg=name)


def test_the_shapes_are_the_shipped_models() -> None:
    attentions, layers = attention_forms.shapes_of("fisheye-petr-compact")
    assert layers == 6
    assert [(a.name, a.heads, a.queries, a.keys, a.size, a.biased) for a in attentions] == [
        ("self", 4, 900, 900, 32, False),
        ("cross", 4, 900, 4 * 10 * 40, 32, True),
    ]
