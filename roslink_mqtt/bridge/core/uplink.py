"""What leaves the robot next on a thin uplink: priority classes, latest-wins slots, a byte budget. ROS-free, I/O-free.

A robot's uplink is a few hundred kbit/s shared by everything the bridge sends. Handed to the network first in,
first out, a telemetry stream that needs more than the link carries piles up in the socket's send buffer
(megabytes: seconds to minutes of stale data) and every newer pose, heartbeat and acknowledgement waits behind
it. So the bridge keeps what it has not yet sent *here*, where it can still choose:

* **latest wins**: a state stream keeps one slot; a newer message replaces the waiting one (counted as
  superseded) and keeps its place in line. A superseded pose is never sent.
* **ordered streams** (retained or QoS 1 rules unless they say ``latest_only: true``) queue every message in
  order; a queue that outgrows its bound loses its oldest, counted (``state/link`` reports it), never silently.
* **priority classes**: control (sent at once, never queued here) > motion > state > bulk. Within a class,
  streams take turns (the one waiting longest goes first).
* **a budget** (:class:`LinkMeter`): the link holds at most what it carries in ``target_delay`` beyond its
  round trip; the rest waits here. It follows the rate the kernel says was delivered, so on a fast link the
  budget is never reached and every message goes out at once, as before.

The I/O side (:mod:`.uplink_sender`) walks :meth:`UplinkScheduler.ready` and takes the next message of a stream
(:meth:`~UplinkScheduler.take_from`) whenever that stream's connection has room: the bytes handed to the network
and not yet seen delivered are under :attr:`LinkMeter.budget`, and a paced lane is within its allowance.
"""

from __future__ import annotations

from collections import OrderedDict, deque
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

from ...config import Priority

MAX_ORDERED = 256  # messages an ordered stream keeps waiting before it loses its oldest


@dataclass(slots=True)
class Outgoing:
    """One MQTT message waiting for the link."""

    topic: str
    payload: bytes
    qos: int
    retain: bool
    queued_at: float

    @property
    def size(self) -> int:
        """Bytes on the wire: fixed header, topic, packet id (QoS > 0) and payload."""
        return wire_size(self.topic, self.payload, self.qos)


def wire_size(topic: str, payload: bytes, qos: int) -> int:
    """Bytes of a PUBLISH on the wire: fixed header, topic, packet id (QoS > 0) and payload."""
    body = 2 + len(topic) + (2 if qos else 0) + len(payload)
    return 1 + (1 if body < 128 else 2 if body < 16_384 else 3 if body < 2_097_152 else 4) + body


@dataclass(slots=True)
class Stream:
    """One topic's place in the scheduler, and what happened to its messages (``state/link`` reports these)."""

    name: str
    priority: Priority
    latest_only: bool
    offered: int = 0
    sent: int = 0
    superseded: int = 0  # replaced in their slot by a newer message (latest wins)
    dropped: int = 0  # ordered streams only: lost to the queue bound, or while the broker was away
    bytes_sent: int = 0
    waiting: deque[Outgoing] = field(default_factory=deque)


