"""``max_rate`` for ROS→MQTT rules: at most N messages a second, newest wins.

The naive rule "send if a period has passed since the last send" loses a whole
slot whenever a message arrives a hair early: a 20 Hz source throttled to
10 Hz gives ~8 Hz, because the message 99.8 ms after the last one waits for the
next check. Here sends are tied to a schedule of slots one period apart: a
message may go out up to ``slack`` before its slot, and the schedule advances
by at least one period per send, so the long-run rate is the configured rate
(never above it) whatever the jitter. A message that arrives between slots is
kept (newest wins) and sent by :meth:`flush` once its slot opens.
"""

from __future__ import annotations

from typing import Any

SLACK = 0.1  # fraction of the period a message may be early for its slot


class Throttle:
    __slots__ = ("period", "slack", "due", "pending")

    def __init__(self, max_rate: float) -> None:
        if not max_rate > 0:
            raise ValueError(f"max_rate must be > 0, got {max_rate!r}")
        self.period = 1.0 / max_rate
        self.slack = SLACK * self.period
        self.due = float("-inf")  # when the next slot opens
        self.pending: Any = None

    def offer(self, msg: Any, now: float) -> Any:
        """The message to send now (``msg``), or None when it must wait for its slot (it is kept)."""
        if now >= self.due - self.slack:
            self._take(now)
            self.pending = None
            return msg
        self.pending = msg
        return None

    def flush(self, now: float) -> Any:
        """The kept message once its slot has opened, else None. Call at least twice per period."""
        if self.pending is None or now < self.due - self.slack:
            return None
        msg, self.pending = self.pending, None
        self._take(now)
        return msg

    def _take(self, now: float) -> None:
        # The next slot is one period after this one (the schedule does not drift with late sends), but
        # never sooner than a period, less the slack, after this send: after a quiet spell nothing bursts
        # to "catch up", and two sends are always at least (1 - 2 * SLACK) periods apart.
        self.due = max(self.due + self.period, now + self.period - self.slack)
