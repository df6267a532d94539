"""MQTT 3.1.1 conformance of the brokers we ship, clause by clause (the clause number is in each test's name).

Each test runs against the embedded broker and the Mosquitto that ``roslink-mqtt acl export`` configures (the
same two processes test_broker_matrix.py uses), with raw sockets, so every flag and packet id is seen as sent:
paho would acknowledge, retry and reorder on its own. Written from the MQTT 3.1.1 specification (OASIS
Standard, 29 October 2014); no test suite's code.
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from tests.support.broker_setup import ExportedMosquitto
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.procs import DEMO_PASSWORDS
from tests.support.rawmqtt import RawClient, connect_packet, publish_packet, remaining_length, subscribe_packet, utf8
from tests.support.waits import wait_until

BACKENDS = ("embedded", "mosquitto")
ADMIN = ("admin", DEMO_PASSWORDS["admin"])
WAIT = 5.0  # s: the most any single packet may take here (a generous safety deadline, not a measurement)
CONNACK, PUBLISH, PUBACK, PUBREC, PUBREL, PUBCOMP, SUBACK, PINGRESP = 2, 3, 4, 5, 6, 7, 9, 13


@dataclass
class Packet:
    kind: int
    flags: int
    body: bytes

    @property
    def dup(self) -> bool:
        return bool(self.flags & 0x08)

    @property
    def qos(self) -> int:
        return (self.flags >> 1) & 0x03

    @property
    def retain(self) -> bool:
        return bool(self.flags & 0x01)

    def publish(self) -> tuple[str, int | None, bytes]:
        """(topic, packet id or None for QoS 0, payload) of a PUBLISH."""
        size = struct.unpack("!H", self.body[:2])[0]
        topic, rest = self.body[2:2 + size].decode(), self.body[2 + size:]
        if self.qos:
            return topic, struct.unpack("!H", rest[:2])[0], rest[2:]
        return topic, None, rest

    @property
    def packet_id(self) -> int:
        return struct.unpack("!H", self.body[:2])[0]


class Wire(RawClient):
    """One raw MQTT 3.1.1 connection: send bytes, read whole packets."""

    def __init__(self, port: int) -> None:
        super().__init__(port, timeout=WAIT)

    def login(self, client_id: str, *, clean: bool = True, keepalive: int = 30,  # type: ignore[override]
              will: tuple[str, bytes, int, bool] | None = None) -> tuple[int, int]:
        """(session present flag, return code) of the CONNACK."""
        self.sock.sendall(connect_packet(client_id, *ADMIN, clean=clean, keepalive=keepalive, will=will))
        ack = self.read()
        assert ack.kind == CONNACK, ack
        return ack.body[0] & 0x01, ack.body[1]

    def read(self, timeout: float = WAIT) -> Packet:
        self.sock.settimeout(timeout)
        first = self.recv_exactly(1)[0]
        length, shift = 0, 0
        while True:
            byte = self.recv_exactly(1)[0]
            length |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                break
        return Packet(first >> 4, first & 0x0F, self.recv_exactly(length))

    def read_kind(self, kind: int, timeout: float = WAIT) -> Packet:
        """The next packet of ``kind`` (PINGRESPs and others in between are skipped)."""
        deadline = time.monotonic() + timeout
        while True:
            packet = self.read(max(0.01, deadline - time.monotonic()))
            if packet.kind == kind:
                return packet

    def nothing_within(self, seconds: float, kind: int = PUBLISH) -> bool:
        try:
            self.read_kind(kind, seconds)
        except TimeoutError:
            return True
        return False

    def subscribe(self, topic_filter: str, qos: int, packet_id: int = 1) -> int:
        """The SUBACK's return code for one filter."""
        self.send(subscribe_packet([topic_filter], packet_id, qos))
        ack = self.read_kind(SUBACK)
        assert ack.packet_id == packet_id
        return ack.body[2]

    def ack(self, kind: int, packet_id: int) -> None:
        flags = 0x02 if kind == PUBREL else 0
        self.send(bytes([kind << 4 | flags, 2]) + struct.pack("!H", packet_id))

    def drop(self) -> None:
        """Close without DISCONNECT (as a lost link does): the session and its will survive it."""
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        self.sock.close()

    def disconnect(self) -> None:
        try:
            self.send(bytes([0xE0, 0]))
        finally:
            self.sock.close()


