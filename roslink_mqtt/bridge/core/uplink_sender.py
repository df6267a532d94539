"""The bridge's uplink: state streams through :mod:`.uplink`'s scheduler into the MQTT connections, never more
than the link carries soon.

The bytes the bridge has handed over and the link has not yet delivered are paho's unsent packets plus the
socket's unacknowledged bytes (``SIOCOUTQ``: what waits in the send buffer and, on a real modem, in the modem's
queue). While they stay under the budget a message goes straight to paho from the thread that offered it, as
before this module existed (a fast link never notices it); otherwise it waits in its stream's slot and a sender
thread hands the next one over as soon as the link has room, polling every :data:`POLL` while anything waits.

State streams, and each bulk stream, go out on connections of their own (lanes), each with a send buffer about
the size of the budget, one message at a time, paced to what the lanes before them leave: a 7 kB scan takes a
quarter of a second on a 256 kbit/s link and a 4 MB map two minutes; on the main connection every heartbeat,
acknowledgement and pose would wait behind them, while from small buffers on other connections the link
interleaves their packets with the main connection's. A congested main connection holds everything back (nothing
of a lower class overtakes it); a lane that is busy or out of allowance holds back only its own streams.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from ... import netstat
from ...config import Priority
from ...protocol.link import LINK_REPORT_PERIOD, LinkReport, PathReport, StreamReport
from .link import MqttLink
from .pacer import Pacer, install
from .path_meter import PROBE_PERIOD, PathMeter
from .spool import Spool
from .uplink import (
    MAX_BUDGET,
    MIN_BUDGET,
    PROBE,
    TARGET_DELAY,
    LinkMeter,
    Outgoing,
    Stream,
    UplinkScheduler,
    wire_size,
)

log = logging.getLogger("roslink_mqtt.bridge.core.uplink")

POLL = 0.01  # s between looks at the socket while messages wait
WANTS_FOR = 1.0  # s a stream's word on what it wants holds (a video stream says it with every picture it encodes;
# one nobody watches any more says nothing, and must not keep half its tier from the scan)
# bytes/s the path steers from behind a hop, before its answers say more (256 kbit/s: a thin link's queue stays
# short; a fast one is found within a second or two, the rate growing 1.25× per answer while no queue shows)
PATH_START_RATE = 32_000.0
MIN_PACING = 1_000  # bytes/s: the least a paced lane's writes are held to while the path steers (bridge/core/pacer.py;
# the path's own least rate): each paced lane gets its allowance, and several floors of a few kB/s each would
# together overfill a thin link (two lanes at 8 kB/s cut a 128 kbit/s path to 28 kbit/s)


def raw_socket(client: Any) -> socket.socket | None:
    """The TCP socket under a paho client (plain, TLS, or inside the websocket wrapper); None while unconnected."""
    return netstat.raw_socket(client.socket())


kernel_unsent = netstat.unacked
delivered = netstat.delivered


def _log_spool_error(err: OSError) -> None:
    log.error("disk buffer: %s (buffered messages may be lost)", err)


def paho_unsent(client: Any) -> int:
    """Bytes queued inside paho and not yet written to the socket (paho 2.2's ``_out_packet``; pinned)."""
    return sum(p["to_process"] for p in list(client._out_packet))


@dataclass(eq=False)
class Lane:
    """One MQTT connection the uplink sends on (main: control and motion; then state; then one per bulk stream)."""

    link: MqttLink
    index: int  # its place in the order of lanes (main first)
    tier: int  # 0 main (control, motion), 1 state, 2 bulk: a tier gets what the tiers before it leave
    paced: bool  # a small send buffer, one message at a time, and an allowance: never crowds the link for long
    sndbuf: int = 0  # what SO_SNDBUF was last set to
    pacer: Pacer = field(default_factory=Pacer)  # its writes, at its allowance while the path steers
    credit: float = 0.0  # bytes it may still hand over (its allowance accrues here; a message may overdraw it)
    offered: int = 0  # bytes offered to its classes since it was made (its demand, superseded messages included)
    refilled: float = 0.0  # monotonic: when credit last accrued
    acked: int = 0  # its socket's bytes acknowledged at the last look (tcpi_bytes_acked)
    wants: float = 0.0  # bytes/s its stream says it would send if it had room (a video stream's encoder target)
    wanted_at: float = float("-inf")  # monotonic: when it last said so (a stream that stopped saying wants nothing)


class Uplink:
    """Where the rules' state goes: ``offer`` from any thread; a sender thread drains what had to wait.

    ``state_link``: the connection for state streams; ``bulk_links``: one connection per bulk stream (by topic),
    so a 4 MB map that takes a minute to cross never holds up the camera. Streams without one use the lane before
    (bulk → state → main). Each of these lanes is paced: its send buffer is about the budget, it gets its next
    message only once paho has written the last one, and it hands over no more than its allowance (what the tiers
    before it leave, shared by the lanes of its tier), so a 7 kB scan or a 4 MB map never sits in front of a
    heartbeat or a pose; the link interleaves their packets with the main connection's.
    """

    def __init__(self, main: MqttLink, state_link: MqttLink | None = None,
                 bulk_links: Mapping[str, MqttLink] | None = None, *, fifo: bool = False,
                 target_delay: float = TARGET_DELAY, report_topic: str | None = None,
                 state_links: Mapping[str, MqttLink] | None = None) -> None:
        """``fifo``: hand every message to paho at once, on the main connection (robots.yaml ``uplink: fifo``).
        ``report_topic``: where the retained :class:`LinkReport` goes every LINK_REPORT_PERIOD (None: nowhere).
        ``state_links``: state streams with a connection of their own (a video stream of the state class), by topic:
        lanes of the state tier, sharing what motion leaves with the state lane."""
        self.fifo, self.report_topic = fifo, report_topic
        self.main = Lane(main, 0, 0, paced=False)
        self.lanes = [self.main]
        self.state_lane = self.main
        self._bulk_lanes: dict[str, Lane] = {}
        self._state_lanes: dict[str, Lane] = {}
        if not fifo:
            if state_link is not None:
                self.state_lane = self._add_lane(state_link, 1)
            for topic, link in (state_links or {}).items():
                self._state_lanes[topic] = self._add_lane(link, 1)
            for topic, link in (bulk_links or {}).items():
                self._bulk_lanes[topic] = self._add_lane(link, 2)
        self._tiers = tuple(lane.tier for lane in self.lanes)
        main.queue_delay = self.queue_delay
        self.scheduler = UplinkScheduler()
        self.meter = LinkMeter(target_delay=target_delay)
        # the path end to end (a hop may acknowledge at once and hide the queue from the socket): probes on the
        # main connection, answered by the broker (bridge/core/path_meter.py); :meth:`_left` is its byte clock. It
        # steers beside the socket's meter behind a hop, once it finds a queue the sockets do not show, and until
        # its first answer
        self.path = PathMeter(target_delay=target_delay, rate=PATH_START_RATE)
        self.handed = 0  # bytes handed to any of the bridge's connections so far
        self._paced_last = 0  # bytes of the last message handed to a state or bulk lane
        main.on_pong = self._pong
        self.lock = threading.Condition()
        self.not_connected = 0  # messages offered while their connection was down (not kept: never replayed stale)
        self._stopped = False
        self.spool: Spool | None = None  # set by use_spool: the disk buffer of ``buffer: disk`` streams
        self._buffered: set[str] = set()  # those streams
        self.spooled = 0  # messages kept on disk while the broker was away
        self._draining = False  # records wait on disk while connected: poll fast
        self._thread = threading.Thread(target=self._run, name="uplink", daemon=True)
        self._labels: dict[str, tuple[str, float | None]] = {}  # stream → (state name, max_rate)
        self._counts: dict[str, tuple[int, int, int, int, int]] = {}  # stream → its counters at the last report
        self._reported = time.monotonic()

    def queue_delay(self) -> float:
        """Seconds a message handed to the main connection now waits before the broker has it: everything the
        bridge's connections hold in the network, at the measured rate (a modem's queue is first in, first out),
        and the queue the path's probes find beyond it (hidden behind a hop)."""
        with self.lock:
            return self._visible_delay(self._held()) + self.path.queue_delay(time.monotonic())

    def _held(self) -> int:
        """Bytes the robot's own sockets and paho hold ahead of a probe: the queue the robot can see."""
        return paho_unsent(self.main.link.client) + sum(kernel_unsent(raw_socket(lane.link.client))
                                                        for lane in self.lanes)

    def _left(self, held: int | None = None) -> int:
        """Bytes that have left the robot (``held``: :meth:`_held`, if read already): handed over, less what its
        sockets and every lane's paho still hold. The path meter's byte clock: a paced lane writes a large message
        as its pacing lets it, so most of a map waits in paho, and counted as sent it would have made the path
        look four megabytes faster than it is."""
        held = self._held() if held is None else held
        return self.handed - held - sum(paho_unsent(lane.link.client) for lane in self.lanes if lane.paced)

    def _visible_delay(self, held: int) -> float:
        return held / self.rate() if held else 0.0

    # -- the rate -------------------------------------------------------------------------------------------
    def rate(self, now: float | None = None) -> float:
        """Bytes/s the uplink may send: the socket's measurement (:class:`.uplink.LinkMeter`), and no more than
        the path's while the path steers (a queue hidden behind a hop was found: the socket's rate there is the
        hop's, not the link's)."""
        path = self.path
        if not self.fifo and path.measured and path.steering(time.monotonic() if now is None else now):
            return min(self.meter.rate, path.rate)
        return self.meter.rate

    def budget(self) -> int:
        """Bytes the bridge lets wait in its sockets: rate × (the kernel's round trip + target delay)."""
        rate = self.rate()
        if rate == self.meter.rate:
            return self.meter.budget
        return int(min(MAX_BUDGET, max(MIN_BUDGET, rate * (self.meter.min_rtt + self.meter.target_delay))))

    def _path_room(self, now: float) -> int | None:
        """Bytes the path still takes beyond the sockets while it steers (None: it does not; the lock is held)."""
        if self.fifo or not self.path.steering(now):
            return None  # (the sockets are read only when the answer depends on them: this is on every offer)
        return self.path.room(self._left(), 0, now)

    def _pong(self, now: float) -> None:
        """A probe's answer (paho's thread): it may open room for what waits."""
        with self.lock:
            before = self.path.rate, self.path.target, self.path.overused
            self.path.probe_answered(now)
            self._log_cut("an answer", before, now)
            self.lock.notify()

    def _log_cut(self, what: str, before: tuple[float, float, int], now: float) -> None:
        """A debug line when ``what`` made the path cut its rate (``before``: its rate, target and count of cuts
        before; the lock is held)."""
        path, (rate, target, cuts) = self.path, before
        if path.overused != cuts and log.isEnabledFor(logging.DEBUG):
            log.debug("uplink path: queue %.0f ms over its target %.0f ms at %s: rate %.0f -> %.0f B/s",
                      path.queue_delay(now) * 1000, target * 1000, what, rate, path.rate)

    def _probe(self, now: float) -> None:
        """Send the next probe when one is due (the lock is held)."""
        if self.fifo or not self.path.probe_due(now):
            return
        held = self._held()  # read before the probe is queued behind it
        if self.main.link.ping():
            self.path.probe_sent(now, self._left(held), self._visible_delay(held))

    def _add_lane(self, link: MqttLink, tier: int) -> Lane:
        lane = Lane(link, len(self.lanes), tier, paced=True)
        install(link.client, lane.pacer)
        self.lanes.append(lane)
        self._watch_socket(lane)
        return lane

    def lane_of(self, stream: Stream) -> Lane:
        """The connection ``stream`` leaves on."""
        if stream.priority <= Priority.MOTION:
            return self.main
        if stream.priority is Priority.BULK:
            return self._bulk_lanes.get(stream.name, self.state_lane)
        return self._state_lanes.get(stream.name, self.state_lane)

    def _watch_socket(self, lane: Lane) -> None:
        """Size a paced lane's send buffer as soon as its socket exists (TCP_NODELAY stays)."""
        opened = lane.link.client.on_socket_open

        def on_socket_open(client: Any, userdata: Any, sock: Any) -> None:
            if opened is not None:
                opened(client, userdata, sock)
            lane.sndbuf = 0
            self._size_buffer(lane, getattr(sock, "_socket", sock))

        lane.link.client.on_socket_open = on_socket_open

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        with self.lock:
            self._stopped = True
            self.lock.notify()

    def stream(self, name: str, priority: Priority, latest_only: bool, *, label: str | None = None,
               max_rate: float | None = None, buffered: bool = False) -> Stream:
        """The stream of topic ``name``; ``label`` (its state name) and ``max_rate`` are for the link report;
        ``buffered``: kept in the disk buffer while the broker is away (needs :meth:`use_spool`)."""
        with self.lock:
            self._labels[name] = (label or name, max_rate)
            if buffered:
                self._buffered.add(name)
            return self.scheduler.stream(name, priority, latest_only)

    def use_spool(self, spool: Spool) -> None:
        with self.lock:
            self.spool = spool
            self._draining = bool(spool)  # records left from before a restart

    # -- the way in ------------------------------------------------------------------------------------------
    def offer(self, stream: Stream, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        """Send now if the link has room and nothing of this class or above waits; else keep it in its slot."""
        if stream.priority is Priority.CONTROL or self.fifo:
            with self.lock:
                stream.offered += 1
                if not self.main.link.connected.is_set() and self._keep(stream, topic, payload, qos):
                    return
                stream.sent += 1
                stream.bytes_sent += len(payload) + len(topic) + 4
                self.handed += wire_size(topic, payload, qos)
            if self.main.link.publish(topic, payload, qos, retain) is None and not self.main.link.connected.is_set():
                with self.lock:
                    self._keep(stream, topic, payload, qos)  # the connection went just now (buffered streams)
            return
        lane = self.lane_of(stream)
        message = Outgoing(topic, payload, qos, retain, time.monotonic())
        with self.lock:
            lane.offered += message.size
            if not lane.link.connected.is_set():
                stream.offered += 1
                if self._keep(stream, topic, payload, qos):
                    return
                self.not_connected += 1
                if not stream.latest_only:
                    stream.dropped += 1  # an ordered stream lost one: counted (a pose is simply stale)
                return
            self._refill(lane, message.queued_at)
            if not self.scheduler.has_waiting(below=stream.priority + 1) and \
                    self._blocked(lane, 0, message.size) is None:
                # nothing of this class or above waits: straight to paho (a lower class waiting behind a busy
                # lane of its own goes through the sender thread, which knows why that lane waits)
                stream.offered += 1
                stream.sent += 1
                stream.bytes_sent += message.size
                self.handed += message.size
                if lane.paced:
                    lane.credit -= message.size
                    self._paced_last = message.size
                if lane.link.publish(topic, payload, qos, retain) is None and not lane.link.connected.is_set():
                    self._keep(stream, topic, payload, qos)  # the connection went just now (buffered streams)
                return
            self.scheduler.offer(stream, message)
            self.lock.notify()

    def _set_aside(self, stream: Stream) -> None:
        """What ``stream`` has waiting when its connection is gone: a ``buffer: disk`` stream's goes to the disk
        buffer, in order (it is sent after reconnecting); anything else is stale by then and dropped."""
        kept = 0
        if stream.name in self._buffered and self.spool is not None:
            kept = sum(1 for m in list(stream.waiting) if self._keep(stream, m.topic, m.payload, m.qos))
        dropped = self.scheduler.drop(stream)
        if not stream.latest_only:
            stream.dropped -= kept  # on disk, not lost
        self.not_connected += dropped - kept

    def _keep(self, stream: Stream, topic: str, payload: bytes, qos: int) -> bool:
        """Offline: a ``buffer: disk`` stream's message goes to the disk buffer (True); others are not kept."""
        if self.spool is None or stream.name not in self._buffered:
            return False
        try:
            self.spool.append(topic, payload, qos, time.time())
        except OSError as err:
            _log_spool_error(err)
            return False
        self.spooled += 1
        return True

    def unsent(self, lane: Lane) -> int:
        """Bytes of ``lane`` handed over and not yet delivered: inside paho, and in the socket."""
        client = lane.link.client
        return paho_unsent(client) + kernel_unsent(raw_socket(client))

    def _blocked(self, lane: Lane, handed: int, size: int = 0) -> str | None:
        """Why ``lane`` may not take another message now (None: it may); ``handed``: bytes given to it in this
        round already; ``size``: the next message's. "network": its bytes wait in the network; "path": the path
        beyond the sockets holds its budget (every lane waits); "allowance": a paced lane used its share."""
        room = self._path_room(time.monotonic())
        if room is not None:
            # behind a hop, one queue holds every connection's bytes in turn: a scan or a camera frame goes in
            # only when it fits the room, or when at most half the budget is on the way (then a pose waits behind
            # one of them, never behind several); motion (small, rate-limited) may add a budget's worth, or the
            # last of those if larger, so that a pose goes in right behind a scan, not a round trip after it
            path_budget = self.path.budget(0.0)
            if lane.paced and (room <= 0 or (size > room and room < path_budget / 2)):
                return "path"
            if not lane.paced and room <= -max(path_budget, min(self._paced_last, 4 * path_budget)):
                return "path"
        budget = self.budget()
        if not lane.paced:
            return "network" if self.unsent(lane) + handed >= budget else None
        if handed or paho_unsent(lane.link.client) or \
                kernel_unsent(raw_socket(lane.link.client)) >= self._lane_budget(lane, budget):
            return "network"
        return "allowance" if lane.credit < 0 else None

    def _lane_budget(self, lane: Lane, budget: int) -> int:
        """Bytes a paced lane may hold in its socket: a video lane its own allowance's worth of the round trip and
        target delay, not the whole link's (the lock is held). Why: where the queue backs up into the robot, a
        lane's socket drains at the lane's share, and a camera's frame behind the whole link's budget of its own
        earlier frames waited seconds after a fall (the link's budget at a quarter of its rate). Only a video lane
        (one whose stream says what it wants): a scan's lane held to its share carried 0.6 scans a second on a
        lossy 128 kbit/s modem instead of 1.7, the link half idle (bench/weak_link.py)."""
        now = time.monotonic()
        if not lane.wants or now - lane.wanted_at >= WANTS_FOR:
            return budget
        allowance, _ = self._allowance(lane, now)
        meter = self.meter
        return int(min(budget, max(MIN_BUDGET, allowance * (meter.min_rtt + meter.target_delay))))

    def has_room(self, lane: Lane, stream: Stream) -> bool:
        """Whether a message of ``stream`` handed over now would leave at once: nothing of it waits, its lane is
        connected and neither the lane nor the path holds its budget (a video frame is encoded only then)."""
        if not lane.link.connected.is_set():
            return False
        with self.lock:
            if stream.waiting:
                return False
            self._refill(lane, time.monotonic())
            return self._blocked(lane, 0) is None

    def share_of(self, lane: Lane, wants: float | None = None) -> tuple[float, bool]:
        """Bytes/s ``lane`` may hand over (what the tiers before it leave), and whether the link had room to spare
        lately (its capacity not found yet: a stream may probe upwards). ``wants``: the bytes/s the lane's stream
        aims at, counted as its need when its peers' shares are worked out (a video stream: it sends only when its
        lane has room, so what it was offered understates what it needs).

        Room to spare: the socket's meter found no full window, or, while the path steers, its probes come back at
        the base round trip and no capacity of a recent cut is known. Why the second: the path's rate never grows
        past 1.5 × what was delivered, and a camera whose encoder sends less than it aims at (a quiet scene) kept
        the rate, and with it the camera's share, far below a 1 Mbit/s link (half its size at 1 Mbit/s)."""
        with self.lock:
            now = time.monotonic()
            if wants is not None:
                lane.wants, lane.wanted_at = wants, now
            # a stream's share is its part of what the link delivers now: where the link is full, not the PROBE ×
            # it the lanes may offer to find a faster link (a camera aiming at that built a standing queue in its
            # socket: 256 kbit/s modem, frames 430 ms old); a stream finds room by probing itself (headroom)
            allowance, steering = self._allowance(lane, now, probing=not self.meter.full)
            if not steering:
                return allowance, not self.meter.full
            path = self.path
            return allowance, (not self.meter.full and path.shows_no_queue(now)
                               and path.known_capacity(now) is None)

    def _allowance(self, lane: Lane, now: float, probing: bool = True) -> tuple[float, bool]:
        """Bytes/s ``lane`` may hand over, and whether the path steers (:meth:`_refill` says why; the lock is held).
        ``probing``: of PROBE × the socket meter's rate (how the lanes find a faster link), else of the rate."""
        steering = not self.fifo and self.path.steering(now)
        wants = [other.wants if now - other.wanted_at < WANTS_FOR else 0.0 for other in self.lanes]
        probe = PROBE if probing else 1.0
        if steering:
            return self.meter.allowance(lane.index, self._tiers, probe=1.0, wants=wants,
                                        rate=min(probe * self.meter.rate, self.path.rate)), True
        return self.meter.allowance(lane.index, self._tiers, rate=self.rate(now), probe=probe, wants=wants), False

    def _refill(self, lane: Lane, now: float) -> None:
        """A paced lane's allowance since its last refill, and while the path steers, the pace of its writes.

        While the path steers, the lanes together get at most the path's rate: the socket's meter offers PROBE ×
        its estimate to find a faster link (and still may, up to the path's rate), but the path meter finds one by
        its own answers. A lane with a long backlog (a 4 MB map) written at PROBE × the path's rate overfilled a
        hidden queue for as long as the map took: the path cut its rate to 0.85 × what it delivered, PROBE put the
        lanes back over it, and the queue grew until the camera got nothing and poses were seconds old
        (bench/weak_link.py, the camera + map rows)."""
        if lane.paced:
            allowance, steering = self._allowance(lane, now)
            lane.credit = min(float(self.budget()), lane.credit + allowance * max(0.0, now - lane.refilled))
            lane.refilled = now
            self._pace(lane, allowance if steering else None)

    @staticmethod
    def _pace(lane: Lane, rate: float | None) -> None:
        """``lane``'s writes at ``rate`` bytes/s (None: as fast as the socket takes them; bridge/core/pacer.py)."""
        lane.pacer.rate = None if rate is None else max(MIN_PACING, rate)

    # -- the sender thread ----------------------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self.lock:
                if self._stopped:
                    return
                self.lock.wait(POLL if self.scheduler or self._draining else PROBE_PERIOD / 2)
                now = time.monotonic()
                try:
                    if self.main.link.connected.is_set():
                        self._probe(now)
                        before = self.path.rate, self.path.target, self.path.overused
                        self.path.update(now)
                        self._log_cut("a probe overdue", before, now)
                    self._pump(now)
                    report = self.report(now) if now - self._reported >= LINK_REPORT_PERIOD else None
                except Exception:  # a bug here must not silence the robot's state for good
                    log.exception("uplink sender")
                    report = None
            if report is not None and self.report_topic is not None:
                self.main.link.publish(self.report_topic, report.to_json(), LinkReport.QOS, LinkReport.RETAINED)

    def report(self, now: float) -> LinkReport:
        """What the uplink carried since the last report (the lock is held)."""
        period = max(1e-3, now - self._reported)
        self._reported = now
        streams = {}
        for name, stream in self.scheduler.streams.items():
            counts = (stream.offered, stream.sent, stream.superseded, stream.dropped, stream.bytes_sent)
            last = self._counts.get(name, (0, 0, 0, 0, 0))
            self._counts[name] = counts
            offered, sent, superseded, dropped, sent_bytes = (a - b for a, b in zip(counts, last, strict=True))
            label, max_rate = self._labels.get(name, (name, None))
            streams[label] = StreamReport(stream.priority.name.lower(), stream.latest_only,
                                          round(offered / period, 2), round(sent / period, 2), superseded, dropped,
                                          max_rate, round(sent_bytes * 8 / 1000 / period, 1))
        meter, path = self.meter, self.path
        return LinkReport("fifo" if self.fifo else "scheduled", round(self.rate() * 8 / 1000, 1), meter.measured,
                          self.budget(), round(meter.min_rtt * 1000, 2), round(period, 2), streams,
                          path=PathReport(round(path.base_rtt * 1000, 1), round(path.current_rtt(now) * 1000, 1),
                                          round(path.queue_delay(now) * 1000, 1), round(path.rate * 8 / 1000, 1),
                                          path.overused, path.steering(now)) if path.measured else None)

    def _pump(self, now: float) -> None:
        """Hand over what waits, the highest class first, then the stream waiting longest. A full main connection
        (the link is congested) stops everything; a paced lane that is busy or out of allowance only stops its
        own streams, and the link's room goes to the next stream on another lane (bulk gets what is left). The
        disk buffer goes last, when nothing live waits."""
        if not self.main.link.connected.is_set():
            for stream in self.scheduler.ready():  # what waited when the broker went: buffered streams keep it
                self._set_aside(stream)
        self._measure(now)
        for lane in self.lanes:
            self._refill(lane, now)
        handed: dict[int, int] = {}
        blocked: set[int] = set()
        progress = True
        while progress:
            progress = False
            for stream in self.scheduler.ready():
                lane = self.lane_of(stream)
                if lane.index in blocked:
                    continue
                if not lane.link.connected.is_set():
                    self._set_aside(stream)  # its own connection went first: the same as the broker going
                    continue
                why = self._blocked(lane, handed.get(lane.index, 0), stream.waiting[0].size)
                if why is not None:
                    if not lane.paced or why == "path":
                        return  # strict priority: nothing of a lower class overtakes a congested link
                    blocked.add(lane.index)
                    continue
                message = self.scheduler.take_from(stream)
                if lane.link.publish(message.topic, message.payload, message.qos, message.retain) is None and \
                        not lane.link.connected.is_set():
                    self._keep(stream, message.topic, message.payload, message.qos)  # went just now (buffered)
                handed[lane.index] = handed.get(lane.index, 0) + message.size
                self.handed += message.size
                if lane.paced:
                    lane.credit -= message.size
                    self._paced_last = message.size
                progress = True
                break  # from the top: the order may have changed
        self._drain_spool(handed)

    def _drain_spool(self, handed: dict[int, int]) -> None:
        """After reconnecting, the disk buffer's records, oldest first, when no live message waits."""
        self._draining = False
        lane = self.state_lane
        if self.spool is None or self.scheduler or not self.main.link.connected.is_set() or \
                not lane.link.connected.is_set():
            return  # offline: the disk buffer waits for the connections (live data waiting goes first)
        sent = 0
        try:
            while self._blocked(lane, handed.get(lane.index, 0)) is None:
                record = self.spool.next(time.time())
                if record is None:
                    break
                if lane.link.publish(record.topic, record.payload, record.qos, False) is None and \
                        not lane.link.connected.is_set():
                    self.spool.unread()  # the connection went just now: it stays on disk for the next one
                    break
                handed[lane.index] = handed.get(lane.index, 0) + len(record.payload)
                self.handed += wire_size(record.topic, record.payload, record.qos)
                if lane.paced:
                    lane.credit -= len(record.payload)
                    self._paced_last = len(record.payload)
                sent += 1
            if sent:
                self.spool.commit()
            self._draining = bool(self.spool)
        except OSError as err:
            _log_spool_error(err)

    def _measure(self, now: float) -> None:
        """Feed the meter every lane's delivered bytes; resize the paced lanes' buffers when a window closes."""
        if not self.main.link.connected.is_set():
            self.meter.reset()
            self.path.reset(self._left())
            return
        acked: list[int] = []
        min_rtt, queued = None, 0
        for lane in self.lanes:
            sock = raw_socket(lane.link.client)
            sample = delivered(sock)
            acked.append(sample[0] if sample is not None else 0)
            if lane.paced and sample is not None:
                self._keep_alive_while_writing(lane, sample[0], now)
            if lane is self.main and sample is not None and sample[1] is not None:  # where the probes go
                self.path.tcp_rtt = sample[1] if self.path.tcp_rtt is None else min(self.path.tcp_rtt, sample[1])
            queued += kernel_unsent(sock)
            if sample is not None and sample[1] is not None:
                min_rtt = sample[1] if min_rtt is None else min(min_rtt, sample[1])
        # The link was the limit if bytes waited in the network at every look of the window: it never idled. While
        # the path steers, not if its probes came back at the base round trip meanwhile: nothing queued then, and
        # what the sockets held was a paced lane's trickle on its way (PathMeter.shows_no_queue)
        limited = queued > 0 and not (not self.fifo and self.path.steering(now) and self.path.shows_no_queue(now))
        offered = tuple(lane.offered for lane in self.lanes)
        if self.meter.sample(now, tuple(acked), limited, min_rtt, offered) is not None:
            if log.isEnabledFor(logging.DEBUG):  # (the line reads every lane's socket)
                log.debug("uplink: %.0f B/s (%s), budget %d B, lanes %s B/s, offered %s B/s; path %.0f B/s%s, "
                          "queue %.0f ms, room %s; paced at %s B/s, holding %s B", self.meter.rate,
                          "measured" if self.meter.measured else "assumed",
                          self.meter.budget, [round(r) for r in self.meter.lane_rates],
                          [round(r) for r in self.meter.lane_demand], self.path.rate,
                          " (steering)" if self.path.steering(now) else "", 1000 * self.path.queue_delay(now),
                          self._path_room(now), [None if lane.pacer.rate is None else round(lane.pacer.rate)
                                                 for lane in self.lanes],
                          [self.unsent(lane) for lane in self.lanes])
            for lane in self.lanes:
                if lane.paced:
                    self._size_buffer(lane)

    def _keep_alive_while_writing(self, lane: Lane, acked: int, now: float) -> None:
        """A paced lane in the middle of a message whose bytes keep leaving, while the broker answers the path's
        probes, is alive: paho is told so (MqttLink.heard_while_writing), or its keep-alive would drop the lane
        mid-message, its PINGREQ queued behind the message (the lock is held)."""
        progressed, lane.acked = acked > lane.acked, acked
        answered = self.path.last_answer
        if progressed and answered is not None and now - answered < lane.link.keepalive \
                and paho_unsent(lane.link.client) > 0:
            lane.link.heard_while_writing()

    def _size_buffer(self, lane: Lane, sock: socket.socket | None = None) -> None:
        """A paced lane's send buffer ≈ the budget (the kernel doubles what it is given)."""
        size = max(2048, self.budget() // 2)
        if sock is None:
            if size == lane.sndbuf:
                return
            sock = raw_socket(lane.link.client)
            if sock is None:
                return
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, size)
            lane.sndbuf = size
        except OSError:
            pass
