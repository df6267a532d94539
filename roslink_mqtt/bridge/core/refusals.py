"""Errors that refuse one user input with a reason for its sender, ROS-free.

The command endpoint turns each of these into an error report on ``to/<user>/error`` and carries out
nothing; any other exception is a bug and is not dressed up as a refusal.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

from ...protocol import ProtocolError
from .presets.command import CommandRefused
from .safety import UnsafeCommand


class ConversionError(ValueError):
    """Untrusted JSON does not fit the ROS type; the message names the field path (``linear.x: …``)."""

    def __init__(self, reason: str, path: str = "") -> None:
        super().__init__(f"{path}: {reason}" if path else reason)
        self.reason, self.path = reason, path

    def inside(self, segment: str) -> ConversionError:
        """The same error seen from the enclosing field (``segment`` is a field name or ``[i]``)."""
        if not self.path:
            return ConversionError(self.reason, segment)
        return ConversionError(self.reason, segment + (self.path if self.path.startswith("[") else "." + self.path))


# a body that is not ROSLink, does not fit the ROS type, cannot be carried out here, or is not a safe velocity
INPUT_REFUSALS: tuple[type[Exception], ...] = (ProtocolError, ConversionError, CommandRefused, UnsafeCommand)


REPORT_RATE, REPORT_BURST = 50.0, 100  # refusal reports per second per user, and the burst allowed


@dataclass
class _Bucket:
    tokens: float
    at: float
    held: int = 0  # refusals not reported one by one since the last report
    last: tuple[str, str] | None = None  # (topic, reason) of the latest of them


class RefusalReports:
    """At most :data:`REPORT_RATE` refusal reports a second per user; the rest are counted, then summarised.

    Every refused input is answered on ``to/<user>/error``, so a user flooding bad (or over-limit) input would
    make the bridge flood back just as fast, on the connection that also carries the robot's heartbeats. Over
    the rate, reports are held back and counted; the next report says how many were not sent, and
    :meth:`summaries` (the supervision timer) reports a count nobody has heard of yet once the flood stops. So
    nothing is refused silently, and a flood costs the robot one report per 20 ms at most. Thread-safe.
    """

    def __init__(self, rate: float = REPORT_RATE, burst: int = REPORT_BURST) -> None:
        self.rate, self.burst = rate, burst
        self._lock = threading.Lock()
        self._buckets: dict[str, _Bucket] = {}

    def _refill(self, bucket: _Bucket, now: float) -> None:
        bucket.tokens = min(self.burst, bucket.tokens + (now - bucket.at) * self.rate)
        bucket.at = now

    def admit(self, user: str, topic: str, reason: str, now: float) -> str | None:
        """The reason to report now (with a count of held-back reports, if any), or None: hold this one back."""
        with self._lock:
            bucket = self._buckets.get(user)
            if bucket is None:
                bucket = self._buckets[user] = _Bucket(float(self.burst), now)
            self._refill(bucket, now)
            if bucket.tokens < 1:
                bucket.held += 1
                bucket.last = (topic, reason)
                return None
            bucket.tokens -= 1
            held, bucket.held, bucket.last = bucket.held, 0, None
        return reason if not held else f"{reason} [{_held_text(held, self.rate)}]"

    def summaries(self, now: float) -> list[tuple[str, str, str]]:
        """``(user, topic, reason)`` for each user whose held-back refusals can be reported now; forgets idle users."""
        out = []
        with self._lock:
            for user, bucket in list(self._buckets.items()):
                self._refill(bucket, now)
                if bucket.held and bucket.tokens >= 1 and bucket.last is not None:
                    bucket.tokens -= 1
                    topic, reason = bucket.last
                    out.append((user, topic, f"{reason} [{_held_text(bucket.held, self.rate)}, this was the last]"))
                    bucket.held, bucket.last = 0, None
                elif not bucket.held and bucket.tokens >= self.burst:
                    del self._buckets[user]  # full again: nothing to remember
        return out


def _held_text(held: int, rate: float) -> str:
    return f"{held} more of your inputs were refused and not reported one by one (over {rate:g} reports/s)"
