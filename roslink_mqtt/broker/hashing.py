"""Password hashing that cannot starve the fleet: one thread, a bounded wait, a fast refusal beyond it.

A login's PBKDF2 (210,000 SHA-512 iterations) takes tens of milliseconds of a core. asyncio's default executor runs
up to min(32, cores + 4) of them at once, so a flood of wrong passwords, from any number of addresses and with no
login needed, took every core from the broker's event loop: issue 48 measured an admin's round trip at p99 7 s and a
robot's heartbeat 4 s late. Here every slow check runs on one thread (hashlib releases the GIL while it hashes: the
event loop keeps the other core), and a check that would wait longer than ``max_wait`` for its turn is not queued
at all: the caller refuses the login at once with "server unavailable", which clients retry; an attempt from an
address whose passwords failed lately only gets an idle thread, so guessers cannot fill the queue in front of a
user who has not failed. Verified logins never get here (the plugin asks
:class:`~roslink_mqtt.config.passwords.VerifiedLogins` first), so a fleet reconnecting through a flood still gets in.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")

MAX_WAIT = 1.0  # s a login may wait for its password check before it is refused as "server unavailable"
INITIAL_COST = 0.1  # s assumed per check before one has been timed


class HashPool:
    """Slow password checks, one at a time, in arrival order; ``busy()`` says when one more would wait too long."""

    def __init__(self, max_wait: float = MAX_WAIT, clock: Callable[[], float] = time.monotonic) -> None:
        self.max_wait, self._clock = max_wait, clock
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="password-check")
        self._lock = threading.Lock()
        self.waiting = 0  # checks queued or running
        self.cost = INITIAL_COST  # s per check, a moving average of the measured ones
        self.done = self.refused = 0

    def expected_wait(self) -> float:
        """Seconds a check submitted now would wait before it starts."""
        with self._lock:
            return self.waiting * self.cost

    def busy(self, suspect: bool = False) -> bool:
        """One more check would wait longer than ``max_wait``: refuse it instead (and count it). A ``suspect`` one
        (from an address whose passwords failed lately) only gets an idle pool: a guesser cannot keep the queue
        full in front of a user who has not failed, whatever its number of addresses beyond the first try each."""
        if suspect:
            with self._lock:
                idle = self.waiting == 0
            if idle:
                return False
        elif self.expected_wait() <= self.max_wait:
            return False
        with self._lock:
            self.refused += 1
        return True

    async def run(self, check: Callable[[], T]) -> T:
        """Run ``check`` on the pool's thread; its duration feeds :attr:`cost`."""
        with self._lock:
            self.waiting += 1

        def timed() -> T:
            started = self._clock()
            try:
                return check()
            finally:
                took = self._clock() - started
                with self._lock:
                    self.cost = 0.8 * self.cost + 0.2 * took
                    self.done += 1

        try:
            return await asyncio.get_running_loop().run_in_executor(self._executor, timed)
        finally:
            with self._lock:
                self.waiting -= 1

    def close(self) -> None:
        self._executor.shutdown(wait=False, cancel_futures=True)
