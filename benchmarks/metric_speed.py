"""How long the evaluation metric takes on a full-size evaluation, with synthetic boxes (no model, no images).

    python benchmarks/metric_speed.py [--frames 10000 --gt 20 --pred 200] [--rounds 3] [--quick]

Three steps timed in turns: the metric on arrays, the conversion of in-memory records to arrays,
and the whole path from records. The boxes come from ``fisheye_infer.eval.random_boxes``.
"""

from __future__ import annotations

import sys

import harness

from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import evaluate
from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.eval.random_boxes import synthetic_boxes, to_results


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="1,000 frames")
    bench.parser.add_argument("--frames", type=int, default=10_000)
    bench.parser.add_argument("--gt", type=int, default=20, help="ground-truth boxes per frame")
    bench.parser.add_argument("--pred", type=int, default=200, help="predictions per frame")
    bench.parser.add_argument("--seed", type=int, default=0)
    bench.parser.add_argument("--rounds", type=int, default=3, help="rounds of the three steps (default 3)")
    args = bench.parse(argv)
    if args.quick:
        args.frames = 1_000
    gt, pred = synthetic_boxes(args.frames, args.gt, args.pred, args.seed)
    gt_records, pred_records = to_results(gt), to_results(pred)
    tokens = list(pred_records)
    scores: dict[str, float] = {}

    def from_arrays() -> None:
        scores["FDS from arrays"] = evaluate(gt, pred, EvalConfig()).FDS

    def to_arrays() -> tuple[EvalBoxes, EvalBoxes]:
        return (
            EvalBoxes.from_records(gt_records, tokens=tokens, ground_truth=True),
            EvalBoxes.from_records(pred_records, tokens=tokens),
        )

    def from_records() -> None:
        scores["FDS from records"] = evaluate(*to_arrays(), EvalConfig()).FDS

    steps = {
        "metric from arrays (main + 0-30 m breakdown)": from_arrays,
        "records -> arrays": to_arrays,
        "whole path from records": from_records,
    }
    timings = harness.alternate(steps, args.rounds, repeat=1, warmup=0)
    boxes = {"frames": args.frames, "ground-truth boxes": len(gt), "predictions": len(pred), **scores}
    bench.save(args, {"Metric time": [{"step": name, **t.row()} for name, t in timings.items()], "Boxes": [boxes]})
    return 0


if __name__ == "__main__":
    sys.exit(main())
