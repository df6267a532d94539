"""Emergency stops arrive twice — on the command connection and on one that carries nothing else — and are
obeyed once. ROS-free.

The bridge reads operators' emergency-stop inputs on a connection of their own as well (bridge/ros/node.py), so a stop
never waits behind other data on a thin downlink. The first copy of each stop (topic and payload) is obeyed, the
other dropped. Memory is bounded whatever arrives: payloads are kept as 16-byte digests, at most
:data:`MAX_KEPT` of them, each for :data:`WINDOW` seconds.
"""

from __future__ import annotations

import hashlib
import threading
import time
from collections.abc import Callable

WINDOW = 5.0  # s a copy is waited for
MAX_KEPT = 1024  # stops remembered at once (beyond: the oldest are forgotten)


class StopDedup:
    """``seen(topic, payload)``: True for the second copy of a stop (drop it), False for a new one (obey it)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self._kept: dict[tuple[str, bytes], float] = {}  # insertion order = arrival order

    def __len__(self) -> int:
        return len(self._kept)

    def seen(self, topic: str, payload: bytes | bytearray) -> bool:
        now = self._clock()
        key = (topic, hashlib.blake2b(payload, digest_size=16).digest())
        with self._lock:
            at = self._kept.pop(key, None)
            if at is not None and now - at < WINDOW:
                return True  # both copies have come: a third (a resend with the same bytes) is a new stop
            if len(self._kept) >= MAX_KEPT:
                self._kept = {k: t for k, t in self._kept.items() if now - t < WINDOW}
                while len(self._kept) >= MAX_KEPT:
                    del self._kept[next(iter(self._kept))]
            self._kept[key] = now
            return False
