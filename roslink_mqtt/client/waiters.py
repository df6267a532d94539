"""Callers waiting for a robot to refuse what they sent, so a refusal wakes them instead of a timeout.

A command sent with ``check=`` and a control request wait a little for the robot's error report on
``to/<user>/error`` (naming the topic they sent on and, for commands, the sequence number). The report arrives on
paho's thread; :meth:`ErrorWaiters.deliver` hands it to whoever waits for it.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

from .errors import RobotError


@dataclass
class Waiter:
    """One caller's wait: set when a matching report came (``errors`` holds it)."""

    topic: str
    sequence: int | None = None  # None: any report on the topic
    done: threading.Event = field(default_factory=threading.Event)
    errors: list[RobotError] = field(default_factory=list)

    def wait(self, timeout: float) -> RobotError | None:
        """The refusal, if one came within ``timeout`` s."""
        return self.errors[0] if self.done.wait(timeout) and self.errors else None


class ErrorWaiters:
    """The callers waiting now (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waiting: list[Waiter] = []

    @contextmanager
    def waiting(self, topic: str, sequence: int | None = None,
                done: threading.Event | None = None) -> Iterator[Waiter]:
        """Wait for a refusal of what is sent on ``topic`` while the block runs (enter before sending); ``done``:
        the event a refusal sets (one the caller also sets for another outcome)."""
        waiter = Waiter(topic, sequence) if done is None else Waiter(topic, sequence, done)
        with self._lock:
            self._waiting.append(waiter)
        try:
            yield waiter
        finally:
            with self._lock:
                self._waiting.remove(waiter)

    def deliver(self, error: RobotError) -> bool:
        """Hand ``error`` to every caller waiting for it; whether any was."""
        awaited = False
        with self._lock:
            for waiter in self._waiting:
                if error.topic == waiter.topic and (waiter.sequence is None or
                                                    error.sequence_number in (None, waiter.sequence)):
                    waiter.errors.append(error)
                    waiter.done.set()
                    awaited = True
        return awaited
