"""One live bridge per robot: every heartbeat carries its bridge's claim, and the older live claim keeps the robot.

Two bridges for one robot (a second terminal, a systemd unit plus a manual start, a restored image on a second
machine) would both execute every command: a service called once ran twice. The claim works the same on every
broker, because it is ordinary publish/subscribe on the robot's own heartbeat topic (which only the robot's login
may write): each heartbeat names its bridge (``instance``, ``host``, ``pid``, ``since``, ``take_over``), and every
bridge reads its robot's heartbeats.

* **At start** (:func:`check_claim`, before the bridge subscribes to any command) a bridge announces its claim
  on ``state/bridge`` (:data:`ANNOUNCE`; not on the heartbeat topic, where a client would take it for the robot
  coming up), which a live bridge answers at once with its heartbeat, and listens to the heartbeat topic for a few
  round trips to the broker (:func:`start_wait`; longer when the retained heartbeat names a live bridge). A live
  heartbeat from another bridge means the robot is taken: the new bridge refuses to start
  (:data:`EXIT_DUPLICATE`, which the systemd unit does not restart), naming the live one. With ``--take-over`` its
  announcement says ``take_over`` 1 instead, and it starts once the old bridge has gone. A retained heartbeat that
  says online but is not followed by a live one is a bridge that died without a last-will (power cut): it is
  replaced after :data:`SILENT_PERIODS` periods, and the new claim counts as a take-over.
* **While running** (:class:`ClaimWatch`) a bridge that sees another bridge's live heartbeat compares claims
  (:func:`winner`): the older claim wins unless the newer one is a take-over. The loser stops its robot and exits
  (:data:`EXIT_FENCED`). That settles what the start check cannot see: two bridges started in the same second, a
  broker whose retained messages live per node (RabbitMQ), a frozen bridge that wakes up after being replaced.

A fixed client id per robot was the other way (MQTT lets one session per client id live): but a broker then
disconnects the *older* session, two auto-reconnecting bridges knock each other off in turn, and which one the
broker keeps is not a decision anybody made. The claim keeps the running bridge and says why the other one stopped.

ROS-free; the start check uses its own short-lived paho connection.
"""

from __future__ import annotations

import logging
import os
import secrets
import socket
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from typing import TYPE_CHECKING, Any

import orjson

from ...protocol import SPECS_BY_ID, MessageId, ProtocolError, SystemStatus, decode, loads
from ...protocol.validate import check_field

if TYPE_CHECKING:
    from ...mqtt import BrokerUrl

log = logging.getLogger("roslink_mqtt.bridge.core.claim")

EXIT_DUPLICATE = 3  # another live bridge has the robot: refused at start (systemd: RestartPreventExitStatus)
EXIT_FENCED = 4  # this bridge stopped its robot and left: taken over, or a duplicate that lost to an older one
# The broker refused the robot's login and robots.yaml's bridge.exit_on_refused_login says to exit then (systemd:
# RestartPreventExitStatus; a restart would only be refused again). Here with its siblings, the bridge's exit codes.
EXIT_LOGIN_REFUSED = 5
ANNOUNCE = "bridge"  # state/bridge: a starting bridge's claim, answered by a live bridge's heartbeat
MIN_START_WAIT = 0.1  # s a starting bridge waits at least for a live one to answer its announcement
START_ROUND_TRIPS = 4  # ... or this many round trips to the broker (the answer takes two: there and back)


def start_wait(round_trip: float, period: float) -> float:
    """How long a starting bridge listens for a live one's answer: a few measured round trips, at least
    :data:`MIN_START_WAIT`, at most 1.2 heartbeat periods (a live bridge beats once a period anyway). Should the
    answer be later still (a thin, busy link), both run until the next heartbeat, and the younger stands down."""
    return min(1.2 * period, max(MIN_START_WAIT, START_ROUND_TRIPS * round_trip))
SILENT_PERIODS = 2.5  # periods a retained "online" heartbeat may go unconfirmed before its bridge counts as dead
HANDOVER_TIMEOUT = 5.0  # s a --take-over bridge waits for the old one to stand down (then starts anyway)
CONNECT_WAIT = 3.0  # s the start check waits for the broker; later, the running bridge's watch decides


