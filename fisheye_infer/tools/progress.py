"""``Progress``: a frames-done line on stderr for long runs (``eval`` over a split, ``detect --ray``).

On a terminal the bar is redrawn in place; in a log (CI, a batch job) one line is written
every ``every`` frames and at the end, so logs stay short and still show the rate.
"""

from __future__ import annotations

import sys
import time

__all__ = ["Progress"]


class Progress:
    """See the module docstring."""

    def __init__(self, total: int, every: int = 100, width: int = 30) -> None:
        self.total, self.every, self.width = total, every, width
        self.tty = sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def update(self, done: int) -> None:
        if not (self.tty or done % self.every == 0 or done == self.total):
            return
        elapsed = time.perf_counter() - self.t0
        rate = done / elapsed if elapsed > 0 else 0.0
        filled = self.width * done // max(self.total, 1)
        eta = (self.total - done) / rate if rate > 0 else 0.0
        line = (
            f"  [{'#' * filled}{'.' * (self.width - filled)}] {done}/{self.total} frames, "
            f"{rate:.1f} frames/s, {eta:.0f} s left"
        )
        end = "\n" if not self.tty or done == self.total else ""
        print(("\r" if self.tty else "") + line, end=end, file=sys.stderr, flush=True)
