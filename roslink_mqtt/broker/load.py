"""When the embedded broker falls behind: what it sheds, and what it tells the admin.

A broker that cannot keep up delays everything together: a twist waits behind a backlog of poses, a heartbeat
arrives seconds late and a robot's stale detection fires. Issue 48 measured that (200 robots, p50 10.7 s, nobody
told). What can be shed without losing anything a client relies on is *superseded state*: a robot's pose 50 ms
old is worth nothing once the next one is there (the broker already keeps latest-wins slots for slow viewers,
hardened fix 26). Commands, calls, heartbeats, presence, acknowledgements, retained messages and anything at QoS 1
or 2 are never shed.

:class:`LoadMonitor` reads how late the event loop runs a probe scheduled every :data:`PROBE` seconds: later than
:data:`LAG_ENTER` :data:`LATE_PROBES` times in a row (a third of a second or more), the broker is overloaded; under
:data:`LAG_LEAVE` for :data:`CALM_FOR`, it keeps up again.
While overloaded, :class:`Shedder` lets one message per state topic through every :data:`STATE_EVERY` seconds
(the newest that arrives then; the rest were superseded). :class:`Outgrown` says, with numbers, when the fleet
spends more than half of a minute overloaded: one process is too small, Mosquitto or the RabbitMQ cluster are the
way on (docs/scaling.md). Pure logic: the caller passes the clock.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

PROBE = 0.02  # s between probes of the event loop
LAG_ENTER = 0.05  # s: probes this late ...
LATE_PROBES = 5  # ... this many in a row mean the broker is behind (one late probe is a pause: GC, a busy core)
LAG_LEAVE = 0.005  # s: probes at most this late ...
CALM_FOR = 1.0  # ... for this long mean it keeps up again
STATE_EVERY = 0.2  # s: while overloaded, each state topic is fanned out at most this often (5 Hz)
MAX_TOPICS = 100_000  # state topics remembered while shedding (more: forgotten, a message more goes through)
OUTGROWN_WINDOW = 60.0  # s over which the share of time overloaded is judged
OUTGROWN_SHARE = 0.5  # overloaded for more than this share of the window: the fleet outgrew one process
OUTGROWN_REPEAT = 600.0  # s between two such warnings


class LoadMonitor:
    """Overloaded or not, from the lateness of the loop's probes, with hysteresis."""

    __slots__ = ("overloaded", "lag", "worst", "since", "_calm_since", "_late")

    def __init__(self) -> None:
        self.overloaded = False
        self.lag = 0.0  # s: the last probe's lateness
        self.worst = 0.0  # s: the worst lateness since the last :meth:`take_worst`
        self.since = 0.0  # monotonic: when the current state began
        self._calm_since: float | None = None
        self._late = 0  # late probes in a row

    def observe(self, lag: float, now: float) -> bool:
        """A probe ran ``lag`` s late at ``now``; True when that changed :attr:`overloaded`."""
        self.lag, self.worst = lag, max(self.worst, lag)
        if not self.overloaded:
            self._late = self._late + 1 if lag > LAG_ENTER else 0
            if self._late >= LATE_PROBES:
                self.overloaded, self.since, self._calm_since, self._late = True, now, None, 0
                return True
            return False
        if lag > LAG_LEAVE:
            self._calm_since = None
            return False
        if self._calm_since is None:
            self._calm_since = now
        if now - self._calm_since >= CALM_FOR:
            self.overloaded, self.since, self._calm_since = False, now, None
            return True
        return False

    def take_worst(self) -> float:
        worst, self.worst = self.worst, self.lag
        return worst


class Shedder:
    """While overloaded: one message per state topic every :data:`STATE_EVERY` s goes through."""

    __slots__ = ("every", "_last")

    def __init__(self, every: float = STATE_EVERY) -> None:
        self.every = every
        self._last: dict[str, float] = {}

    def admit(self, topic: str, now: float) -> bool:
        last = self._last.get(topic)
        if last is not None and now - last < self.every:
            return False
        if last is None and len(self._last) >= MAX_TOPICS:
            self._last.clear()
        self._last[topic] = now
        return True

    def clear(self) -> None:
        self._last.clear()


# The retained ``$SYS/broker/load`` status (administrators only): field -> meaning (docs/protocol.md lists them)
LOAD_FIELDS = {
    "overloaded": "true while the broker sheds superseded robot state because its event loop runs late",
    "for_s": "seconds since it became overloaded, or since it keeps up again",
    "lag_ms": "the worst lateness of the event loop since the last status, ms",
    "received_per_s": "PUBLISH packets a second from clients since the last status",
    "shed_per_s": "superseded state messages shed a second since the last status",
    "shed_total": "superseded state messages shed since the broker started",
}


def load_status(overloaded: bool, for_s: float, lag: float, rates: Rates, shed_total: int) -> dict[str, object]:
    """The body of ``$SYS/broker/load`` (:data:`LOAD_FIELDS`)."""
    return {"overloaded": overloaded, "for_s": round(for_s, 1), "lag_ms": round(1000 * lag, 1),
            "received_per_s": round(rates.received), "shed_per_s": round(rates.shed), "shed_total": shed_total}


@dataclass
class Rates:
    """Messages a second over the last status period: received from clients, and state shed."""

    received: float = 0.0
    shed: float = 0.0


class Counter:
    """Counts received and shed messages; :meth:`rates` turns them into per-second rates once per period."""

    __slots__ = ("received", "shed", "total_shed", "_at")

    def __init__(self, now: float) -> None:
        self.received = self.shed = self.total_shed = 0
        self._at = now

    def rates(self, now: float) -> Rates:
        elapsed = max(now - self._at, 1e-9)
        out = Rates(self.received / elapsed, self.shed / elapsed)
        self.received = self.shed = 0
        self._at = now
        return out


class Outgrown:
    """Whether the fleet spent more than :data:`OUTGROWN_SHARE` of the last :data:`OUTGROWN_WINDOW` overloaded;
    says so at most every :data:`OUTGROWN_REPEAT` s."""

    __slots__ = ("_samples", "_said_at")

    def __init__(self) -> None:
        self._samples: deque[tuple[float, bool]] = deque()
        self._said_at: float | None = None

    def sample(self, now: float, overloaded: bool) -> float | None:
        """Record a status period; the share of the window spent overloaded when it is time to warn, else None."""
        samples = self._samples
        samples.append((now, overloaded))
        while samples and now - samples[0][0] > OUTGROWN_WINDOW:
            samples.popleft()
        if now - samples[0][0] < OUTGROWN_WINDOW * 0.9:
            return None  # not a whole window yet
        share = sum(1 for _t, o in samples if o) / len(samples)
        if share <= OUTGROWN_SHARE or (self._said_at is not None and now - self._said_at < OUTGROWN_REPEAT):
            return None
        self._said_at = now
        return share
