"""How many messages a second one of the bridge's connections reads: the viewers' connection, bounded.

Why: the bridge reads viewers' traffic (their requests and presence) on a connection of its own, so nothing a
viewer sends queues in front of an operator's command in one TCP stream. But every message costs the bridge
Python time on that connection's thread, and the threads share one interpreter: a viewer flooding parameter
reads through a broker that does not pace him (Mosquitto: 60,000 in one second) kept the bridge so busy that
alice's twists, on their own connection, reached ROS up to 0.47 s late and the robot's link check fired. Reading
the viewers' connection at a bounded rate makes the flood's cost the broker's: the bridge's socket fills, TCP
pushes back, and the bridge's time goes to what it reads, at most ``rate`` messages a second.

A token bucket (``rate`` a second, bursts of BURST_TIME of it, at least MIN_BURST): the reader asks before each
message and sleeps what it is told. Pure logic: the link (bridge/core/link.py) sleeps.
"""

from __future__ import annotations

BURST_TIME = 0.1  # s of the rate that may be read at once (after a quiet spell)
MIN_BURST = 20  # messages: a viewer's few requests and presence never wait


class Intake:
    """At most ``rate`` messages a second, on average, through one reader."""

    def __init__(self, rate: float, what: str = "messages") -> None:
        """``what``: whose messages, for the log line."""
        if rate <= 0:
            raise ValueError(f"an intake rate must be positive, got {rate}")
        self.rate, self.what = rate, what
        self.burst = max(float(MIN_BURST), rate * BURST_TIME)
        self._tokens = self.burst
        self._at: float | None = None
        self.waited = 0.0  # s the reader was told to wait, in all (the log says when it starts)

    def wait(self, now: float) -> float:
        """Take one message's token: the seconds to wait before handling it (0.0: at once). A token not there yet
        is owed, so a reader that sleeps what it is told reads at ``rate`` exactly."""
        if self._at is not None:
            self._tokens = min(self.burst, self._tokens + self.rate * max(0.0, now - self._at))
        self._at = now
        self._tokens -= 1.0
        if self._tokens >= 0.0:
            return 0.0
        delay = -self._tokens / self.rate
        self.waited += delay
        return delay
