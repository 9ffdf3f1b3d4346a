"""What ONNX Runtime's spinning threads cost and give: ``Detector(spin=True)`` (the default) against ``spin=False``.

    .venv/bin/python benchmarks/spinning.py artifacts/int8/model.onnx          # a file benchmarks/int8.py writes
    .venv/bin/python benchmarks/spinning.py MODEL --rate 10 --seconds 5 --rounds 4 --threads 2

After a call, ONNX Runtime's intra-op threads spin for a while, ready for the next one (``session.intra_op.allow_spinning``).
Two measurements, the settings alternated round by round:

1. **a camera's pace**: one Detector called ``--rate`` times a second for ``--seconds``; the median
   latency of a call, and the CPU time the process used per frame (its threads' spinning included):
   what is left of the cores for everything else on the machine;
2. **two models in one process**: two Detectors on the file called in turn, back to back; the
   median latency of a call, which starts while the other session's threads may still spin.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from fisheye_infer.bench import machine
from fisheye_infer.detector import Detector

SETTINGS = {"spin (default)": True, "spin=False": False}
#: Pause before each measured phase, so that no thread left spinning by the phase before is counted in it.
SETTLE_S = 0.5


def paced(detector: Detector, images: np.ndarray, valid: np.ndarray, rate: float, seconds: float) -> tuple[list[float], float, float]:
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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="an exported ONNX file")
    parser.add_argument("--threads", type=int, default=None, help="intra-op threads (default: all cores)")
    parser.add_argument("--rate", type=float, default=10.0, help="calls per second in the paced measurement (default 10)")
    parser.add_argument("--seconds", type=float, default=5.0, help="length of one paced round (default 5)")
    parser.add_argument("--rounds", type=int, default=4, help="alternated rounds per setting (default 4)")
    parser.add_argument("--calls", type=int, default=10, help="calls per model per round, two models in turn (default 10)")
    args = parser.parse_args()

    host = machine()
    print(f"CPU: {host['cpu']}, {host['cpu_count']} cores; onnxruntime {host['onnxruntime']}; {Path(args.model).name}, threads {args.threads or 'all cores'}")
    detectors = {name: Detector(args.model, threads=args.threads, spin=spin) for name, spin in SETTINGS.items()}
    pairs = {name: (detectors[name], Detector(args.model, threads=args.threads, spin=spin)) for name, spin in SETTINGS.items()}
    info = next(iter(detectors.values())).info
    width, height = info.image_size
    images = np.random.default_rng(0).integers(0, 256, (1, len(info.cameras), height, width, 3), dtype=np.uint8)
    valid = np.ones(images.shape[:2], bool)

    latency: dict[str, list[float]] = {name: [] for name in SETTINGS}
    cpu: dict[str, list[float]] = {name: [] for name in SETTINGS}
    busy: dict[str, list[float]] = {name: [] for name in SETTINGS}
    turns: dict[str, list[float]] = {name: [] for name in SETTINGS}
    for r in range(args.rounds):
        for name in list(SETTINGS)[:: 1 if r % 2 == 0 else -1]:  # each setting first in every other round
            time.sleep(SETTLE_S)
            ms, cpu_ms, cores = paced(detectors[name], images, valid, args.rate, args.seconds)
            latency[name] += ms
            cpu[name].append(cpu_ms)
            busy[name].append(cores)
            time.sleep(SETTLE_S)
            for _ in range(args.calls):
                for detector in pairs[name]:
                    t0 = time.perf_counter()
                    detector.run_arrays(images, valid)
                    turns[name].append((time.perf_counter() - t0) * 1e3)
    print(f"\nmedians over {args.rounds} alternated rounds; paced: {args.rate:g} calls/s for {args.seconds:g} s; two models: {args.calls} calls each in turn\n")
    print("| setting | paced: latency ms | paced: CPU ms per frame | paced: cores busy | two models in turn: latency ms |\n|---|---|---|---|---|")
    for name in SETTINGS:
        print(f"| {name} | {np.median(latency[name]):.1f} | {np.median(cpu[name]):.1f} | {np.median(busy[name]):.2f} | {np.median(turns[name]):.1f} |")


if __name__ == "__main__":
    main()
