"""In-flight ROS calls with deadlines: one table for service calls made for MQTT users and for preset commands.

A call is answered exactly once: by its future finishing or by the supervision timer finding it past its
deadline, whichever comes first. Both paths :meth:`PendingCalls.take` the entry under one lock, so the
loser finds nothing and says nothing. ROS-free (the entry is whatever the owner needs to answer).
"""

from __future__ import annotations

import itertools
import threading
from typing import Generic, TypeVar

T = TypeVar("T")


class PendingCalls(Generic[T]):
    """``key → (deadline, entry)``; thread-safe: futures finish in the executor, timeouts in the timer."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._entries: dict[int, tuple[float, T]] = {}
        self._keys = itertools.count(1)

    def add(self, entry: T, deadline: float) -> int:
        """Park ``entry`` until ``deadline`` (monotonic s); the key identifies it to :meth:`take`."""
        key = next(self._keys)
        with self._lock:
            self._entries[key] = (deadline, entry)
        return key

    def take(self, key: int) -> T | None:
        """The entry, removed; None when it was already answered (its timeout won the race)."""
        with self._lock:
            found = self._entries.pop(key, None)
        return None if found is None else found[1]

    def expire(self, now: float) -> list[T]:
        """Remove and return every entry past its deadline, oldest first."""
        with self._lock:
            late = [key for key, (deadline, _) in self._entries.items() if now > deadline]
            return [self._entries.pop(key)[1] for key in late]

    def __len__(self) -> int:
        with self._lock:
            return len(self._entries)
