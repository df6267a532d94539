"""Measuring what an attack costs a broker: event-loop stalls and memory, from outside the process.

* :class:`StallMeter` is an honest client that publishes QoS 1 messages back to back and
  times each PUBACK. A broker whose event loop is held by one connection answers late, so
  the longest round trip during an attack is the stall every other client -- a bridge's
  heartbeat, an operator's stop -- suffered.
* :func:`rss_bytes` reads a process's resident memory from /proc.
"""

from __future__ import annotations

import math
import threading
import time

from tests.support.waits import wait_until

from .broker_client import Probe
from .procs import DEMO_PASSWORDS


def rss_bytes(pid: int) -> int:
    with open(f"/proc/{pid}/status") as status:
        for line in status:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError(f"no VmRSS for pid {pid}")


class StallMeter:
    """Round trips of QoS 1 PUBLISH -> PUBACK from turtle1 to a topic nobody reads, in a thread."""

    def __init__(self, port: int, login: str = "turtle1", topic: str = "roslink/turtle1/state/stall_meter",
                 period: float = 0.01) -> None:
        self.probe = Probe(port, login, DEMO_PASSWORDS[login], f"stall-meter-{time.monotonic_ns()}")
        self.topic, self.period = topic, period
        self.samples: list[float] = []
        self.failed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stall-meter", daemon=True)

    def __enter__(self) -> StallMeter:
        assert self.probe.connect() == 0, "stall meter refused"
        self._thread.start()
        try:
            self.keep_measuring(0.3)  # a baseline before the attack starts
        except BaseException:
            self.__exit__()
            raise
        return self

    def keep_measuring(self, seconds: float, stalled: float = 1.0, timeout: float = 30.0) -> None:
        """Until the round trips of at least ``seconds`` more are measured: one per ``period`` at most, so as many
        as ``seconds`` / ``period`` never take less than ``seconds``, and a busy machine's slower meter still takes
        them all. Ends early on a round trip of ``stalled`` s: the stall is measured already."""
        goal = len(self.samples) + math.ceil(seconds / self.period) + 1  # + 1: the round trip under way now
        wait_until(f"{seconds:g} s of honest round trips", lambda: len(self.samples) >= goal or self.worst >= stalled,
                   timeout=timeout)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(15)
        self.probe.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            started = time.monotonic()
            info = self.probe.client.publish(self.topic, b"x", qos=1)
            try:
                info.wait_for_publish(10)
            except (RuntimeError, ValueError):
                self.failed += 1
            if info.is_published():
                self.samples.append(time.monotonic() - started)
            else:
                self.failed += 1
                self.samples.append(10.0)
            self._stop.wait(self.period)

    @property
    def p99(self) -> float:
        """The 99th percentile round trip (s): what an honest client meets, one scheduler hiccup of a busy machine
        aside."""
        ordered = sorted(self.samples)
        return ordered[min(len(ordered) - 1, int(len(ordered) * 0.99))] if ordered else 0.0

    @property
    def worst(self) -> float:
        """The longest round trip seen (s)."""
        return max(self.samples, default=0.0)
