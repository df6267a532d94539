"""Waiting on conditions, not on the clock: the suite's only pauses.

A test that sleeps a guessed time and then checks is green on a quiet machine and red on a busy one (a core taken
by another process stretches every start-up and every delivery), and it is slow everywhere else. These helpers
wait for what the test is really waiting for, with a generous deadline that only a real defect reaches, and say
what they waited for when it does not come:

* ``wait_until(what, check)`` — until ``check()`` is truthy; returns its value (a message, a row, a count).
* ``stays(what, check, seconds)`` — ``check()`` holds for the whole window (a robot that must keep moving).
* ``never(what, check, seconds)`` — ``check()`` never holds in the window (nothing may reach the actuator). A
  window is the one place a test waits for time itself: "nothing happened for 2 s" cannot be a condition.
* ``paced(period, ...)`` — a steady stream (an operator's twists, a flood): ticks on a fixed schedule, not
  ``sleep(period)`` after each send, so a slow send does not slow the stream down.

Every wait polls with ``time.monotonic`` (a wall-clock step does not cut a window short).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: How often a condition is looked at: short against every deadline in the suite, long against a check's cost.
POLL = 0.05


def wait_until(what: str, check: Callable[[], T], timeout: float = 10.0, period: float = POLL) -> T:
    """Poll ``check`` until it returns something truthy and return that; fail naming ``what`` after ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        last = check()
        if last:
            return last
        if time.monotonic() >= deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what} (last: {last!r})")
        time.sleep(period)


def stays(what: str, check: Callable[[], object], seconds: float, period: float = POLL) -> None:
    """Fail as soon as ``check()`` is falsy within the next ``seconds``: ``what`` must hold throughout."""
    end = time.monotonic() + seconds
    while True:
        value = check()
        if not value:
            raise AssertionError(f"{what} stopped holding (got {value!r})")
        if time.monotonic() >= end:
            return
        time.sleep(min(period, max(0.0, end - time.monotonic())))


def never(what: str, check: Callable[[], object], seconds: float, period: float = POLL) -> None:
    """Fail as soon as ``check()`` is truthy within the next ``seconds``: ``what`` must not happen."""
    end = time.monotonic() + seconds
    while True:
        value = check()
        if value:
            raise AssertionError(f"{what} happened (got {value!r})")
        if time.monotonic() >= end:
            return
        time.sleep(min(period, max(0.0, end - time.monotonic())))


def paced(period: float, count: int | None = None, within: float | None = None,
          stop: Callable[[], object] | None = None) -> Iterator[int]:
    """Yield 0, 1, 2, … one ``period`` apart on a fixed schedule (a late tick is not carried into the next).

    Ends after ``count`` ticks, after ``within`` seconds, or once ``stop()`` is truthy — whichever comes first;
    ``count`` or ``within`` must be given (a stream bounded only by a condition may never end).
    """
    if count is None and within is None:
        raise ValueError("paced() needs count or within")
    start = began = time.monotonic()  # start: the schedule's origin (moved when behind); began: the window's
    tick = 0
    while (count is None or tick < count) and (within is None or time.monotonic() - began < within):
        if stop is not None and stop():
            return
        yield tick
        tick += 1
        delay = start + tick * period - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        elif delay < -period:  # fell behind (a busy machine): start the schedule again from now, do not burst
            start = time.monotonic() - tick * period