class UplinkScheduler:
    """Slots and queues of the streams that wait for the link; not thread-safe (the link holds a lock)."""

    def __init__(self, max_ordered: int = MAX_ORDERED) -> None:
        self.max_ordered = max_ordered
        self.streams: dict[str, Stream] = {}
        # per class, the streams with something waiting, longest-waiting first
        self._ready: list[OrderedDict[str, Stream]] = [OrderedDict() for _ in Priority]
        self.waiting_bytes = 0

    def stream(self, name: str, priority: Priority, latest_only: bool) -> Stream:
        """The stream called ``name`` (usually its topic), created on first use."""
        s = self.streams.get(name)
        if s is None:
            s = self.streams[name] = Stream(name, priority, latest_only)
        return s

    def __bool__(self) -> bool:
        return any(self._ready)

    def head(self, skip: Collection[Priority] = ()) -> Priority | None:
        """The class of the message that must leave next (the highest class waiting, but none of ``skip``)."""
        for priority, ready in enumerate(self._ready):
            if ready and priority not in skip:
                return Priority(priority)
        return None

    def has_waiting(self, below: int | None = None) -> bool:
        """Anything waiting (of a class served before ``below``, when given)."""
        classes = self._ready if below is None else self._ready[:below]
        return any(classes)

    def offer(self, stream: Stream, message: Outgoing) -> bool:
        """Queue ``message``; True when it replaced a waiting one (latest wins) or pushed out the oldest."""
        stream.offered += 1
        waiting = stream.waiting
        replaced = False
        if waiting and stream.latest_only:
            old = waiting.pop()
            self.waiting_bytes -= len(old.payload)
            stream.superseded += 1
            replaced = True
        elif len(waiting) >= self.max_ordered:
            old = waiting.popleft()
            self.waiting_bytes -= len(old.payload)
            stream.dropped += 1
            replaced = True
        waiting.append(message)
        self.waiting_bytes += len(message.payload)
        ready = self._ready[stream.priority]
        if stream.name not in ready:
            ready[stream.name] = stream  # a replaced slot keeps its place in line
        return replaced

    def take(self, below: Priority | None = None, only: Priority | None = None) -> tuple[Stream, Outgoing] | None:
        """The next message for the link: the highest class first, streams of a class in turn (of a class served
        before ``below``, or of class ``only``, when given)."""
        for priority, ready in enumerate(self._ready):
            if below is not None and priority >= below:
                return None
            if not ready or (only is not None and priority != only):
                continue
            name, stream = next(iter(ready.items()))
            message = stream.waiting.popleft()
            self.waiting_bytes -= len(message.payload)
            del ready[name]
            if stream.waiting:
                ready[name] = stream  # its next message waits behind the other streams of the class
            stream.sent += 1
            stream.bytes_sent += message.size
            return stream, message
        return None

    def ready(self) -> list[Stream]:
        """The streams with something waiting, in the order they are served: highest class first, then the one
        waiting longest."""
        return [stream for ready in self._ready for stream in ready.values()]

    def take_from(self, stream: Stream) -> Outgoing:
        """The oldest message of ``stream`` (which must have one); the stream goes behind the others of its class."""
        ready = self._ready[stream.priority]
        message = stream.waiting.popleft()
        self.waiting_bytes -= len(message.payload)
        del ready[stream.name]
        if stream.waiting:
            ready[stream.name] = stream
        stream.sent += 1
        stream.bytes_sent += message.size
        return message

    def drop(self, stream: Stream) -> int:
        """Drop what ``stream`` has waiting (its connection went); ordered streams count it as dropped."""
        count = len(stream.waiting)
        if not stream.latest_only:
            stream.dropped += count
        self.waiting_bytes -= sum(len(m.payload) for m in stream.waiting)
        stream.waiting.clear()
        self._ready[stream.priority].pop(stream.name, None)
        return count

    def drop_all(self, priority: Priority | None = None) -> int:
        """The broker is gone: waiting state is stale by the time it returns (never replayed). Returns how many.

        ``priority``: only that class's (its connection is the one that went)."""
        dropped = 0
        for p, ready in enumerate(self._ready):
            if priority is not None and p != priority:
                continue
            for stream in ready.values():
                dropped += len(stream.waiting)
                if not stream.latest_only:
                    stream.dropped += len(stream.waiting)
                self.waiting_bytes -= sum(len(m.payload) for m in stream.waiting)
                stream.waiting.clear()
            ready.clear()
        return dropped


# -- the budget --------------------------------------------------------------------------------------------
TARGET_DELAY = 0.1  # s of data the bridge lets wait in the network beyond one round trip: the freshness cost
MIN_BUDGET = 1500  # bytes: one full segment, however thin the link
MAX_BUDGET = 8 << 20
INITIAL_RATE = 125_000.0  # bytes/s assumed before the first measurement (1 Mbit/s): corrected within a window
WINDOW = 0.25  # s between rate measurements
MIN_RATE = 1_000.0  # bytes/s (8 kbit/s): the estimate never falls below it, so the budget always reopens
PROBE = 1.25  # the lanes together may offer this much more than the estimate: how a faster link is found


