"""Refused logins in the broker's log: each one while they are few, a count once they are many.

A refused login was one log line, and anyone who can reach the port can make thousands a second with no login
(issue 48's guessing flood: 19,815 in 8 s). That filled the log at ~0.5 MB a second — a disk to fill, a log
nobody can read — and formatting and writing the lines was 5 % of the event loop the robots' traffic runs on.
Now the first :data:`BUDGET` refusals of each :data:`WINDOW` are logged line by line, as before (what an admin
needs to see a user's mistake); past that they are counted, and one line at the window's end says how many more
there were, why, and from how many addresses. ROS-free and I/O-free but for the logger it is given.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable

WINDOW = 10.0  # s per window of the budget
BUDGET = 100  # refusals logged line by line per window; the rest are counted
MAX_ADDRESSES = 10_000  # distinct addresses remembered per window (a count past it says "or more")


def reason_kind(reason: str) -> str:
    """What a refusal's reason says without its numbers: its text before the first '(' or ';'."""
    for mark in ("(", ";"):
        reason = reason.split(mark, 1)[0]
    return reason.strip() or "refused"


class RefusalLog:
    """Logs refused logins within a budget per window, and a summary of the rest (``tick`` ends a window)."""

    def __init__(self, logger: logging.Logger, *, window: float = WINDOW, budget: int = BUDGET,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger, self.window, self.budget, self.clock = logger, window, budget, clock
        self.total = 0  # refusals since the start, logged or not
        self._ends = clock() + window
        self._logged = 0
        self._held: Counter[str] = Counter()
        self._addresses: set[str] = set()

    def refused(self, who: Callable[[], str], reason: str, address: str | None) -> None:
        """A login was refused; ``who`` describes it (called only when the line is written)."""
        self.tick()
        self.total += 1
        if self._logged < self.budget:
            self._logged += 1
            self.logger.warning("refused %s: %s", who(), reason)
            if self._logged == self.budget:
                self.logger.warning("%d logins refused within %.0f s: the rest of this window's are counted, "
                                    "not logged one by one", self.budget, self.window)
            return
        self._held[reason_kind(reason)] += 1
        if len(self._addresses) < MAX_ADDRESSES:
            self._addresses.add(address or "?")

    def tick(self) -> None:
        """End the window if its time is up: the summary of what was counted in it (cheap when nothing was)."""
        now = self.clock()
        if now < self._ends:
            return
        if self._held:
            count = sum(self._held.values())
            reasons = ", ".join(f"{kind}: {n}" for kind, n in self._held.most_common())
            addresses = f"{len(self._addresses)}{' or more' if len(self._addresses) >= MAX_ADDRESSES else ''}"
            self.logger.warning("refused %d more logins in the last %.0f s (%s) from %s addresses", count,
                                self.window, reasons, addresses)
        self._ends = now + self.window
        self._logged = 0
        self._held.clear()
        self._addresses.clear()
