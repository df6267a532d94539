"""Logins waiting for a place among those being checked: woken in turn as places free, never polled.

The login throttle lets only a few unanswered attempts per address and per login be checked at once
(:meth:`~.ratelimit.LoginThrottle.try_begin`), so that many guesses in the same millisecond cannot all be checked
before the first failures slow the rest, and a fleet behind one address (one NAT) that reconnects at once is
checked a few at a time instead of being refused. Those waiting used to try again every 5 ms: a fleet of 1,000
robots and their operators reconnecting from one address was 2,000 coroutines waking 400,000 times a second, and
the broker's event loop — every robot's traffic — did little else (bench/fleet.py at 1,000 robots: 82 s to
connect, 581 connections lost). Here each waiter sleeps on a future registered under the places it waits for
(a key: ``("address", a)`` or ``("login", l)``), and each place that frees wakes the oldest waiter for it: the
loop wakes once per answered attempt, whatever the number waiting.
"""

from __future__ import annotations

import asyncio
import time
from collections import deque
from collections.abc import Hashable, Iterable

from .ratelimit import LoginThrottle

Slot = tuple[tuple[str, str], ...]  # the places an attempt holds (LoginThrottle.try_begin)


def _settle(future: asyncio.Future[Hashable | None], key: Hashable | None) -> None:
    if not future.done():
        future.set_result(key)


class Admission:
    """Futures waiting per key, first come first woken (asyncio, one event loop)."""

    def __init__(self) -> None:
        self._waiting: dict[Hashable, deque[asyncio.Future[Hashable | None]]] = {}

    def waiting(self) -> int:
        """Waiters not yet woken (a waiter for two keys counts twice): for tests and the log."""
        return sum(1 for queue in self._waiting.values() for future in queue if not future.done())

    async def wait(self, keys: Iterable[Hashable], timeout: float) -> Hashable | None:
        """Sleep until a place of one of ``keys`` frees (that key) or ``timeout`` s pass (None)."""
        loop = asyncio.get_running_loop()
        future: asyncio.Future[Hashable | None] = loop.create_future()
        for key in keys:
            self._waiting.setdefault(key, deque()).append(future)
        timer = loop.call_later(max(0.0, timeout), _settle, future, None)
        try:
            return await future
        finally:
            timer.cancel()
            if not future.done():
                future.cancel()  # (this task was cancelled: a release must not wake a waiter that is gone)

    def release(self, keys: Iterable[Hashable]) -> None:
        """A place of each of ``keys`` freed: wake the oldest live waiter for each."""
        for key in keys:
            queue = self._waiting.get(key)
            while queue:
                future = queue.popleft()
                if not future.done():
                    future.set_result(key)
                    break
            if queue is not None and not queue:
                del self._waiting[key]

    async def begin(self, throttle: LoginThrottle, address: str, login: str) -> Slot | None:
        """A place for this attempt among those being checked, once there is one (hand it to :meth:`end` when the
        attempt is answered); None when none came within the throttle's ``max_wait``.

        A waiter woken for a place it does not take passes it on to the next in line: it still waits for another
        place, or it needs none after all (a login known good since it began to wait). Otherwise that place would
        stay free while the others sleep until their ``max_wait``."""
        deadline = time.monotonic() + throttle.max_wait
        woken_for: Hashable | None = None
        while (slot := throttle.try_begin(address, login)) is None:
            blocked = throttle.blocked_on(address, login)
            if woken_for is not None and woken_for not in blocked:
                self.release([woken_for])
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            woken_for = await self.wait(blocked, remaining)
        if woken_for is not None and woken_for not in slot:
            self.release([woken_for])
        return slot

    def end(self, throttle: LoginThrottle, slot: Slot) -> None:
        """The attempt holding ``slot`` was answered: its places go to the oldest waiting for them."""
        throttle.end(slot)
        self.release(slot)