@pytest.fixture(params=BACKENDS)
def port(request, acl_embedded: EmbeddedBrokerProcess, acl_mosquitto: ExportedMosquitto) -> int:
    return acl_embedded.port if request.param == "embedded" else acl_mosquitto.port


@pytest.fixture
def wires(port: int, request) -> Iterator:
    """Connections to the broker under test; ``topic(name)`` is a topic of this test alone."""
    made: list[Wire] = []

    def make() -> Wire:
        made.append(Wire(port))
        return made[-1]

    make.topic = lambda name: f"conformance/{request.node.name}/{name}"  # type: ignore[attr-defined]
    make.cid = lambda name: f"c{abs(hash(request.node.name)) % 10**8}-{name}"  # type: ignore[attr-defined]
    yield make
    for w in made:
        try:
            w.sock.close()
        except OSError:
            pass


def publish(wires, topic: str, payload: bytes, qos: int, *, retain: bool = False) -> None:
    """A complete publish by a client of its own (its flow finished before this returns)."""
    w = wires()
    w.login(wires.cid("pub"))
    w.send(publish_packet(topic, payload, qos=qos, retain=retain, packet_id=7))
    if qos == 1:
        assert w.read_kind(PUBACK).packet_id == 7
    elif qos == 2:
        assert w.read_kind(PUBREC).packet_id == 7
        w.ack(PUBREL, 7)
        assert w.read_kind(PUBCOMP).packet_id == 7
    w.disconnect()


def persistent_subscriber(wires, topic_name: str, qos: int) -> tuple[str, str, Wire]:
    """(client id, topic, connection): a session with CleanSession=0 subscribed to a topic of this test alone."""
    cid, topic = wires.cid("sub"), wires.topic(topic_name)
    sub = wires()
    sub.login(cid, clean=False)
    assert sub.subscribe(topic, qos) == qos
    return cid, topic, sub


def test_mqtt_3_1_2_2_unsupported_protocol_level_gets_connack_1(wires) -> None:
    """A protocol level the broker does not speak is answered with CONNACK 0x01 and the connection closed."""
    w = wires()
    body = utf8("MQTT") + bytes([7, 0x02]) + struct.pack("!H", 30) + utf8(wires.cid("level7"))
    w.send(bytes([0x10]) + remaining_length(len(body)) + body)
    ack = w.read(2.0)
    assert (ack.kind, ack.body[-1]) == (CONNACK, 0x01)
    assert w.closed_within(2.0)


def test_mqtt_3_2_2_1_and_2_session_present(wires) -> None:
    """CleanSession=1: session present 0; CleanSession=0 resuming a stored session: session present 1."""
    cid = wires.cid("s")
    first = wires()
    assert first.login(cid, clean=False) == (0, 0)  # a new session
    assert first.subscribe(wires.topic("t"), 1) == 1
    first.disconnect()
    again = wires()
    assert again.login(cid, clean=False) == (1, 0)
    again.disconnect()
    clean = wires()
    assert clean.login(cid, clean=True) == (0, 0)
    clean.disconnect()


def test_mqtt_4_4_0_1_unacknowledged_qos1_is_resent_with_dup_on_reconnect(wires) -> None:
    cid, topic, sub = persistent_subscriber(wires, "q1", 1)
    publish(wires, topic, b"once", 1)
    first = sub.read_kind(PUBLISH)
    got_topic, pid, payload = first.publish()
    assert (got_topic, payload, first.qos, first.dup) == (topic, b"once", 1, False)
    sub.drop()  # no PUBACK
    again = wires()
    assert again.login(cid, clean=False) == (1, 0)
    resent = again.read_kind(PUBLISH)
    assert resent.publish() == (topic, pid, b"once") and resent.dup and resent.qos == 1
    again.ack(PUBACK, pid)
    again.disconnect()  # not drop(): a reset may discard the PUBACK before the broker reads it
    third = wires()
    assert third.login(cid, clean=False) == (1, 0)
    assert third.nothing_within(0.5), "an acknowledged message was sent again"
    third.disconnect()
    wires().login(cid, clean=True)