@dataclass(slots=True)
class LinkMeter:
    """The uplink's rate, from the bytes the kernel reports delivered on each lane, and what it implies.

    A window in which bytes waited in the network at every look (the link never idled) measures the link's
    capacity: the estimate follows it, down as well as up. Any other window only proves a lower bound: the
    estimate never falls because of it (a robot that sends little does not talk its link down) but rises to what
    was delivered.

    * ``budget`` = rate × (round trip + ``target_delay``): enough to keep the link busy, little enough that a new
      message never waits long behind old ones.
    * ``allowance(i)``: the rate lane ``i`` may hand over, = PROBE × rate − what the lanes before it need (the
      larger of what they delivered and what was offered to them; never below MIN_RATE), shared max-min with the
      busy lanes of its own tier (a peer that needs less than an equal share leaves the rest to the others). The
      state lane gets what control and motion leave, the bulk lane what state leaves too; offering a little more
      than the estimate (PROBE) is what lets the estimate find a faster link.
    """

    rate: float = INITIAL_RATE  # bytes/s
    target_delay: float = TARGET_DELAY  # s (robots.yaml bridge.uplink_target_delay)
    min_rtt: float = 0.0  # s, as the kernel measured it
    measured: bool = False  # a capacity measurement has been made
    full: bool = True  # the last window found bytes waiting in the network at every look (False: the link had room)
    lane_rates: list[float] = field(default_factory=list)  # bytes/s each lane delivered in the last window
    lane_demand: list[float] = field(default_factory=list)  # bytes/s offered to each lane in the last window
    _since: float | None = None
    _acked: tuple[int, ...] = ()
    _offered: tuple[int, ...] = ()
    _limited: bool = True  # every sample of the window found bytes waiting in the network

    @property
    def budget(self) -> int:
        return int(min(MAX_BUDGET, max(MIN_BUDGET, self.rate * (self.min_rtt + self.target_delay))))

    def allowance(self, lane: int, tiers: Sequence[int] | None = None, rate: float | None = None,
                  probe: float = PROBE, wants: Sequence[float] = ()) -> float:
        """Bytes/s lane ``lane`` may hand over: what the lanes of earlier tiers (``tiers[i]`` is lane i's; by
        default each lane its own tier) need, taken from ``probe`` × rate, shared by the busy lanes of its tier
        (``rate``: the uplink's, when something other than this meter limits it; ``probe``: 1 where another
        controller finds a faster link, as the path meter does by its own answers; ``wants[i]``: bytes/s lane i
        would send if it had room, when it says so, as a video stream does: it encodes only when its lane has room,
        so what it was offered understates its need while other lanes take the room first)."""
        tiers = tiers if tiers is not None else range(len(self.lane_rates))
        rates = self.lane_rates + [0.0] * (len(tiers) - len(self.lane_rates))
        demand = self.lane_demand + [0.0] * (len(tiers) - len(self.lane_demand))
        demand = [max(d, wants[i]) if i < len(wants) else d for i, d in enumerate(demand)]
        mine = tiers[lane] if lane < len(tiers) else lane
        need = sum(max(rates[i], demand[i]) for i, tier in enumerate(tiers) if tier < mine)
        peers = sorted(max(rates[i], demand[i]) for i, tier in enumerate(tiers)
                       if tier == mine and i != lane and demand[i] > 0)
        left = probe * (self.rate if rate is None else rate) - need
        # max-min among the busy lanes of the tier, this one asking for all it can get: a peer that needs less
        # than an equal share gets what it needs, the rest is shared (a camera beside a 5 Hz scan gets all the
        # scan leaves, not half the link while the scan uses a third)
        for count, wanted in zip(range(len(peers) + 1, 1, -1), peers, strict=True):
            left -= min(wanted, left / count)
        return max(MIN_RATE, left)

    def sample(self, now: float, acked: tuple[int, ...], limited: bool, min_rtt: float | None = None,
               offered: tuple[int, ...] = ()) -> float | None:
        """Feed each lane's delivered-bytes counter (monotonic within one connection), whether bytes wait in the
        network now (``limited``: the link is busy) and each lane's offered-bytes counter; the window's total
        rate when a window closed, else None."""
        if min_rtt is not None:
            self.min_rtt = min_rtt
        if (self._since is None or len(acked) != len(self._acked)
                or any(a < b for a, b in zip(acked, self._acked, strict=True))):  # a new connection's counter
            self._since, self._acked, self._offered, self._limited = now, acked, offered, limited
            return None
        self._limited = self._limited and limited
        elapsed = now - self._since
        if elapsed < WINDOW:
            return None
        self.lane_rates = [(a - b) / elapsed for a, b in zip(acked, self._acked, strict=True)]
        if len(offered) == len(self._offered):
            self.lane_demand = [(a - b) / elapsed for a, b in zip(offered, self._offered, strict=True)]
        delivered = sum(self.lane_rates)
        self.full = self._limited
        if self._limited:
            self.rate = delivered if not self.measured else 0.5 * self.rate + 0.5 * delivered
            self.rate = max(self.rate, MIN_RATE)
            self.measured = True
        elif delivered > self.rate:
            self.rate = delivered
        self._since, self._acked, self._offered, self._limited = now, acked, offered, True
        return delivered

    def reset(self) -> None:
        """A new connection: its counter starts again (the rate learnt so far is kept as the first guess)."""
        self._since, self._acked, self._offered, self._limited = None, (), (), True
