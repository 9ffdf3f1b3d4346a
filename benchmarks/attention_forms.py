"""FisheyePETR's decoder attention in the forms ONNX Runtime can run it: what each costs at the shipped model's shapes.

    python benchmarks/attention_forms.py [--model fisheye-petr-compact] [--quick]

The shapes are the shipped model's (its config: queries, heads, head size, layers; keys of the cross-attention:
cameras x feature cells), for the self-attention (queries to queries) and the cross-attention (queries to the
cameras' features, with the additive key bias that masks the cells outside the lens, 10 % of them here). One
layer's attention of one frame, in each form:

1. ``exported``: as ``models.petr_transformer.MultiheadAttention`` exports it (opset 18): the queries in chunks of
   ``QUERY_CHUNK``, MatMul by the transposed keys (the key bias riding as one more coordinate), Softmax, MatMul by
   the values;
2. ``Attention (opset 23)``: ONNX's attention operator, one node (the same bias coordinate; scale 1, as the queries
   come scaled);
3. ``int8 products``: the exported form with both products in int8, the operands quantized per frame
   (DynamicQuantizeLinear, MatMulInteger, the product of the two scales; the key bias added after the first
   product, as its masking values would take a quantizer's whole range): what an int8 file's attention would run,
   where both operands are activations.

Each form is a session of its own (the runtime's session options) at 1 and 2 threads, timed alone after warm-up
(20 runs, then 100 timed; the sessions one after another: an idle session's threads spin on). The table gives
each form's time against the exported form's, its whole decoder's time (the layers' sum) and its largest
difference from the exported form's output, relative to that output's largest magnitude. Inputs: seeded Gaussian
queries (scaled by 1/sqrt(head size), as the exported graph scales them), keys and values.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import harness
import numpy as np
import onnx
from onnx import TensorProto, helper

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.models.mmconfig import read_mmdet3d_config
from fisheye_infer.models.petr_config import PETRConfig
from fisheye_infer.models.petr_transformer import MASK_BIAS, QUERY_CHUNK
from fisheye_infer.models.pretrained import pretrained
from fisheye_infer.runtime.session import open_session, session_options

#: Opset of the exported files (``export.trace.OPSET``) and of ONNX's attention operator.
EXPORTED_OPSET, ATTENTION_OPSET = 18, 23
#: Share of the cross-attention's keys masked by the key bias.
MASKED = 0.1


@dataclass(frozen=True)
class Shapes:
    """One attention of the decoder: heads, queries, keys, head size, and whether a key bias rides along."""

    name: str
    heads: int
    queries: int
    keys: int
    size: int
    biased: bool

    def feeds(self, seed: int = 0) -> dict[str, np.ndarray]:
        """Seeded queries, keys and values (1, heads, length, size + 1 where biased), float32."""
        rng = np.random.default_rng(seed)
        q = rng.normal(size=(1, self.heads, self.queries, self.size)) / math.sqrt(self.size)
        k = rng.normal(size=(1, self.heads, self.keys, self.size))
        v = rng.normal(size=(1, self.heads, self.keys, self.size))
        if self.biased:
            bias = np.where(rng.uniform(size=self.keys) < MASKED, MASK_BIAS, 0.0)
            q = np.concatenate([q, np.ones((1, self.heads, self.queries, 1))], axis=-1)
            k = np.concatenate([k, np.broadcast_to(bias[None, None, :, None], (1, self.heads, self.keys, 1))], -1)
        return {"q": q.astype(np.float32), "k": k.astype(np.float32), "v": v.astype(np.float32)}


def shapes_of(model: str) -> tuple[list[Shapes], int]:
    """The self- and cross-attention of a shipped FisheyePETR, and its decoder's layers."""
    shipped = pretrained(model)
    config = PETRConfig.from_mmdet3d_dict(read_mmdet3d_config(shipped.config), str(shipped.config))
    h = config.head
    cameras = len(Rig.load(shipped.rig).names)
    size = h.embed_dims // h.num_heads
    cross = cameras * h.feature_size[0] * h.feature_size[1]
    return [
        Shapes("self", h.num_heads, h.num_query, h.num_query, size, biased=False),
        Shapes("cross", h.num_heads, h.num_query, cross, size, biased=True),
    ], h.num_layers