@dataclass(frozen=True, slots=True)
class Claim:
    """Which bridge process a heartbeat comes from."""

    instance: str
    host: str
    pid: int
    since: float  # s since the epoch
    take_over: bool = False

    @classmethod
    def mine(cls, *, take_over: bool = False) -> Claim:
        return cls(secrets.token_hex(8), socket.gethostname(), os.getpid(), time.time(), take_over)

    @classmethod
    def of(cls, payload: dict[str, Any]) -> Claim:
        """The claim in a heartbeat's payload (a bridge older than claims: instance '', since 0)."""
        return cls(str(payload.get("instance", "")), str(payload.get("host", "")), int(payload.get("pid", 0)),
                   float(payload.get("since", 0.0)), bool(payload.get("take_over", 0)))

    def fields(self) -> dict[str, Any]:
        """The heartbeat fields that carry this claim."""
        return {"instance": self.instance, "host": self.host, "pid": self.pid, "since": self.since,
                "take_over": int(self.take_over)}

    def describe(self) -> str:
        """``on robot-pc (pid 4242) since 2026-11-26 12:03:05``."""
        where = f"on {self.host or 'an unknown host'}" + (f" (pid {self.pid})" if self.pid else "")
        when = datetime.fromtimestamp(self.since).strftime("%Y-%m-%d %H:%M:%S") if self.since else "an unknown time"
        return f"{where} since {when}"


def winner(a: Claim, b: Claim) -> Claim:
    """Of two live claims for one robot, the one that keeps it: the older, unless the newer is a take-over."""
    newer, older = (a, b) if (a.since, a.instance) > (b.since, b.instance) else (b, a)
    return newer if newer.take_over else older


def read_heartbeat(payload: bytes) -> tuple[SystemStatus | int, Claim] | None:
    """(status, claim) of a heartbeat message; None for an empty or malformed one."""
    if not payload:
        return None
    try:
        body = decode(payload, MessageId.HEARTBEAT).payload
    except ProtocolError:
        return None
    return body["system_status"], Claim.of(body)


class Verdict(Enum):
    START = "start"  # nobody else has the robot
    REPLACE = "replace"  # a silent bridge (no last-will) or one that handed over: start as a take-over
    REFUSE = "refuse"  # a live bridge has the robot


@dataclass(frozen=True, slots=True)
class StartCheck:
    verdict: Verdict
    other: Claim | None = None  # the live (REFUSE) or replaced (REPLACE) bridge
    note: str = ""

    def refusal(self, robot: str) -> str:
        """The error a refused bridge prints."""
        assert self.other is not None
        return (f"robot {robot} already has a live bridge {self.other.describe()}; this one does not start "
                f"(stop that one first, or start this one with --take-over to stop it)")


class _Listener:
    """Heartbeats of one robot as seen by the start check (paho's thread in, the checking thread out)."""

    def __init__(self, instance: str) -> None:
        self.instance = instance
        self.cond = threading.Condition()
        self.retained: tuple[SystemStatus | int, Claim] | None = None
        self.live: dict[str, tuple[SystemStatus | int, Claim, float]] = {}  # instance → latest, when

    def on_message(self, payload: bytes, retained: bool) -> None:
        seen = read_heartbeat(payload)
        if seen is None or seen[1].instance == self.instance:
            return
        with self.cond:
            if retained:
                self.retained = seen
            else:
                self.live[seen[1].instance] = (seen[0], seen[1], time.monotonic())
            self.cond.notify_all()

    def live_rival(self) -> Claim | None:
        """Another bridge's claim from a live heartbeat that says it runs (not offline, not a booting one)."""
        for status, claim, _ in self.live.values():
            if status != SystemStatus.OFFLINE:
                return claim
        return None


def announcement(me: Claim) -> bytes:
    """What a starting bridge publishes on ``state/bridge`` (not retained): its claim. A live bridge answers it."""
    return orjson.dumps(me.fields())


# An announcement carries the heartbeat's claim fields, declared (and so checked) by the heartbeat's message spec
CLAIM_FIELDS = tuple(f for f in SPECS_BY_ID[MessageId.HEARTBEAT].fields if f.name in Claim.__slots__)


