"""What ONNX Runtime's spinning threads cost and give: ``Detector(spin=True)`` (the default) against ``spin=False``.

    python benchmarks/spinning.py compact [--rate 10 --seconds 5 --rounds 4 --threads 2] [--quick]

After a call, ONNX Runtime's intra-op threads spin for a while, ready for the next one
(``session.intra_op.allow_spinning``). Two measurements, the settings in turns (each first in
every other round):

1. a camera's pace: one Detector called ``--rate`` times a second for ``--seconds``; the median
   latency of a call, and the CPU time the process used per frame (its threads' spinning
   included): what is left of the cores for everything else on the machine;
2. two models in one process: two Detectors on the file called in turn, back to back; the median
   latency of a call, which starts while the other session's threads may still spin.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass

import harness
import numpy as np
from model_files import MODEL_HELP, model_path

from fisheye_infer.runtime.detector import Detector

SETTINGS = {"spin (default)": True, "spin=False": False}
#: Pause before each measured phase, so that no thread left spinning by the phase before is counted in it.
SETTLE_S = 0.5


@dataclass(frozen=True)
class Round:
    """One round of one setting: paced call latencies (ms), CPU ms per paced call, cores kept busy,
    and the latencies (ms) of the two models called in turn."""

    paced_ms: list[float]
    cpu_ms: float
    cores: float
    turns_ms: list[float]


def paced(
    detector: Detector, images: np.ndarray, valid: np.ndarray, rate: float, seconds: float
) -> tuple[list[float], float, float]:
    """Call latencies (ms) at ``rate`` calls per second; the process's CPU ms per call (every
    thread's, spinning included); and the cores it kept busy (CPU time over wall time, which holds
    when the calls are too slow for the rate)."""
    period, latencies = 1.0 / rate, []
    cpu0, start = time.process_time(), time.perf_counter()
    for k in range(max(1, int(rate * seconds))):
        time.sleep(max(0.0, start + k * period - time.perf_counter()))
        t0 = time.perf_counter()
        detector.run_arrays(images, valid)
        latencies.append((time.perf_counter() - t0) * 1e3)
    time.sleep(max(0.0, start + len(latencies) * period - time.perf_counter()))  # the last period's spinning counts too
    cpu_s, wall_s = time.process_time() - cpu0, time.perf_counter() - start
    return latencies, cpu_s * 1e3 / len(latencies), cpu_s / wall_s


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="2 rounds of 3 s")
    p = bench.parser
    p.add_argument("model", help=MODEL_HELP)
    p.add_argument("--threads", type=int, default=None, help="intra-op threads (default: all cores)")
    p.add_argument("--rate", type=float, default=10.0, help="calls per second in the paced measurement (default 10)")
    p.add_argument("--seconds", type=float, default=5.0, help="length of one paced round (default 5)")
    p.add_argument("--rounds", type=int, default=4, help="rounds per setting, settings in turns (default 4)")
    p.add_argument("--calls", type=int, default=10, help="calls per model per round, two models in turn (default 10)")
    args = bench.parse(argv)
    if args.quick:
        args.rounds, args.seconds = 2, 3.0

    model = model_path(args.model)
    pairs = {
        name: (Detector(model, threads=args.threads, spin=spin), Detector(model, threads=args.threads, spin=spin))
        for name, spin in SETTINGS.items()
    }
    info = pairs["spin (default)"][0].info
    width, height = info.image_size
    images = np.random.default_rng(0).integers(0, 256, (1, len(info.cameras), height, width, 3), dtype=np.uint8)
    valid = np.ones(images.shape[:2], bool)

    def one_round(first: Detector, second: Detector) -> Round:
        time.sleep(SETTLE_S)
        ms, cpu_ms, cores = paced(first, images, valid, args.rate, args.seconds)
        time.sleep(SETTLE_S)
        turns = harness.alternate(
            {"first": lambda: first.run_arrays(images, valid), "second": lambda: second.run_arrays(images, valid)},
            args.calls,
            warmup=0,
        )
        return Round(ms, cpu_ms, cores, [t for s in turns.values() for t in s.values])

    calls = {name: (lambda pair=pair: one_round(*pair)) for name, pair in pairs.items()}
    rounds = harness.in_turns(calls, args.rounds, flip=True)
    rows = [
        {
            "setting": name,
            "paced: latency median ms": float(np.median([t for r in rs for t in r.paced_ms])),
            "paced: CPU ms per frame": float(np.median([r.cpu_ms for r in rs])),
            "paced: cores busy": float(np.median([r.cores for r in rs])),
            "two models in turn: latency median ms": float(np.median([t for r in rs for t in r.turns_ms])),
        }
        for name, rs in rounds.items()
    ]
    bench.save(args, {"Spinning against not, settings in turns": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
