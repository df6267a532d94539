"""How many requests one user may have unanswered on this robot at once (``bridge.max_requests_per_user``).

Every service call and parameter request an MQTT user makes becomes a ROS service call on the robot. Without a
bound, a viewer who may read parameters could queue thousands of calls on a ROS node in a second and keep the
robot busy for minutes. A request takes a slot when the bridge accepts it and gives it back when it is answered
(reply, failure or timeout); one over the bound is refused at once, with :meth:`RequestBudget.refusal` as the
reason. ROS-free and thread-safe: requests arrive on MQTT threads and are answered on the executor.
"""

from __future__ import annotations

import threading
from collections import Counter

SETTING = "bridge.max_requests_per_user"


class RequestBudget:
    """Per-user count of requests in flight, shared by every kind of request it guards."""

    def __init__(self, limit: int) -> None:
        if limit < 1:
            raise ValueError(f"{SETTING} must be at least 1, got {limit}")
        self.limit = limit
        self._lock = threading.Lock()
        self._in_flight: Counter[str] = Counter()

    def acquire(self, user: str) -> bool:
        """Take a slot for ``user``; False when they already have ``limit`` requests unanswered."""
        with self._lock:
            if self._in_flight[user] >= self.limit:
                return False
            self._in_flight[user] += 1
            return True

    def release(self, user: str) -> None:
        """Give back a slot taken by :meth:`acquire` (exactly once per accepted request)."""
        with self._lock:
            left = self._in_flight[user] - 1
            if left > 0:
                self._in_flight[user] = left
            else:
                del self._in_flight[user]

    def in_flight(self, user: str) -> int:
        with self._lock:
            return self._in_flight[user]

    def refusal(self, user: str) -> str:
        """Why a request over the bound is refused (one line, names the setting)."""
        return (f"too many requests in flight: {user} already has {self.limit} service calls and parameter "
                f"requests unanswered on this robot ({SETTING}); wait for their replies")
