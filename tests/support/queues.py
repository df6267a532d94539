"""Reading what test clients collected."""

from __future__ import annotations

import queue
import time
from typing import TypeVar

T = TypeVar("T")


def drain(q: queue.Queue[T], seconds: float) -> list[T]:
    """Everything that arrives on ``q`` within ``seconds``."""
    end, out = time.monotonic() + seconds, []
    while (left := end - time.monotonic()) > 0:
        try:
            out.append(q.get(timeout=left))
        except queue.Empty:
            break
    return out