def read_announcement(payload: bytes) -> Claim | None:
    """The claim in a ``state/bridge`` message; None for anything else."""
    try:
        body = loads(payload)
        if not isinstance(body, dict):
            return None
        claim = Claim.of({f.name: check_field(f.name, f, body[f.name]) for f in CLAIM_FIELDS if f.name in body})
    except ProtocolError:
        return None
    return claim if claim.instance else None


Publish = Callable[[str, bytes], object]  # what it returns (paho's MQTTMessageInfo) is not used


def check_claim(connect: Callable[[Callable[[bytes, bool], None]], tuple[Publish, float] | None],
                robot: str, me: Claim, period: float, *, announce: bytes,
                handover_timeout: float = HANDOVER_TIMEOUT) -> StartCheck:
    """Decide whether this bridge may start. ``connect(on_heartbeat)`` subscribes to the robot's heartbeat topic
    and returns (a publish function for the announcement, the round trip its SUBSCRIBE took) once subscribed, or
    None when the broker is not reachable in time; ``announce``: this bridge's :func:`announcement`."""
    listener = _Listener(me.instance)
    connected = connect(listener.on_message)
    if connected is None:
        return StartCheck(Verdict.START, note="no connection to the broker yet (the lines below say why): the claim "
                                                 "is checked once connected")
    publish, round_trip = connected
    started = time.monotonic()
    publish(robot, announce)
    with listener.cond:
        while True:  # the retained heartbeat may come after the SUBACK: it lengthens the window when it does
            rival, retained = listener.live_rival(), listener.retained
            silent = retained is not None and retained[0] != SystemStatus.OFFLINE
            window = SILENT_PERIODS * period if silent else start_wait(round_trip, period)
            left = started + window - time.monotonic()
            if rival is not None or left <= 0:
                break
            listener.cond.wait(left)
    silent_claim = retained[1] if silent and retained is not None else None
    if me.take_over:
        # the bridge to replace: the live one, else one that already went offline in answer to the announcement
        # (which said take_over 1: a live bridge stands down at once), else the silent one
        target = rival or next((c for st, c, _ in listener.live.values() if st == SystemStatus.OFFLINE),
                               silent_claim)
        if target is None:
            return StartCheck(Verdict.START)
        return _hand_over(listener, publish, robot, announce, target, period, handover_timeout)
    if rival is not None:
        return StartCheck(Verdict.REFUSE, rival)
    if silent_claim is not None:
        return StartCheck(Verdict.REPLACE, silent_claim,
                          f"replacing the bridge {silent_claim.describe()}: its retained heartbeat says online but "
                          f"no heartbeat came for {time.monotonic() - started:.1f} s (it stopped without a last-will)")
    return StartCheck(Verdict.START)


def _hand_over(listener: _Listener, publish: Publish, robot: str, announce: bytes,
               target: Claim, period: float, timeout: float) -> StartCheck:
    """Wait until ``target`` has stood down: its offline heartbeat, or 1.5 periods without one. The announcement
    (take_over 1) is repeated each period, in case one was missed."""
    started = time.monotonic()
    deadline = started + timeout
    while True:
        with listener.cond:
            seen = listener.live.get(target.instance)
            heard = seen[2] if seen is not None else started
            gone = (seen is not None and seen[0] == SystemStatus.OFFLINE) or time.monotonic() - heard > 1.5 * period
            if gone or time.monotonic() >= deadline:
                break
            listener.cond.wait(min(period, max(0.0, deadline - time.monotonic())))
        publish(robot, announce)
    note = (f"took over from the bridge {target.describe()}" if gone else
            f"the bridge {target.describe()} did not stand down within {timeout:g} s; starting anyway "
            f"(it stops when it sees this one's heartbeat)")
    return StartCheck(Verdict.REPLACE, target, note)