def test_mqtt_4_4_0_1_unacknowledged_qos2_publish_is_resent_with_dup(wires) -> None:
    cid, topic, sub = persistent_subscriber(wires, "q2", 2)
    publish(wires, topic, b"exactly", 2)
    _t, pid, _p = sub.read_kind(PUBLISH).publish()
    sub.drop()  # no PUBREC
    again = wires()
    assert again.login(cid, clean=False) == (1, 0)
    resent = again.read_kind(PUBLISH)
    assert resent.publish() == (topic, pid, b"exactly") and resent.dup and resent.qos == 2
    again.ack(PUBREC, pid)
    assert again.read_kind(PUBREL).packet_id == pid
    again.ack(PUBCOMP, pid)
    assert again.nothing_within(0.5)
    again.disconnect()
    wires().login(cid, clean=True)


def test_mqtt_4_3_3_qos2_after_pubrec_only_pubrel_is_resent(wires) -> None:
    """Exactly once across a reconnect: once the subscriber sent PUBREC, the broker resends PUBREL, never the
    PUBLISH again (MQTT-4.3.3-1, MQTT-4.4.0-1)."""
    cid, topic, sub = persistent_subscriber(wires, "q2rel", 2)
    publish(wires, topic, b"one", 2)
    _t, pid, _p = sub.read_kind(PUBLISH).publish()
    sub.ack(PUBREC, pid)
    assert sub.read_kind(PUBREL).packet_id == pid
    sub.drop()  # no PUBCOMP
    again = wires()
    assert again.login(cid, clean=False) == (1, 0)
    packet = again.read()
    while packet.kind not in (PUBLISH, PUBREL):
        packet = again.read()
    assert (packet.kind, packet.packet_id) == (PUBREL, pid), f"expected PUBREL {pid}, got {packet}"
    again.ack(PUBCOMP, pid)
    assert again.nothing_within(0.5), "the message was delivered twice"
    again.disconnect()
    wires().login(cid, clean=True)


def test_mqtt_4_3_3_a_publishers_resent_qos2_publish_is_delivered_once(wires) -> None:
    """Exactly once in the other direction: a publisher whose QoS 2 PUBLISH the broker acknowledged (PUBREC) loses
    its connection before PUBREL, reconnects to its session and sends the PUBLISH again with DUP=1, then PUBREL. The
    subscriber gets the message once (MQTT-4.3.3-2: until PUBREL, a PUBLISH with that packet id is not new)."""
    topic = wires.topic("q2in")
    sub = wires()
    sub.login(wires.cid("sub"))
    assert sub.subscribe(topic, 2) == 2
    cid = wires.cid("pub")
    pub = wires()
    pub.login(cid, clean=False)
    pub.send(publish_packet(topic, b"exactly once", qos=2, packet_id=9))
    assert pub.read_kind(PUBREC).packet_id == 9
    pub.drop()  # no PUBREL
    again = wires()
    assert again.login(cid, clean=False)[0] == 1
    resend = bytearray(publish_packet(topic, b"exactly once", qos=2, packet_id=9))
    resend[0] |= 0x08  # DUP
    again.send(bytes(resend))
    assert again.read_kind(PUBREC).packet_id == 9
    again.ack(PUBREL, 9)
    assert again.read_kind(PUBCOMP).packet_id == 9
    copies = []
    deadline = time.monotonic() + 2.0
    while time.monotonic() < deadline:
        try:
            packet = sub.read(deadline - time.monotonic())
        except TimeoutError:
            break
        if packet.kind == PUBLISH:
            _t, pid, payload = packet.publish()
            copies.append(payload)
            sub.ack(PUBREC, pid)
        elif packet.kind == PUBREL:
            sub.ack(PUBCOMP, packet.packet_id)
    assert copies == [b"exactly once"], f"delivered {len(copies)} times"
    again.disconnect()
    sub.disconnect()
    wires().login(cid, clean=True)


def test_mqtt_3_3_1_5_and_10_retained_message_and_its_removal(wires) -> None:
    topic = wires.topic("r")
    publish(wires, topic, b"kept", 1, retain=True)
    late = wires()
    late.login(wires.cid("late"))
    assert late.subscribe(topic, 1) == 1
    got = late.read_kind(PUBLISH)
    assert got.publish()[2] == b"kept" and got.retain  # MQTT-3.3.1-8: RETAIN set for a retained copy
    late.disconnect()
    publish(wires, topic, b"", 1, retain=True)  # MQTT-3.3.1-10: an empty retained message removes it
    later = wires()
    later.login(wires.cid("later"))
    assert later.subscribe(topic, 1) == 1
    assert later.nothing_within(0.5)
    later.disconnect()


