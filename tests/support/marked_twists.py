"""An operator's twist stream whose every command says, on arrival at ``/cmd_vel``, which one it was.

Each twist carries its sequence number in ``az`` (milli-rad/s), so a ``/cmd_vel`` watcher (tests/support/ros.py)
tells which command reached the robot and how long it took — what the attack tests measure while something
else floods the broker or the bridge.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import orjson


def nonzero(m: Any) -> bool:
    """A Twist that moves (the bridge's stops are all zeros)."""
    return any((m.linear.x, m.linear.y, m.linear.z, m.angular.x, m.angular.y, m.angular.z))


@dataclass(frozen=True)
class Delays:
    """Delays of the commands sent in a window, seconds, sorted; ``sent``: how many were sent in it."""

    delivered: list[float]
    sent: int

    def quantile(self, q: float) -> float:
        return self.delivered[int(q * (len(self.delivered) - 1))] if self.delivered else float("inf")

    @property
    def worst(self) -> float:
        return self.delivered[-1] if self.delivered else float("inf")


class MarkedTwists:
    """Publish ``lx`` twists from ``client`` (a tests.support.mqtt_client.TestClient) every ``period`` s."""

    def __init__(self, client: Any, topic: str, lx: float, period: float) -> None:
        self.client, self.topic, self.lx, self.period = client, topic, lx, period
        self.sent: dict[int, float] = {}  # sequence -> time.monotonic() at publish
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        seq = 0
        while not self._stop.is_set():
            seq += 1
            self.sent[seq] = time.monotonic()
            self.client.client.publish(self.topic, orjson.dumps({"message_id": 100, "sequence_number": seq,
                                                                 "payload": {"lx": self.lx, "az": seq / 1000}}),
                                       qos=0)
            self._stop.wait(self.period)

    def start(self) -> MarkedTwists:
        self._thread.start()
        return self

    def stop(self) -> int:
        """Stop streaming; the last sequence number sent."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        return max(self.sent, default=0)

    def delays(self, seen: list[tuple[float, Any]], start: float, end: float) -> Delays:
        """Delays of the commands sent in [start, end], from ``seen`` ((arrival, Twist) pairs at /cmd_vel)."""
        first: dict[int, float] = {}
        for at, m in seen:
            seq = round(m.angular.z * 1000)
            if nonzero(m) and seq in self.sent and seq not in first:
                first[seq] = at - self.sent[seq]
        window = [s for s, t in self.sent.items() if start <= t <= end]
        return Delays(sorted(first[s] for s in window if s in first), len(window))
