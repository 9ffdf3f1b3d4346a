"""How long the metric takes on a full-size evaluation, with synthetic boxes (no model, no images).

    .venv/bin/python benchmarks/metric_speed.py --frames 10000 --gt 20 --pred 200

Timed separately: the metric on arrays, the conversion of in-memory records, and the whole path
from records. The boxes come from ``fisheye_infer.eval.synthetic``.
"""

from __future__ import annotations

import argparse
import time

from fisheye_infer.eval.boxes import EvalBoxes
from fisheye_infer.eval.evaluate import evaluate
from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.eval.synthetic import synthetic_boxes, to_results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    parser.add_argument("--frames", type=int, default=10_000)
    parser.add_argument("--gt", type=int, default=20, help="ground-truth boxes per frame")
    parser.add_argument("--pred", type=int, default=200, help="predictions per frame")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    gt, pred = synthetic_boxes(args.frames, args.gt, args.pred, args.seed)
    print(f"{args.frames} frames, {len(gt):,} ground-truth boxes, {len(pred):,} predictions")
    t0 = time.perf_counter()
    report = evaluate(gt, pred, EvalConfig())
    t1 = time.perf_counter()
    print(f"metric from arrays (main + 0-30 m breakdown): {t1 - t0:.2f} s   FDS {report.FDS:.4f}  mAP {report.mAP:.4f}")
    gt_res, pred_res = to_results(gt), to_results(pred)
    t2 = time.perf_counter()
    tokens = list(pred_res)
    gt_boxes = EvalBoxes.from_records(gt_res, tokens=tokens, ground_truth=True)
    pred_boxes = EvalBoxes.from_records(pred_res, tokens=tokens)
    t3 = time.perf_counter()
    again = evaluate(gt_boxes, pred_boxes, EvalConfig())
    t4 = time.perf_counter()
    print(f"records -> arrays: {t3 - t2:.2f} s   whole path from records: {t4 - t2:.2f} s   FDS {again.FDS:.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
