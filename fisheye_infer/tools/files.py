"""Files that appear whole or not at all: written beside their destination, renamed into place.

A reader (another process, a server reloading a model) never sees half a file, and a failed or
refused write leaves nothing behind: the temporary file is removed however the block ends.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["PendingFile", "pending_file"]


class PendingFile:
    """A temporary path beside ``out`` (same folder, so the rename is atomic) and the rename into place."""

    def __init__(self, out: Path, tag: str = "") -> None:
        self.out = out
        self.path = out.with_name(f".{out.name}.{os.getpid()}{'.' + tag if tag else ''}.tmp")

    def commit(self) -> Path:
        """Rename the temporary file to ``out``, replacing what was there; returns ``out``."""
        os.replace(self.path, self.out)
        return self.out


@contextmanager
def pending_file(out: str | Path, tag: str = "") -> Iterator[PendingFile]:
    """Write to ``.path``, then ``commit()`` to publish it as ``out``; without a commit nothing appears.

    ``tag`` tells apart temporary files of different writers aiming at the same folder at once.
    """
    pending = PendingFile(Path(out), tag)
    try:
        yield pending
    finally:
        pending.path.unlink(missing_ok=True)
