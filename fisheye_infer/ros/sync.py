"""Approximate-time synchronisation of N camera streams, for a live node and for replay alike.

    sync = Synchroniser(["front", "rear"], tolerance_ns=20_000_000, queue_size=10)
    for complete in sync.push("front", stamp, item): ...     # each complete set, oldest first
    sync.flush()                                              # at the end: what never completed is counted

A set is one message per camera whose stamps lie within ``tolerance_ns`` of each other, as ROS
``message_filters``' approximate policy pairs them. Each camera's messages queue in stamp order; when
every queue has one, the oldest heads are compared: within the tolerance they form a set; otherwise the
oldest head can never be matched (every other camera's next message is later than its tolerance) and is
dropped. Every message that leaves without a set is counted by reason (``dropped``):

- ``unsynchronised``: no message of some other camera within the tolerance;
- ``out of order``: older than one already taken from the same camera;
- ``queue full``: its camera's queue held ``queue_size`` messages while another camera was silent;
- ``incomplete at the end``: still waiting when the stream ended (``flush``).
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

__all__ = ["DROP_REASONS", "Synchroniser", "SyncedSet"]

DROP_REASONS = ("unsynchronised", "out of order", "queue full", "incomplete at the end")


@dataclass(frozen=True)
class SyncedSet:
    """One message per camera, in the synchroniser's camera order, with their stamps.

    Attributes:
        stamps: Each camera's stamp, ns.
        items: Each camera's message, as pushed.
    """

    stamps: tuple[int, ...]
    items: tuple[Any, ...]

    @property
    def stamp(self) -> int:
        """The set's stamp: its first camera's."""
        return self.stamps[0]


@dataclass
class Synchroniser:
    """Approximate-time synchronisation of N camera streams (the module docstring says how sets form and drop).

    Attributes:
        cameras: The cameras' names, in the order each set lists them.
        tolerance_ns: How far apart (ns) the stamps of one set may be.
        queue_size: Messages kept per camera while waiting for the others.
        dropped: Messages that left without a set, by reason (``DROP_REASONS``).

    Raises:
        ValueError: The camera names repeat or are empty, or the tolerance or queue size is out of range.

    Examples:
        ```python
        sync = Synchroniser(["front", "rear"], tolerance_ns=20_000_000)
        sets = [*sync.push("front", 100, "f0"), *sync.push("rear", 105, "r0")]
        print(sets[0].items)  # ('f0', 'r0')
        ```
    """

    cameras: Sequence[str]
    tolerance_ns: int
    queue_size: int = 10
    dropped: Counter[str] = field(default_factory=Counter)
    _queues: dict[str, deque[tuple[int, Any]]] = field(init=False)
    _last: dict[str, int] = field(init=False)

    def __post_init__(self) -> None:
        if not self.cameras or len(set(self.cameras)) != len(self.cameras):
            raise ValueError(f"cameras: expected distinct names, got {list(self.cameras)}")
        if self.tolerance_ns < 0 or self.queue_size < 1:
            raise ValueError(
                f"tolerance_ns {self.tolerance_ns} and queue_size {self.queue_size}: expected >= 0 and >= 1"
            )
        self._queues = {c: deque() for c in self.cameras}
        self._last = {}

    def push(self, camera: str, stamp: int, item: Any) -> Iterator[SyncedSet]:
        """Queue one message; yields the sets it completes, oldest first.

        Args:
            camera: The message's camera, one of ``cameras``.
            stamp: The message's stamp, ns.
            item: The message (any object; returned in the set's ``items``).

        Yields:
            SyncedSet: Each set this message completes.

        Raises:
            KeyError: ``camera`` is not one of ``cameras``.
        """
        if camera not in self._queues:
            raise KeyError(f"camera {camera!r}: not one of {', '.join(self.cameras)}")
        if camera in self._last and stamp < self._last[camera]:
            self.dropped["out of order"] += 1
            return
        self._last[camera] = stamp
        queue = self._queues[camera]
        queue.append((stamp, item))
        if len(queue) > self.queue_size:
            queue.popleft()
            self.dropped["queue full"] += 1
        while all(self._queues.values()):
            heads = [self._queues[c][0][0] for c in self.cameras]
            if max(heads) - min(heads) <= self.tolerance_ns:
                taken = [self._queues[c].popleft() for c in self.cameras]
                yield SyncedSet(tuple(s for s, _ in taken), tuple(i for _, i in taken))
            else:
                oldest = self.cameras[heads.index(min(heads))]
                self._queues[oldest].popleft()
                self.dropped["unsynchronised"] += 1

    def flush(self) -> None:
        """End of stream: every message still queued is counted ``incomplete at the end``."""
        for queue in self._queues.values():
            if queue:
                self.dropped["incomplete at the end"] += len(queue)
            queue.clear()