def test_mqtt_3_1_2_8_will_is_published_when_the_link_is_lost_and_3_1_2_10_not_after_disconnect(wires) -> None:
    topic = wires.topic("will")
    watcher = wires()
    watcher.login(wires.cid("watch"))
    assert watcher.subscribe(topic, 1) == 1
    lost = wires()
    lost.login(wires.cid("lost"), will=(topic, b"gone", 1, False))
    lost.drop()
    assert watcher.read_kind(PUBLISH).publish()[2] == b"gone"
    polite = wires()
    polite.login(wires.cid("polite"), will=(topic, b"never", 1, False))
    polite.disconnect()
    assert watcher.nothing_within(0.5)
    watcher.disconnect()


def test_mqtt_3_1_2_24_silent_client_is_disconnected_after_one_and_a_half_keepalives(wires) -> None:
    w = wires()
    w.login(wires.cid("quiet"), keepalive=1)
    began = time.monotonic()
    # a generous deadline: Mosquitto checks keep-alives on a coarse timer (seen 1.5-5 s for this 1.5 s)
    assert w.closed_within(2 * WAIT), "a client silent past 1.5 × its keep-alive stayed connected"
    assert time.monotonic() - began >= 1.0  # not before its keep-alive


def test_mqtt_4_7_2_1_hash_does_not_match_dollar_topics(wires) -> None:
    every, system = wires(), wires()
    every.login(wires.cid("every"))
    system.login(wires.cid("sys"))
    assert every.subscribe("#", 0) == 0
    assert system.subscribe("$SYS/#", 0) == 0
    system.read_kind(PUBLISH, 3.0)  # the broker's own statistics (sys_interval 1 s on both)
    deadline = time.monotonic() + 1.5
    while (left := deadline - time.monotonic()) > 0:
        try:
            packet = every.read_kind(PUBLISH, left)
        except TimeoutError:
            break
        assert not packet.publish()[0].startswith("$"), packet.publish()[0]
    every.disconnect()
    system.disconnect()


@pytest.fixture(params=BACKENDS)
def backend_port(request, acl_embedded: EmbeddedBrokerProcess, acl_mosquitto: ExportedMosquitto) -> int:
    if request.param == "mosquitto":
        request.applymarker(pytest.mark.xfail(strict=True, reason=(
            "known: Mosquitto 2.0 with an acl_file grants every SUBSCRIBE and checks read access per message "
            "at delivery, so the refused filter gets a SUBACK with its QoS and simply receives nothing")))
    return acl_embedded.port if request.param == "embedded" else acl_mosquitto.port


def test_mqtt_3_9_3_suback_0x80_for_a_refused_filter(backend_port: int) -> None:
    """bob (a viewer of turtle1) may not read alice's commands: that filter's return code is 0x80 (failure),
    while a filter he may read is granted in the same connection."""
    w = Wire(backend_port)
    w.sock.sendall(connect_packet("conformance-bob", "bob", DEMO_PASSWORDS["bob"]))
    assert w.read_kind(CONNACK).body[1] == 0
    assert w.subscribe("roslink/turtle1/from/alice/#", 1, packet_id=3) == 0x80
    assert w.subscribe("roslink/turtle1/heartbeat", 1, packet_id=4) in (0, 1)
    w.disconnect()


def test_mqtt_3_3_5_1_overlapping_subscriptions_deliver_at_the_maximum_qos(wires) -> None:
    base = wires.topic("o")
    sub = wires()
    sub.login(wires.cid("over"))
    assert sub.subscribe(f"{base}/#", 0, packet_id=1) == 0
    assert sub.subscribe(f"{base}/x", 1, packet_id=2) == 1
    publish(wires, f"{base}/x", b"both", 1)
    copies = []  # a broker may send one copy per matching subscription (MQTT-3.3.5-1 allows either)
    try:
        while True:
            copies.append(sub.read_kind(PUBLISH, 0.5 if copies else WAIT))
    except TimeoutError:
        pass
    assert copies and max(c.qos for c in copies) == 1, "no copy at the maximum QoS of the matching subscriptions"
    sub.disconnect()


