"""Sequence-number tracking: drop duplicate and stale commands.

Sequence numbers are 32-bit and wrap. Comparison uses serial-number
arithmetic (RFC 1982): ``b`` is newer than ``a`` when ``(b - a) mod 2**32``
lies in ``1 .. 2**31 - 1``. A number far behind the last one (more than
``window`` back) is taken as a sender that restarted its counter, not as an
ancient message — otherwise a restarted teleop client would be ignored until
its counter caught up.
"""

from __future__ import annotations

from collections.abc import Hashable
from enum import Enum

MODULUS = 2**32
HALF = 2**31


class Verdict(Enum):
    NEW = "new"
    DUPLICATE = "duplicate"
    STALE = "stale"
    RESTART = "restart"  # accepted: the sender started counting again

    @property
    def accepted(self) -> bool:
        return self in (Verdict.NEW, Verdict.RESTART)


class SequenceTracker:
    """Remembers the newest sequence number per sender (e.g. ``(user, message_id)``)."""

    def __init__(self, window: int = 1024) -> None:
        if not 0 < window < HALF:
            raise ValueError(f"window must be in 1..{HALF - 1}")
        self.window = window
        self._last: dict[Hashable, int] = {}

    def check(self, sender: Hashable, sequence_number: int) -> Verdict:
        """Classify ``sequence_number`` and remember it when accepted."""
        seq = sequence_number % MODULUS
        last = self._last.get(sender)
        if last is None:
            self._last[sender] = seq
            return Verdict.NEW
        ahead = (seq - last) % MODULUS
        if ahead == 0:
            return Verdict.DUPLICATE
        if ahead < HALF:
            self._last[sender] = seq
            return Verdict.NEW
        behind = MODULUS - ahead
        if behind <= self.window:
            return Verdict.STALE
        self._last[sender] = seq
        return Verdict.RESTART

    def forget(self, sender: Hashable) -> None:
        """Drop what is known about ``sender`` (e.g. when its session ends)."""
        self._last.pop(sender, None)

    def __len__(self) -> int:
        return len(self._last)
