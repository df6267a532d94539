"""``max_rate`` for ROS→MQTT rules: at most N messages a second, newest wins.

The naive rule "send if a period has passed since the last send" loses a whole
slot whenever a message arrives a hair early: a 20 Hz source throttled to
10 Hz gives ~8 Hz, because the message 99.8 ms after the last one waits for the
next check. Here sends are tied to a schedule of slots one period apart: a
message may go out up to ``slack`` before its slot, and the schedule advances
by at least one period per send, so the long-run rate is the configured rate
(never above it) whatever the jitter. A message that arrives between slots is
kept (newest wins) and sent by :meth:`flush` once its slot opens — unless the
source's next message is due within WAIT of the slot: then the slot goes to that
fresher one (the kept one is sent all the same if the next is late).

Why the wait: a 20 Hz odometry throttled to 10 Hz keeps every second message; a
flush that sent the kept one as soon as the slot opened sent, in every slot, a
message up to a source period old while a fresh one was milliseconds away (the
flush timer's phase against the source's, fixed for a whole run: the viewer's
pose 45 ms old at the median in one run, 80 ms in the next, on the same link).
"""

from __future__ import annotations

from typing import Any

SLACK = 0.1  # fraction of the period a message may be early for its slot
WAIT = 0.25  # fraction of the period (at most one source gap) a slot may wait for the source's next, fresher message
GAP_WEIGHT = 0.2  # weight of each new gap between offers in the source's period (a moving average)


class Throttle:
    __slots__ = ("period", "slack", "due", "pending", "pending_at", "gap", "last_offer")

    def __init__(self, max_rate: float) -> None:
        if not max_rate > 0:
            raise ValueError(f"max_rate must be > 0, got {max_rate!r}")
        self.period = 1.0 / max_rate
        self.slack = SLACK * self.period
        self.due = float("-inf")  # when the next slot opens
        self.pending: Any = None
        self.pending_at = float("-inf")  # when the kept message came
        self.gap: float | None = None  # the source's period, as its offers come (None: not known yet)
        self.last_offer: float | None = None

    def offer(self, msg: Any, now: float) -> Any:
        """The message to send now (``msg``), or None when it must wait for its slot (it is kept)."""
        self._learn(now)
        if now >= self.due - self.slack:
            self._take(now)
            self.pending = None
            return msg
        self.pending, self.pending_at = msg, now
        return None

    def flush(self, now: float) -> Any:
        """The kept message once its slot has opened, else None. Call at least twice per period."""
        if self.pending is None or now < self.due - self.slack:
            return None
        if self.gap is not None:
            fresher_at = self.pending_at + self.gap  # when the source's next message is due
            grace = min(WAIT * self.period, self.gap)  # (a fast source's next is late after one of its own gaps)
            if fresher_at <= self.due + grace and now < fresher_at + grace:
                return None  # the slot goes to that one (or to this one, should it be late)
        msg, self.pending = self.pending, None
        self._take(now)
        return msg

    def _learn(self, now: float) -> None:
        """The source's period from the gaps between its offers (an offer is each message the source sent)."""
        if self.last_offer is not None and now > self.last_offer:
            gap = now - self.last_offer
            self.gap = gap if self.gap is None else self.gap + GAP_WEIGHT * (gap - self.gap)
        self.last_offer = now

    def _take(self, now: float) -> None:
        # The next slot is one period after this one (the schedule does not drift with late sends), but
        # never sooner than a period, less the slack, after this send: after a quiet spell nothing bursts
        # to "catch up", and two sends are always at least (1 - 2 * SLACK) periods apart.
        self.due = max(self.due + self.period, now + self.period - self.slack)