class ClaimWatch:
    """The running bridge's side: another bridge's live heartbeat either yields to this one, or fences this one."""

    def __init__(self, me: Claim, on_fenced: Callable[[str, Claim], None], answer: Callable[[], None]) -> None:
        """``answer()`` publishes this bridge's heartbeat now: the reply to a starting bridge's announcement."""
        self.me, self.on_fenced, self.answer = me, on_fenced, answer
        self.fenced: str | None = None  # why this bridge stands down
        self._told: set[str] = set()  # rivals already logged (each once)

    def on_announcement(self, robot: str, payload: bytes, retained: bool) -> None:
        """A starting bridge's claim on ``state/bridge`` (paho's thread): a take-over fences this bridge; anything
        else is answered with this bridge's heartbeat, which tells the new one the robot is taken."""
        rival = None if retained or self.fenced is not None else read_announcement(payload)
        if rival is not None and rival.instance != self.me.instance:
            self._rival(robot, rival, starting=True)

    def on_heartbeat(self, robot: str, payload: bytes, retained: bool) -> None:
        """A message on the robot's heartbeat topic (paho's thread)."""
        if retained or self.fenced is not None:
            return
        seen = read_heartbeat(payload)
        if seen is None:
            return
        status, rival = seen
        if rival.instance == self.me.instance or status == SystemStatus.OFFLINE:
            return
        self._rival(robot, rival, starting=False)

    def _rival(self, robot: str, rival: Claim, *, starting: bool) -> None:
        if winner(rival, self.me) is rival:
            self.fenced = (f"taken over by the bridge {rival.describe()}" if rival.take_over else
                           f"robot {robot} already had a live bridge {rival.describe()} (started earlier); this "
                           f"one stands down")
            self.on_fenced(self.fenced, rival)
            return
        if starting:
            self.answer()  # this heartbeat tells the starting bridge that the robot is taken
        if rival.instance not in self._told and len(self._told) < 64:
            self._told.add(rival.instance)
            log.warning("another bridge for %s %s %s; it stands down (this one keeps the robot)", robot,
                        "is starting" if starting else "runs", rival.describe())


def paho_connector(urls: Sequence[BrokerUrl], username: str, password: str | None, ca_file: str | None, topic: str,
                   announce_topic: str, *, wait: float = CONNECT_WAIT
                   ) -> tuple[Callable[[Callable[[bytes, bool], None]], tuple[Publish, float] | None],
                              Callable[[], None]]:
    """(connect, close) for :func:`check_claim`: a short-lived connection of the robot's login (a random client
    id: a fixed one would knock the live bridge off a broker) that subscribes to the heartbeat ``topic`` and
    publishes on ``announce_topic``."""
    import paho.mqtt.client as mqtt

    from ...mqtt import make_client
    from .link import bridge_client_id

    client = make_client(bridge_client_id(username, "claim"), username=username, password=password, url=urls,
                         ca_file=ca_file)
    subscribed, answered = threading.Event(), threading.Event()  # answered: subscribed, refused or unreachable
    round_trip = [0.0]

    def connect(on_heartbeat: Callable[[bytes, bool], None]) -> tuple[Publish, float] | None:
        asked = [0.0]

        def on_connect(c: mqtt.Client, _u: object, _f: object, reason: mqtt.ReasonCode, _p: object) -> None:
            if reason.is_failure:
                answered.set()  # the main connection logs why (a wrong password, say)
            else:
                asked[0] = time.monotonic()
                c.subscribe(topic, 1)

        def on_subscribe(*_: object) -> None:
            round_trip[0] = time.monotonic() - asked[0]
            subscribed.set()
            answered.set()

        client.on_connect = on_connect
        client.on_subscribe = on_subscribe
        client.on_connect_fail = lambda *_: answered.set()
        # paho types a message's payload bytes | bytearray; a received one is always bytes (struct.unpack)
        client.on_message = lambda _c, _u, m: on_heartbeat(m.payload, bool(m.retain))  # type: ignore[arg-type]
        try:
            client.connect_async(urls[0].host, urls[0].port, keepalive=5)
            client.loop_start()
        except OSError:
            return None
        answered.wait(wait)
        if not subscribed.is_set():
            return None
        return (lambda _robot, payload: client.publish(announce_topic, payload, qos=1)), round_trip[0]

    def close() -> None:
        try:
            client.disconnect()
        finally:
            client.loop_stop()

    return connect, close