MQTT5_REFUSED_WITHIN = 0.1  # s: the goal (measured ~1 ms), reported in the run's summary
# What the test fails on: far below the 5 s a reader that took the CONNECT for 3.1.1 would wait for the rest of
# it, far above what a busy machine adds (issue 47).
MQTT5_REFUSED_DEADLINE = 1.0  # s


def test_mqtt_3_1_2_2_mqtt5_connect_gets_connack_1_at_once(acl_embedded: EmbeddedBrokerProcess) -> None:
    """An MQTT 5 CONNECT (properties after the keep-alive shift every later field) is answered at once with
    CONNACK 0x01, not read as 3.1.1 until a timeout. Mosquitto speaks MQTT 5, so this one is the embedded
    broker's alone."""
    properties = bytes([0x11]) + struct.pack("!I", 0)  # session expiry interval 0
    body = (utf8("MQTT") + bytes([5, 0xC2]) + struct.pack("!H", 30) + remaining_length(len(properties))
            + properties + utf8("conformance-v5") + utf8(ADMIN[0]) + utf8(ADMIN[1]))
    w = Wire(acl_embedded.port)
    began = time.monotonic()
    w.send(bytes([0x10]) + remaining_length(len(body)) + body)
    ack = w.read(2.0)
    took = time.monotonic() - began
    assert (ack.kind, ack.body) == (CONNACK, bytes([0, 1]))
    assert w.closed_within(2.0)
    record_measurement("[embedded] MQTT 5 CONNECT -> CONNACK 0x01", took, MQTT5_REFUSED_WITHIN)
    assert took < MQTT5_REFUSED_DEADLINE  # nothing in the gate's answer waits for more bytes


def test_a_subscriber_that_never_acknowledges_holds_at_most_its_outbox(acl_embedded: EmbeddedBrokerProcess) -> None:
    """Deliveries stay in flight until acknowledged (MQTT-4.4.0-1), so a login that reads QoS 1 messages and
    never acknowledges them must not pin the broker's memory: at most ``max_queued_messages`` (1,000) wait for
    it, the rest are dropped (and it is disconnected after ``slow_consumer_timeout``); a subscriber that
    acknowledges gets every message meanwhile. Two bursts of 900: each fits the limit, so the acknowledging
    subscriber gets both whole (a single burst over the limit, read in one go, outruns any subscriber's
    acknowledgements: over the limit is over the limit), while the silent one reaches the limit in the second."""
    topic, burst = "roslink/turtle1/state/conformance_never_acks", 900  # a robot's login: not paced
    mute, fair = Wire(acl_embedded.port), Wire(acl_embedded.port)
    mute.login("conformance-mute")
    fair.login("conformance-fair")
    assert mute.subscribe(topic, 1) == 1 and fair.subscribe(topic, 1) == 1
    received: list[int] = []

    def read_and_acknowledge() -> None:
        while len(received) < 2 * burst:
            _t, pid, _p = fair.read_kind(PUBLISH).publish()
            fair.ack(PUBACK, pid or 0)
            received.append(1)

    reader = threading.Thread(target=read_and_acknowledge, daemon=True)
    reader.start()
    pub = Wire(acl_embedded.port)
    pub.sock.sendall(connect_packet("conformance-robot", "turtle1", DEMO_PASSWORDS["turtle1"]))
    assert pub.read_kind(CONNACK).body[1] == 0
    for first in (0, burst):
        pub.send(b"".join(publish_packet(topic, b"%d" % i, qos=1, packet_id=i + 1)
                          for i in range(first, first + burst)))
        try:
            wait_until("the acknowledging subscriber's burst", lambda n=first + burst: len(received) >= n, timeout=30,
                       period=0.02)
        except AssertionError:
            pass  # counted below
    reader.join(30)
    assert len(received) == 2 * burst, f"the acknowledging subscriber got {len(received)} of {2 * burst}"
    unacked = 0
    try:
        while True:
            mute.read_kind(PUBLISH, 0.5)
            unacked += 1
    except TimeoutError:
        pass
    assert burst < unacked <= 1000, f"{unacked} deliveries waited for a client that never acknowledges"
    for w in (mute, fair, pub):
        w.disconnect()
