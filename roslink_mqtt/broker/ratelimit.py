"""Failed-login throttling per client address: password guessing gets slow, people do not get locked out.

The first ``free_failures`` failures from an address (within ``forget_after`` seconds)
cost nothing, so a person who mistypes is not delayed. After that, every login attempt
from that address -- right or wrong, because the verdict must not come back early --
waits for its own slot: slots are spaced ``delay`` apart, and ``delay`` doubles with each
further failure up to ``max_delay``. Spacing slots (instead of sleeping a fixed time per
attempt) bounds the guessing rate even when an attacker opens many connections at
once. When the queue of waiting attempts from one address grows beyond ``max_wait``,
new attempts are refused at once without checking the password, so the broker does not
hold thousands of sockets for one attacker.

Nothing is ever blocked for good: failures older than ``forget_after`` are forgotten,
and other addresses are never affected. Behind a reverse proxy every client shares the
proxy's address; run the broker's listeners directly, or raise the limits.

Pure logic with an injectable clock; the auth plugin awaits the returned delay.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

REFUSE = -1.0  # returned by :meth:`LoginThrottle.reserve`: refuse without checking


@dataclass
class _Record:
    failures: list[float] = field(default_factory=list)  # monotonic times of recent failures
    next_slot: float = 0.0  # earliest time the next throttled attempt may be checked


class LoginThrottle:
    def __init__(self, *, free_failures: int = 5, base_delay: float = 0.5, max_delay: float = 8.0,
                 max_wait: float = 30.0, forget_after: float = 300.0, max_addresses: int = 10_000,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if free_failures < 0 or base_delay < 0 or max_delay < base_delay:
            raise ValueError("need free_failures >= 0 and 0 <= base_delay <= max_delay")
        self.free_failures, self.base_delay, self.max_delay = free_failures, base_delay, max_delay
        self.max_wait, self.forget_after, self.max_addresses = max_wait, forget_after, max_addresses
        self.clock = clock
        self._records: dict[str, _Record] = {}

    def _record(self, address: str, now: float) -> _Record | None:
        record = self._records.get(address)
        if record is not None:
            horizon = now - self.forget_after
            if record.failures and record.failures[0] < horizon:
                record.failures = [t for t in record.failures if t >= horizon]
            if not record.failures and record.next_slot <= now:
                del self._records[address]
                return None
        return record

    def delay_for(self, failures: int) -> float:
        """Spacing between attempts after ``failures`` recent failures."""
        over = failures - self.free_failures
        if failures == 0 or over < 0:
            return 0.0
        return min(self.base_delay * 2 ** over, self.max_delay)

    def reserve(self, address: str) -> float:
        """Seconds this attempt must wait before its password is checked, or :data:`REFUSE`."""
        now = self.clock()
        record = self._record(address, now)
        if record is None:
            return 0.0
        spacing = self.delay_for(len(record.failures))
        if spacing <= 0:
            return 0.0
        slot = max(now, record.next_slot) + spacing
        if slot - now > self.max_wait:
            return REFUSE
        record.next_slot = slot
        return slot - now

    def failed(self, address: str) -> None:
        now = self.clock()
        record = self._record(address, now)
        if record is None:
            if len(self._records) >= self.max_addresses:
                self._prune(now)
            record = self._records[address] = _Record()
        record.failures.append(now)

    def failures(self, address: str) -> int:
        record = self._record(address, self.clock())
        return 0 if record is None else len(record.failures)

    def _prune(self, now: float) -> None:
        for address in list(self._records):
            self._record(address, now)
        while len(self._records) >= self.max_addresses:  # still full: forget the oldest
            del self._records[next(iter(self._records))]
