"""Which PINGRESP answers the uplink's probe. ROS-free, I/O-free, thread-safe.

Why: the uplink's path meter (bridge/core/path_meter.py) sends PINGREQs as probes on the main connection, and paho
sends its own for the keep-alive. A broker answers PINGREQs in order, so the n-th PINGRESP of a connection answers
its n-th PINGREQ; only a probe's answer is a round trip of that probe (paho's, answered a moment after a probe left
behind a queue, once taught the meter a base round trip of 3 ms on a 40 ms path).

The order matters twice, both found under load, when a thread can be held between two lines:

* a PINGREQ is entered **before** it is queued: on loopback its answer can come (on paho's thread) before the
  sending thread runs its next line; entered after, that answer found no probe, the probe was never answered, the
  meter stopped probing and held the uplink until paho's keep-alive dropped the connection;
* paho marks "waiting for a PINGRESP" (``_ping_t``) after it queued the PINGREQ; an answer that came in between
  leaves that mark set with nothing out, and the keep-alive would drop a healthy connection once probing pauses.
  :meth:`PingLedger.none_waiting` tells the sender to clear it.
"""

from __future__ import annotations

import threading
from collections import deque


class PingLedger:
    """The PINGREQs of one connection in order, and which of them are probes."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._sent = 0  # PINGREQs entered on this connection
        self._answered = 0  # PINGRESPs received on it
        self._probes: deque[int] = deque()  # the numbers of the probes not yet answered, oldest first

    def sending(self, probe: bool) -> int:
        """A PINGREQ is about to be queued (call before queuing it): its number on this connection."""
        with self._lock:
            self._sent += 1
            if probe:
                self._probes.append(self._sent)
            return self._sent

    def not_sent(self, number: int) -> None:
        """The PINGREQ entered as ``number`` was not queued after all: no answer will come for it."""
        with self._lock:
            if number == self._sent:
                self._sent -= 1
                if self._probes and self._probes[-1] == number:
                    self._probes.pop()

    def answer(self) -> bool:
        """A PINGRESP arrived: True when it answers a probe."""
        with self._lock:
            self._answered += 1
            while self._probes and self._probes[0] < self._answered:
                self._probes.popleft()  # (not answered: cannot happen with a broker that answers in order)
            if self._probes and self._probes[0] == self._answered:
                self._probes.popleft()
                return True
            return False

    def none_waiting(self) -> bool:
        """Every PINGREQ entered has been answered (a probe's answer may come before its sender's next line)."""
        with self._lock:
            return self._answered >= self._sent

    def reset(self) -> None:
        """A new connection: nothing sent on the old one will be answered."""
        with self._lock:
            self._sent = self._answered = 0
            self._probes.clear()
