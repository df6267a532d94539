"""``state/link``: what the robot's uplink carries, so people see why a stream is slow (docs/protocol.md, "Link").

The bridge publishes it retained every few seconds (:data:`LINK_REPORT_PERIOD`): the uplink's measured rate, and per
state stream the rate it is offered (after ``max_rate``), the rate actually sent, and how many messages a newer one
superseded (latest wins) or were dropped. ``roslink-mqtt info`` and ``monitor`` show it ("range_finder_data 1.2 Hz of
5 — link 240 kbit/s"). A client reads it leniently (unknown fields ignored), so the bridge may grow it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..topics import TopicTree
from .body import BodyField, Boolean, Choice, Integer, NestedBody, Nullable, Number, Obj, body_of, read, write

LINK = "link"  # the state name: roslink/<robot>/state/link
LINK_REPORT_PERIOD = 2.0  # s between reports
PRIORITY_NAMES = ("control", "motion", "state", "bulk")
UPLINK_MODES = ("scheduled", "fifo")  # robots.yaml bridge.uplink
_DOC = TopicTree()


@dataclass(frozen=True, slots=True)
class StreamReport(NestedBody):
    """One state stream over the last period."""

    priority: str
    latest_only: bool
    offered_hz: float  # what the rule handed to the uplink (after max_rate)
    sent_hz: float
    superseded: int = 0  # in the period: replaced by a newer message before they could leave
    dropped: int = 0  # in the period: ordered streams over their bound, or offered while the broker was away
    max_rate: float | None = None  # the rule's max_rate (Hz), if any
    kbit_s: float = 0.0  # sent

    FIELDS = (  # documented in LinkReport's `streams`
        BodyField("priority", Choice(PRIORITY_NAMES), True, "the stream's priority class"),
        BodyField("latest_only", Boolean(), True, "a newer message replaces one that waits"),
        BodyField("offered_hz", Number(), True, "what the rule produced, after `max_rate`"),
        BodyField("sent_hz", Number(), True, "what left"),
        BodyField("superseded", Integer(0), False, "replaced by a newer one in the period", 0),
        BodyField("dropped", Integer(0), False, "dropped in the period", 0),
        BodyField("kbit_s", Number(), False, "sent", 0.0),
        BodyField("max_rate", Nullable(Number()), False, "the rule's max_rate", None),
    )

    def to_body(self) -> dict[str, Any]:
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, name: str, body: Any) -> StreamReport:
        return cls(**read(cls.FIELDS, body, shape=f"streams.{name}: expected an object", strict=False,
                          what=f"streams.{name}"))


@dataclass(frozen=True, slots=True)
class PathReport(NestedBody):
    """The uplink end to end (bridge/core/path_meter.py): round trips of probes answered through the broker."""

    base_ms: float  # the least round trip lately: the path with empty queues
    rtt_ms: float  # the round trip a message meets now
    queue_ms: float  # rtt − base: what waits in the path, seen or hidden from the robot's socket
    rate_kbit_s: float  # what the path's answers allow
    cuts: int = 0  # times the rate was cut since the bridge started (a queue past the target)
    steering: bool = False  # the path limits the uplink now: a queue the robot's socket does not show was found

    FIELDS = (  # documented in LinkReport's `path`
        BodyField("base_ms", Number(), True, "the least round trip lately"),
        BodyField("rtt_ms", Number(), True, "the round trip now"),
        BodyField("queue_ms", Number(), True, "rtt − base"),
        BodyField("rate_kbit_s", Number(), True, "the path's rate"),
        BodyField("cuts", Integer(0), False, "rate cuts so far", 0),
        BodyField("steering", Boolean(), False, "true: a queue hidden from the robot's socket was found lately, and "
                  "the path's rate limits the uplink", False),
    )

    def to_body(self) -> dict[str, Any]:
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, body: Any) -> PathReport:
        return cls(**read(cls.FIELDS, body, shape="path: expected an object", strict=False, what="path"))


@dataclass(frozen=True, slots=True)
class LinkReport:
    """Retained on ``state/link`` by the bridge: its uplink over the last period (read by every granted user)."""

    mode: str  # bridge.uplink: scheduled or fifo
    rate_kbit_s: float  # the uplink's estimated rate
    measured: bool  # the estimate was measured on a full link (false: a lower bound, the link had room)
    budget_bytes: int
    rtt_ms: float
    period: float  # s the rates and counts cover
    streams: dict[str, StreamReport] = field(default_factory=dict)
    path: PathReport | None = None  # None until the path's probes are answered (and with `uplink: fifo`)

    FIELDS = (
        BodyField("mode", Choice(UPLINK_MODES), True, "the bridge's `uplink` setting"),
        BodyField("rate_kbit_s", Number(), True, "the uplink's estimated rate, kbit/s (all the bridge's "
                                                 "connections)"),
        BodyField("measured", Boolean(), True, "true: measured while the link was full (its capacity); false: the "
                                               "link had room, so the rate is at least this"),
        BodyField("budget_bytes", Integer(), True, "bytes the bridge lets wait in the network (rate × (round trip "
                                                   "+ `uplink_target_delay`))"),
        BodyField("rtt_ms", Number(), True, "the least round trip the kernel measured to the broker, ms"),
        BodyField("period", Number(), True, "seconds the rates and counts below cover"),
        BodyField("streams", Obj(), True, "per state name: `priority`, `latest_only`, `offered_hz` (what the "
                                          "rule produced, after `max_rate`), `sent_hz`, `superseded` and "
                                          "`dropped` (counts in the period), `kbit_s` sent, and `max_rate` "
                                          "when the rule has one", {}),
        BodyField("path", Nullable(Obj()), False, "the uplink end to end, from probes the broker answers (PINGREQ → "
                                                  "PINGRESP): `base_ms` (the least round trip lately), `rtt_ms` (now), "
                                                  "`queue_ms` (rtt − base: what waits in the path, also behind hops "
                                                  "that hide it from the robot), `rate_kbit_s` (what the path "
                                                  "allows), `cuts` (rate cuts so far) and `steering` (true: a queue "
                                                  "the robot's socket does not show was found lately, and the path's "
                                                  "rate limits the uplink); absent before the first answer", None),
    )
    QOS = 0  # a snapshot, replaced every period
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> LinkReport:
        got = read(cls.FIELDS, data, shape='expected a JSON object {"mode": "scheduled", "rate_kbit_s": 240, …}',
                   strict=False, what="link report")
        got["streams"] = {str(n): StreamReport.from_body(str(n), s) for n, s in got["streams"].items()}
        if got.get("path") is not None:
            got["path"] = PathReport.from_body(got["path"])
        return cls(**got)

    def summary(self) -> str:
        """One line for people: ``link 240 kbit/s — range_finder_data 1.2 Hz of 5 (14 superseded)``."""
        parts = []
        for name, s in self.streams.items():
            if s.sent_hz + 0.05 < s.offered_hz or s.dropped:
                text = f"{name} {s.sent_hz:.1f} Hz of {s.offered_hz:.1f}"
                losses = [f"{n} {what}" for n, what in ((s.superseded, "superseded"), (s.dropped, "dropped")) if n]
                parts.append(text + (f" ({', '.join(losses)})" if losses else ""))
        # unmeasured: the link never filled, so the rate is only what was sent (on loopback: not a capacity)
        head = (f"link {self.rate_kbit_s:.0f} kbit/s" if self.measured or self.hidden else
                f"link never full ({self.rate_kbit_s:.0f} kbit/s sent; capacity not measured)")
        if self.hidden and self.path is not None:
            head += (f" (its queue hidden beyond the robot: {self.path.queue_ms:.0f} ms; round trip "
                     f"{self.path.rtt_ms:.0f} ms, base {self.path.base_ms:.0f} ms)")
        return head + (" — " + ", ".join(parts) if parts else " — every stream at its rate")

    @property
    def hidden(self) -> bool:
        """A queue the robot's socket does not show was found lately (a hop that acknowledges at once): the
        path's rate steers the uplink."""
        return self.path is not None and self.path.steering


LINK_BODIES: tuple[tuple[str, str, type], ...] = (
    ("link report", f"`{_DOC.state('<robot>', LINK)}`", LinkReport),
)