def _exported(
    products: Callable[[str, str, str], list[onnx.NodeProto]], chunks: int, bias_apart: bool = False
) -> list[onnx.NodeProto]:
    """Chunks of queries through (q k^T) -> Softmax -> (p v), each product made by ``products``; ``bias_apart``: the
    key bias coordinate taken out of the first product and added to its result in float."""
    nodes = [
        helper.make_node("Transpose", ["k"], ["kt"], perm=[0, 1, 3, 2]),
        helper.make_node("Split", ["q", "chunks"], [f"q{i}" for i in range(chunks)], axis=2),
    ]
    keys = "kt"
    if bias_apart:
        nodes += [
            helper.make_node("Split", ["kt", "body_and_bias"], ["kt_body", "key_bias"], axis=2),
            helper.make_node("Split", ["q", "body_and_bias"], ["q_body", "q_one"], axis=3),
            helper.make_node("Split", ["q_body", "chunks"], [f"q{i}" for i in range(chunks)], axis=2),
        ]
        del nodes[1]
        keys = "kt_body"
    for i in range(chunks):
        if bias_apart:
            nodes += products(f"q{i}", keys, f"r{i}")
            nodes.append(helper.make_node("Add", [f"r{i}", "key_bias"], [f"s{i}"]))
        else:
            nodes += products(f"q{i}", keys, f"s{i}")
        nodes.append(helper.make_node("Softmax", [f"s{i}"], [f"p{i}"], axis=-1))
        nodes += products(f"p{i}", "v", f"y{i}")
    nodes.append(helper.make_node("Concat", [f"y{i}" for i in range(chunks)], ["y"], axis=2))
    return nodes


def _float_product(a: str, b: str, out: str) -> list[onnx.NodeProto]:
    return [helper.make_node("MatMul", [a, b], [out])]


def _int8_product(a: str, b: str, out: str) -> list[onnx.NodeProto]:
    return [
        helper.make_node("DynamicQuantizeLinear", [a], [f"{out}_qa", f"{out}_sa", f"{out}_za"]),
        helper.make_node("DynamicQuantizeLinear", [b], [f"{out}_qb", f"{out}_sb", f"{out}_zb"]),
        helper.make_node("MatMulInteger", [f"{out}_qa", f"{out}_qb", f"{out}_za", f"{out}_zb"], [f"{out}_i"]),
        helper.make_node("Cast", [f"{out}_i"], [f"{out}_f"], to=TensorProto.FLOAT),
        helper.make_node("Mul", [f"{out}_sa", f"{out}_sb"], [f"{out}_s"]),
        helper.make_node("Mul", [f"{out}_f", f"{out}_s"], [out]),
    ]


def forms(shapes: Shapes) -> dict[str, bytes]:
    """Each form of one attention as a serialized model (inputs q, k, v; output y)."""
    chunks = math.ceil(shapes.queries / QUERY_CHUNK)
    split = [QUERY_CHUNK] * (chunks - 1) + [shapes.queries - QUERY_CHUNK * (chunks - 1)]
    split_init = [helper.make_tensor("chunks", TensorProto.INT64, [chunks], split)]
    graphs = {
        "exported": (_exported(_float_product, chunks), split_init, EXPORTED_OPSET),
        f"Attention (opset {ATTENTION_OPSET})": (
            [helper.make_node("Attention", ["q", "k", "v"], ["y"], scale=1.0)],
            [],
            ATTENTION_OPSET,
        ),
        "int8 products": (
            _exported(_int8_product, chunks, bias_apart=shapes.biased),
            [*split_init, helper.make_tensor("body_and_bias", TensorProto.INT64, [2], [shapes.size, 1])],
            EXPORTED_OPSET,
        ),
    }
    feeds = shapes.feeds()
    inputs = [helper.make_tensor_value_info(n, TensorProto.FLOAT, list(a.shape)) for n, a in feeds.items()]
    output = helper.make_tensor_value_info("y", TensorProto.FLOAT, [1, shapes.heads, shapes.queries, shapes.size])
    out = {}
    for name, (nodes, initializers, opset) in graphs.items():
        graph = helper.make_graph(nodes, shapes.name, inputs, [output], initializer=initializers)
        proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)])
        onnx.checker.check_model(proto, full_check=True)
        out[name] = proto.SerializeToString()
    return out


def main() -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="4 timed runs")
    bench.parser.add_argument("--model", default="fisheye-petr-compact", help="a shipped FisheyePETR")
    args = bench.parse()
    warmup, repeat = (2, 4) if args.quick else (20, 100)
    attentions, layers = shapes_of(args.model)
    rows = []
    for shapes in attentions:
        feeds = shapes.feeds()
        models = forms(shapes)
        for threads in (1, 2):
            outputs, times = {}, {}
            for name, model in models.items():  # one session at a time: idle sessions' threads spin on
                session = open_session(model, session_options(threads), ["CPUExecutionProvider"], name)
                outputs[name] = session.run(None, feeds)[0]
                times[name] = harness.measure(harness.session_call(session, feeds), repeat=repeat, warmup=warmup)
                del session
            reference = outputs["exported"]
            for name, t in times.items():
                rows.append(
                    {
                        "attention": f"{shapes.name}: {shapes.heads} heads, {shapes.queries} x {shapes.keys}",
                        "form": name,
                        "threads": threads,
                        "ms median": t.median,
                        "ms p90": t.p90,
                        "time / exported": t.median / times["exported"].median,
                        f"{layers} layers ms": t.median * layers,
                        "max |diff| / max |exported|": float(
                            np.abs(outputs[name] - reference).max() / np.abs(reference).max()
                        ),
                    }
                )
            print(*rows[-len(times) :], sep="\n", flush=True)
    bench.save(args, {"One layer's attention, one frame": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
