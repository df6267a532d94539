"""Failed-login throttling by login *and* by address: guessing gets slow, robots are not locked out.

:class:`KeyThrottle` spaces attempts for one key (an address, a login, or the pair): the
first ``free_failures`` failures of a key (within ``forget_after`` seconds) cost nothing,
so a person who mistypes is not delayed. After that, every attempt of that key -- right or
wrong, because the verdict must not come back early -- waits for its own slot: slots are
spaced ``delay`` apart, and ``delay`` doubles with each further failure up to
``max_delay``. Spacing slots (instead of sleeping a fixed time per attempt) bounds the
guessing rate even when an attacker opens many connections at once. When the queue of one
key grows beyond ``max_wait``, new attempts are refused at once without checking the
password, so the broker does not hold thousands of sockets for one attacker.

:class:`LoginThrottle` combines three of them, because one key alone fails one way or the other:

* by address alone, ten wrong passwords from a NAT that a robot shares locked the robot's
  bridge out for minutes, while 40 guesses from 40 addresses went through in 0.1 s;
* so an attempt waits for the slowest of its address, its login and its (login, address)
  pair -- which bounds the guessing rate per login and per address -- *unless* the pair
  is known good: that login succeeded from that address within ``remember_good``
  seconds. A known-good pair waits only for its own failures, so a robot reconnecting from
  its usual address gets in at once however much others guess, from anywhere.

Attempts that arrive together are checked a few at a time (``free_failures`` unanswered per address and per
login, :meth:`LoginThrottle.try_begin`), so 40 simultaneous guesses cannot all be checked before the first
failures slow the rest. They used to count as failures until answered, which refused a fleet of ten robots
reconnecting at once from one address (a NAT, a gateway, every robot of a loopback benchmark) after a
broker restart, when no pair is known good yet: now they wait their turn, a millisecond or two each.

What cannot be told apart is not: wrong passwords for the robot's own login from the
robot's own address slow the robot too (bounded by ``max_wait``). Nothing is blocked for
good: failures older than ``forget_after`` are forgotten.

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


class KeyThrottle:
    """Slot spacing for the attempts of one kind of key (see the module docstring)."""

    def __init__(self, *, free_failures: int = 5, base_delay: float = 0.5, max_delay: float = 8.0,
                 max_wait: float = 10.0, forget_after: float = 300.0, max_addresses: int = 10_000,
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
        growth: int = 2 ** over  # over >= 0 here: an int
        return min(self.base_delay * growth, self.max_delay)

    def reserve(self, address: str, pending: int = 0) -> float:
        """Seconds this attempt must wait before its password is checked, or :data:`REFUSE`.

        ``pending``: other attempts of this key let in and not answered yet; once the key has failed, they count
        as failures for the spacing (they may all be wrong), so answers arriving one by one cannot let more
        than the free failures through at once.
        """
        now = self.clock()
        record = self._record(address, now)
        if record is None:
            return 0.0
        spacing = self.delay_for(len(record.failures) + pending)
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

    def forget(self, address: str) -> None:
        self._records.pop(address, None)

    def _prune(self, now: float) -> None:
        for address in list(self._records):
            self._record(address, now)
        while len(self._records) >= self.max_addresses:  # still full: forget the oldest
            del self._records[next(iter(self._records))]


class LoginThrottle:
    """Per address, per login and per (login, address) pair, with known-good pairs exempt from the first two."""

    def __init__(self, *, free_failures: int = 5, base_delay: float = 0.5, max_delay: float = 8.0,
                 max_wait: float = 10.0, forget_after: float = 300.0, max_addresses: int = 10_000,
                 remember_good: float = 7 * 24 * 3600.0, clock: Callable[[], float] = time.monotonic) -> None:
        def make() -> KeyThrottle:
            return KeyThrottle(free_failures=free_failures, base_delay=base_delay, max_delay=max_delay,
                               max_wait=max_wait, forget_after=forget_after, max_addresses=max_addresses, clock=clock)

        self.by_address, self.by_login, self.by_pair = make(), make(), make()
        self.remember_good, self.max_good, self.clock = remember_good, max_addresses, clock
        self._good: dict[str, float] = {}  # pair -> when it last succeeded (insertion order = age)
        self._in_flight: dict[tuple[str, str], int] = {}  # (kind, address or login) -> unanswered attempts
        self.max_wait = max_wait

    @staticmethod
    def _pair(address: str, login: str) -> str:
        return f"{login}\0{address}"

    def is_known_good(self, address: str, login: str) -> bool:
        when = self._good.get(self._pair(address, login))
        return when is not None and self.clock() - when <= self.remember_good

    def reserve(self, address: str, login: str) -> float:
        """Seconds this attempt must wait before its password is checked (spacing after failures), or REFUSE.

        Only answered attempts count: a wrong password is recorded by :meth:`failed`. Attempts that arrive
        together are bounded by :meth:`try_begin` instead, so a fleet behind one address (or one NAT) that
        reconnects at once after a broker restart is checked a few at a time, never refused for being many.
        """
        pair = self._pair(address, login)
        if self.is_known_good(address, login):
            return self.by_pair.reserve(pair)
        pending = [self._in_flight.get(("address", address), 1) - 1, self._in_flight.get(("login", login), 1) - 1]
        waits = [self.by_pair.reserve(pair), self.by_address.reserve(address, max(0, pending[0])),
                 self.by_login.reserve(login, max(0, pending[1]))]
        return REFUSE if REFUSE in waits else max(waits)

    def try_begin(self, address: str, login: str) -> tuple[tuple[str, str], ...] | None:
        """Let this attempt be checked now, or None (not yet): at most ``free_failures`` unanswered attempts per
        address and per login are checked at once; a known-good pair always is. 40 guesses in the same
        millisecond therefore cannot all be checked before the first failures slow the rest, and a fleet
        reconnecting at once waits a moment instead of being refused. The caller retries within ``max_wait``
        and hands what this returned to :meth:`end` once the attempt is answered."""
        if self.is_known_good(address, login):
            return ()
        keys = (("address", address), ("login", login))
        cap = max(1, self.by_address.free_failures)
        if any(self._in_flight.get(key, 0) >= cap for key in keys):
            return None
        for key in keys:
            self._in_flight[key] = self._in_flight.get(key, 0) + 1
        return keys

    def blocked_on(self, address: str, login: str) -> tuple[tuple[str, str], ...]:
        """The places (keys) an attempt :meth:`try_begin` turned away waits for: those at their cap now."""
        cap = max(1, self.by_address.free_failures)
        return tuple(key for key in (("address", address), ("login", login)) if self._in_flight.get(key, 0) >= cap)

    def end(self, admitted: tuple[tuple[str, str], ...]) -> None:
        """The attempt :meth:`try_begin` let in has been answered: free its places."""
        for key in admitted:
            left = self._in_flight.get(key, 0) - 1
            if left > 0:
                self._in_flight[key] = left
            else:
                self._in_flight.pop(key, None)

    def failed(self, address: str, login: str) -> None:
        """A wrong password (or unknown login): counted for the pair, and for the address and the login unless
        the pair is known good (a robot's own typo must not slow everyone behind its NAT)."""
        self.by_pair.failed(self._pair(address, login))
        if not self.is_known_good(address, login):
            self.by_address.failed(address)
            self.by_login.failed(login)

    def succeeded(self, address: str, login: str) -> None:
        """The attempt's password was right: remember the pair as good."""
        pair = self._pair(address, login)
        self.by_pair.forget(pair)
        self._good.pop(pair, None)
        self._good[pair] = self.clock()
        while len(self._good) > self.max_good:
            del self._good[next(iter(self._good))]

    def login_failures(self, login: str) -> int:
        """Recent failures of ``login``, from any address."""
        return self.by_login.failures(login)

    def failures(self, address: str, login: str | None = None) -> int:
        """Recent failures of ``address`` (or of the pair, when ``login`` is given)."""
        if login is None:
            return self.by_address.failures(address)
        return self.by_pair.failures(self._pair(address, login))
