"""Issue 12, tried as an attacker would: an ordinary login (bob, a *viewer* of turtle1) against the real broker.

Each test reproduces one attack with real clients -- paho, or a raw socket where paho would
refuse to send the packet -- against the embedded broker in its own process, prints what it
measured, and asserts a generous safety bound:

* no take-over across logins;
* no event-loop stall over 200 ms from any single client (measured by :class:`StallMeter`,
  an honest client timing QoS 1 round trips during the attack);
* broker memory growth under 20 MB from any single login's abuse.

Where Mosquitto (the exported configuration) behaves differently, a test says so and pins the
documented behaviour, so docs/safety.md stays true.
"""

from __future__ import annotations

import re
import socket
import threading
import time
from collections.abc import Iterator

import pytest
from websockets.sync.client import connect as ws_connect

from tests.support.attack import StallMeter, rss_bytes
from tests.support.broker_client import Probe
from tests.support.broker_setup import ExportedMosquitto, write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.procs import DEMO_PASSWORDS as PW
from tests.support.rawmqtt import RawClient, connect_packet, publish_header, publish_packet, subscribe_packet
from tests.support.waits import never, paced, wait_until

pytestmark = [pytest.mark.timeout(120), pytest.mark.security]

STALL_BOUND = 0.200  # s: the longest any honest client may wait because of one attacker (p99, and reported)
# The worst single round trip may exceed STALL_BOUND on a busy machine (another process taking a core) for a
# scheduler hiccup that no attacker caused; a stall the attack causes lasts seconds. Failing on the worst only
# past this deadline keeps the test meaningful and green on a busy machine (issue 47).
STALL_DEADLINE = 1.0  # s
MEMORY_BOUND = 20 * 1024 * 1024  # bytes of broker growth one login's abuse may cause


def _broker(tmp_path, *args: str, ws: bool = False) -> EmbeddedBrokerProcess:
    fleet = write_fleet(tmp_path)
    return EmbeddedBrokerProcess(tmp_path, fleet, "--sys-interval", "0", *args, ws=ws)


@pytest.fixture
def clients() -> Iterator:
    made: list[Probe] = []

    def make(port: int, login: str, client_id: str = "", **kw) -> Probe:
        p = Probe(port, login, PW[login], client_id, **kw)
        made.append(p)
        assert p.connect() == 0, f"{login} refused"
        return p

    yield make
    for p in made:
        p.close()


# -- 1: client-id take-over -------------------------------------------------------------------


def test_a_viewer_reusing_the_bridges_client_id_disconnects_nobody(tmp_path, clients) -> None:
    """bob connects 5 times with turtle1's and alice's client ids: both stay connected, no will fires."""
    with _broker(tmp_path) as broker:
        bridge = clients(broker.port, "turtle1", "roslink-bridge-turtle1",
                         will=("roslink/turtle1/heartbeat", b"offline", 1, True))
        assert bridge.subscribe("roslink/turtle1/from/+/#") == [1]
        alice = clients(broker.port, "alice", "alice-sdk-1",
                        will=("roslink/operators/alice/alice-sdk-1", b"", 1, True))
        watcher = clients(broker.port, "admin")
        assert watcher.subscribe(["roslink/turtle1/heartbeat", "roslink/operators/#"]) == [1, 1]
        kicked = lambda: bridge.disconnected.is_set() or alice.disconnected.is_set()  # noqa: E731
        for cid in ["roslink-bridge-turtle1", "alice-sdk-1"] * 5:
            attacker = Probe(broker.port, "bob", PW["bob"], cid)
            assert attacker.connect() == 0  # bob gets a session of his own
            never("bob's connection kicking another login's session", kicked, seconds=0.05)
            attacker.close()
        never("bob's connections kicking another login's session", kicked, seconds=0.5)
        assert not bridge.disconnected.is_set(), "bob's connection kicked the bridge"
        assert not alice.disconnected.is_set(), "bob's connection kicked alice"
        assert watcher.drain(0.3) == [], "a will fired: a session of another login was ended"
        alice.publish("roslink/turtle1/from/alice/cmd/twist", b"{}")
        assert bridge.wait_for(lambda m: m.topic.endswith("cmd/twist"), 5)
        # the same login may still take over its own session (MQTT-3.1.4-2), without a will
        again = clients(broker.port, "turtle1", "roslink-bridge-turtle1")
        assert bridge.disconnected.wait(5), "a login could not take over its own client id"
        assert again.subscribe("roslink/turtle1/from/+/#") == [1]
        assert watcher.drain(0.5) == [], "a take-over by the same login published the will"


def test_mosquitto_lets_any_login_take_over_a_known_client_id(tmp_path, clients) -> None:
    """Mosquitto 2.0 has no per-login client ids: documented exposure (docs/safety.md), pinned here.

    Our programs therefore use client ids with 64 random bits that other users' logins cannot read.
    """
    fleet = write_fleet(tmp_path)
    with ExportedMosquitto(tmp_path, fleet) as mosquitto:
        victim = clients(mosquitto.port, "alice", "known-id")
        attacker = clients(mosquitto.port, "bob", "known-id")
        assert victim.disconnected.wait(5), "Mosquitto now refuses cross-login take-over: update docs/safety.md"
        attacker.close()


def test_our_programs_use_unguessable_client_ids() -> None:
    from roslink_mqtt.client import RobotClient

    suffixes = [RobotClient("alice", "alice-demo", presence=False).client_id.rsplit("-", 1)[1] for _ in range(64)]
    # 64 random bits each: hexadecimal, at least 16 digits, never the same twice, and every digit position varies
    assert all(re.fullmatch(r"[0-9a-f]{16,}", s) for s in suffixes), suffixes[:3]
    assert len(set(suffixes)) == len(suffixes), suffixes
    assert all(len({s[i] for s in suffixes}) > 1 for i in range(16)), suffixes[:3]
    from roslink_mqtt.bridge.core.link import bridge_client_id

    ids = {bridge_client_id("turtle1") for _ in range(3)}
    assert len(ids) == 3 and all(len(i.rsplit("-", 1)[1]) >= 16 for i in ids), ids


# -- 2: one packet must not stall the event loop ------------------------------------------------


def test_a_781_kB_subscribe_is_refused_before_it_is_read(tmp_path) -> None:
    with _broker(tmp_path) as broker:
        seed = Probe(broker.port, "turtle1", PW["turtle1"])
        assert seed.connect() == 0
        for i in range(300):  # a retained store to rescan, as in the attack
            seed.client.publish(f"roslink/turtle1/state/r{i}", b"x" * 100, qos=0, retain=True)
        seed.publish("roslink/turtle1/state/last", b"x", retain=True)
        with StallMeter(broker.port) as meter:
            bob = RawClient(broker.port)
            assert bob.login("bob-big", "bob", PW["bob"]) == 0
            packet = subscribe_packet([f"roslink/turtle1/state/{i}" for i in range(200_000)])[:800_000]
            started = time.monotonic()
            try:
                bob.send(packet)
            except OSError:
                pass  # closed while sending: what we want
            closed = bob.closed_within(5)
            took = time.monotonic() - started
        seed.close()
        record_measurement("attack: 781 kB SUBSCRIBE, worst round trip", meter.worst, STALL_BOUND)
        print(f"781 kB SUBSCRIBE: closed={closed} after {took * 1000:.0f} ms; worst honest round trip "
              f"{meter.worst * 1000:.1f} ms over {len(meter.samples)} samples")
        assert closed
        assert meter.p99 < STALL_BOUND and meter.worst < STALL_DEADLINE, \
            f"event loop stalled: p99 {meter.p99 * 1000:.0f} ms, worst {meter.worst * 1000:.0f} ms"
        assert "SUBSCRIBE of" in broker.output()


def test_many_subscribe_packets_within_the_size_limit_do_not_stall(tmp_path) -> None:
    """64 kB SUBSCRIBEs of wildcard filters against 2,000 retained messages: bounded per session, no stall."""
    with _broker(tmp_path, "--limit", "user_publish_rate=0") as broker:  # the seeding is not what is tested
        seed = Probe(broker.port, "admin", PW["admin"])
        assert seed.connect() == 0
        for i in range(2000):
            seed.client.publish(f"roslink/turtle1/state/r{i}", b"x" * 50, qos=0, retain=True)
        seed.publish("roslink/turtle1/state/last", b"x", retain=True)
        with StallMeter(broker.port) as meter:
            bob = RawClient(broker.port)
            assert bob.login("bob-subs", "bob", PW["bob"]) == 0
            filters = [f"roslink/+/state/{i}/#" for i in range(3000)] + ["#", "roslink/#", "+/+/+/+"]
            packet_id = 1
            for start in range(0, len(filters), 2500):
                bob.send(subscribe_packet(filters[start:start + 2500], packet_id))
                packet_id += 1
            wait_until("the broker reading both SUBSCRIBEs (and refusing the rest)",
                       lambda: "limit 1024" in broker.output(), timeout=10)
            meter.keep_measuring(0.3)
            bob.close()
        seed.close()
        record_measurement("attack: 3,000 filters / 2,000 retained, worst round trip", meter.worst, STALL_BOUND)
        print(f"3,003 filters in 2 SUBSCRIBEs vs 2,000 retained: worst honest round trip {meter.worst * 1000:.1f} ms")
        assert meter.p99 < STALL_BOUND and meter.worst < STALL_DEADLINE, (meter.p99, meter.worst)
        assert "limit 1024" in broker.output()


def _ws_half_publish(port: int, *, login: bool) -> None:
    """A packet whose body is one big field, then one byte of it in a second frame, then the WebSocket closes.

    amqtt's reader then re-appended that last frame until the field was "complete" without yielding.
    """
    try:
        with ws_connect(f"ws://127.0.0.1:{port}/", subprotocols=["mqtt"], open_timeout=5, close_timeout=1) as ws:
            if login:
                ws.send(connect_packet(f"bob-ws-{time.monotonic_ns()}", "bob", PW["bob"]))
                ws.recv(timeout=5)
                ws.send(publish_header("roslink/operators/bob/x", 1_000_000))  # the payload: 1 MB to come
            else:  # a CONNECT of 60,000 bytes (under the limit) whose client id is 59,980 bytes
                body_head = b"\x00\x04MQTT\x04\x02\x00\x1e" + (59_980).to_bytes(2, "big")
                ws.send(bytes([0x10, 0xE0, 0xD4, 0x03]) + body_head)
            ws.send(b"x")
    except OSError:
        pass  # the broker may close first: that is fine


@pytest.mark.parametrize("before_login", [False, True])
def test_websocket_closed_mid_packet_does_not_stall(tmp_path, before_login: bool) -> None:
    count = 48 if before_login else 8
    with _broker(tmp_path, ws=True) as broker:
        with StallMeter(broker.port) as meter:
            threads = [threading.Thread(target=_ws_half_publish, args=(broker.ws_port,),
                                        kwargs={"login": not before_login}) for _ in range(count)]
            for t in threads:
                t.start()
            for t in threads:
                t.join(20)
            meter.keep_measuring(1.0)
        stopping = time.monotonic()  # held-back logins (the throttle) must not hold up a stop (hardened fix 30)
        code = broker.stop()
        stopped_in = time.monotonic() - stopping
        what = f"{count} WebSocket {'CONNECT' if before_login else 'PUBLISH'}s closed after their first bytes"
        record_measurement(f"attack: {what[:30]}…, worst round trip", meter.worst, STALL_BOUND)
        print(f"{what}: worst honest round trip {meter.worst * 1000:.1f} ms; the broker stopped in {stopped_in:.1f} s")
        assert meter.p99 < STALL_BOUND and meter.worst < STALL_DEADLINE, (meter.p99, meter.worst)
        assert code == 0 and stopped_in < 3.0, f"SIGTERM took {stopped_in:.1f} s, exit {code}"


# -- 3: a slow consumer -------------------------------------------------------------------------


def test_a_client_that_never_reads_is_bounded_then_dropped(tmp_path, clients) -> None:
    """bob subscribes and never reads; turtle1 streams 200 kB state at 20 Hz: memory bounded, alice unaffected."""
    with _broker(tmp_path, "--limit", "slow_consumer_timeout=3") as broker:
        alice = clients(broker.port, "alice")
        assert alice.subscribe("roslink/turtle1/state/#", qos=0) == [0]
        bob = RawClient(broker.port)
        bob.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        assert bob.login("bob-slow", "bob", PW["bob"]) == 0
        bob.send(subscribe_packet(["roslink/turtle1/state/#"]))
        assert bob.recv_exactly(5)[0] == 0x90, "no SUBACK for bob"  # subscribed; he reads nothing after it
        robot = clients(broker.port, "turtle1")
        before = rss_bytes(broker.proc.pid)
        latencies, peak = [], before
        payload = b"s" * 200_000  # 4 MB/s: 16 MB in 4 s, far more than the kernel buffers of a socket
        for _ in paced(0.05, within=4.0):
            sent = time.monotonic()
            robot.client.publish("roslink/turtle1/state/scan", payload, qos=0)
            msg = alice.wait_for(lambda m: m.topic.endswith("/scan"), 5)
            latencies.append(msg.at - sent)
            peak = max(peak, rss_bytes(broker.proc.pid))
        growth = peak - before
        gave_up = lambda: "slow consumer: over its queue limit" in broker.output()  # noqa: E731
        for _ in paced(0.05, within=6.0, stop=gave_up):  # stream on until the broker gives up on bob (timeout 3 s)
            robot.client.publish("roslink/turtle1/state/scan", payload, qos=0)
        dropped = gave_up()
        bob.close()
        latencies.sort()
        record_measurement("attack: slow consumer, alice's p99 state latency", latencies[int(len(latencies) * .99)],
                           STALL_BOUND)
        print(f"slow consumer: broker RSS +{growth / 1e6:.1f} MB over 4 s of 4 MB/s; alice p50 "
              f"{latencies[len(latencies) // 2] * 1000:.1f} ms, max {latencies[-1] * 1000:.1f} ms; "
              f"bob dropped={dropped}")
        assert growth < MEMORY_BOUND
        assert latencies[int(len(latencies) * .99)] < STALL_BOUND and latencies[-1] < STALL_DEADLINE, \
            (latencies[int(len(latencies) * .99)], latencies[-1])
        assert dropped, "a client over its queue limit for slow_consumer_timeout was not disconnected"
        assert "slow consumer" in broker.output()


# -- 4: memory anyone can pin -------------------------------------------------------------------


def test_retained_quota_per_login(tmp_path, clients) -> None:
    # unpaced: bob's 2,150 messages must all be stored before the replay is read (pacing has its own test)
    with _broker(tmp_path, "--limit", "user_publish_rate=0") as broker:
        before = rss_bytes(broker.proc.pid)
        bob = clients(broker.port, "bob")
        for i in range(150):  # 150 x 1 MB on his own presence subtree: over the presence cap
            bob.client.publish(f"roslink/operators/bob/big{i}", b"b" * 1_000_000, qos=0, retain=True)
        for i in range(2000):  # 2,000 x 4 kB: within the cap, over his 64 kB retained quota
            bob.client.publish(f"roslink/operators/bob/p{i}", b"p" * 4000, qos=0, retain=True)
        bob.publish("roslink/operators/bob/done", b"d", retain=True)
        robot = clients(broker.port, "turtle1")
        for i in range(30):  # a robot's quota is larger, but bounded too (16 MB)
            robot.client.publish(f"roslink/turtle1/state/map{i}", b"m" * 1_000_000, qos=0, retain=True)
        robot.publish("roslink/turtle1/state/done", b"d", retain=True)
        time.sleep(0.5)
        bridge_view = clients(broker.port, "turtle1", "bridge-view")
        assert bridge_view.subscribe("roslink/operators/bob/#") == [1]
        replayed = bridge_view.drain(1.0)
        growth = rss_bytes(broker.proc.pid) - before
        print(f"retained: bob's presence subtree replays {len(replayed)} messages, "
              f"{sum(len(m.payload) for m in replayed)} bytes; broker RSS +{growth / 1e6:.1f} MB "
              "(robot: 16 MB quota used)")
        assert sum(len(m.payload) for m in replayed) <= 64 * 1024
        assert growth < MEMORY_BOUND + 16 * 1024 * 1024  # bob's part under 20 MB; the robot's 16 MB is its quota
        assert "retained quota" in broker.output()


def test_half_sent_publishes_cannot_pin_more_than_the_login_budget(tmp_path, clients) -> None:
    """bob's 31 connections each announce a 4 MiB PUBLISH and stop one byte short (stock: +124 MB, held until he
    closed them); meanwhile the robot's own 3 MB map still goes through."""
    size = 4 * 1024 * 1024
    topic = "roslink/operators/bob/x"
    with _broker(tmp_path, "--limit", "packet_piece_timeout=2") as broker:
        alice = clients(broker.port, "alice")
        assert alice.subscribe("roslink/turtle1/state/map", qos=0) == [0]
        robot = clients(broker.port, "turtle1")
        before = peak = rss_bytes(broker.proc.pid)
        conns = []
        for i in range(31):
            bob = RawClient(broker.port)
            assert bob.login(f"bob-half-{i}", "bob", PW["bob"]) == 0
            conns.append(bob)
            try:
                bob.send(publish_header(topic, size) + b"h" * (size - 2 - len(topic) - 1))
            except OSError:
                pass  # refused while sending: what the budget is for
            peak = max(peak, rss_bytes(broker.proc.pid))
        time.sleep(0.3)
        peak = max(peak, rss_bytes(broker.proc.pid))
        robot.client.publish("roslink/turtle1/state/map", b"m" * 3_000_000, qos=0)  # another login: its own budget
        map_arrived = alice.wait_for(lambda m: m.topic.endswith("/map"), 10) is not None
        closed = sum(c.closed_within(6) for c in conns)  # the refused at once, the rest after the piece timeout
        for c in conns:
            c.close()
        growth = peak - before
        refused = broker.output().count("packets still arriving on this login's connections")
        print(f"31 half-sent 4 MiB PUBLISHes: broker RSS +{growth / 1e6:.1f} MB at peak; {refused} refused over "
              f"the login's budget, {closed} of 31 closed; the robot's 3 MB map arrived={map_arrived}")
        assert growth < MEMORY_BOUND
        assert refused >= 29, broker.output()[-2000:]
        assert "did not arrive within 2 s" in broker.output()
        assert closed == 31
        assert map_arrived


def test_acl_cache_and_closed_sessions_are_bounded_in_bytes(tmp_path) -> None:
    """1,000 distinct 60 kB topics (all denied, 60 MB of topic text), from 20 short sessions: growth under 20 MB."""
    with _broker(tmp_path, "--limit", "user_publish_rate=0") as broker:  # unpaced: the cache, not the pacer
        before = rss_bytes(broker.proc.pid)
        for session in range(20):
            bob = RawClient(broker.port)
            assert bob.login(f"bob-cache-{session}", "bob", PW["bob"]) == 0
            for i in range(50):
                topic = f"roslink/turtle2/state/{session}-{i}-" + "t" * 60_000
                bob.send(publish_packet(topic, b"x"))
            bob.send(publish_packet("roslink/operators/bob/sync", b"x", qos=1))
            bob.recv_exactly(4)  # PUBACK: the 50 before it were handled
            bob.send(b"\xe0\x00")  # DISCONNECT
            bob.close()
        time.sleep(0.5)
        growth = rss_bytes(broker.proc.pid) - before
        print(f"ACL cache: 1,000 x 60 kB denied topics over 20 sessions: broker RSS +{growth / 1e6:.1f} MB")
        assert growth < MEMORY_BOUND


def test_connections_per_login_are_bounded(tmp_path) -> None:
    with _broker(tmp_path, "--limit", "max_connections_per_login=8") as broker:
        made = [RawClient(broker.port) for _ in range(10)]
        codes = [c.login(f"bob-{i}", "bob", PW["bob"]) for i, c in enumerate(made)]
        alice = RawClient(broker.port)
        alice_code = alice.login("alice-1", "alice", PW["alice"])
        for c in [*made, alice]:
            c.close()
        assert codes == [0] * 8 + [5, 5]
        assert alice_code == 0, "one login's connections counted against another"
        assert "limit 8" in broker.output()


# -- 7: retained commands -----------------------------------------------------------------------


def test_retained_commands_are_refused(tmp_path, clients) -> None:
    with _broker(tmp_path) as broker:
        bridge = clients(broker.port, "turtle1")
        assert bridge.subscribe("roslink/turtle1/from/+/#") == [1]
        alice = clients(broker.port, "alice")
        alice.publish("roslink/turtle1/from/alice/cmd/twist", b'{"lx": 0.4}', retain=True)
        alice.publish("roslink/turtle1/from/alice/call/reset", b'{"id": 1}', retain=True)
        alice.publish("roslink/turtle1/from/alice/provide/svc", b'{"type": "std_srvs/srv/Trigger"}', retain=True)
        got = bridge.collect(1, timeout=3)
        assert [m.topic for m in got] == ["roslink/turtle1/from/alice/provide/svc"], got
        late = clients(broker.port, "turtle1", "late-bridge")
        assert late.subscribe("roslink/turtle1/from/+/#") == [1]
        assert [m.topic for m in late.collect(1, timeout=3)] == ["roslink/turtle1/from/alice/provide/svc"]
        assert "retained 'cmd' messages are refused" in broker.output()


# -- 10: protocol violations ------------------------------------------------------------------


@pytest.mark.parametrize("topic", [b"roslink/operators/bob/+", b"roslink/operators/bob/#",
                                   b"roslink/operators/bob\x00"])
def test_an_invalid_publish_topic_ends_the_connection_with_a_reason(tmp_path, topic: bytes) -> None:
    with _broker(tmp_path) as broker:
        bob = RawClient(broker.port)
        assert bob.login("bob-bad", "bob", PW["bob"]) == 0
        bob.send(publish_packet(topic, b"x", qos=1))
        assert bob.closed_within(3), "no PUBACK and no close: the sender hangs"
        bob.close()
        assert "closing client_id='bob-bad'" in broker.output() and "PUBLISH topic" in broker.output()


def test_a_will_with_qos_3_is_refused(tmp_path) -> None:
    with _broker(tmp_path) as broker:
        bob = RawClient(broker.port)
        code = bob.login("bob-will", "bob", PW["bob"], will=("roslink/operators/bob/w", b"", 3, False))
        bob.close()
        assert code == 5
        assert "will QoS 3" in broker.output()


# -- the same attacks against the exported Mosquitto configuration ------------------------------


def test_mosquitto_takes_a_781_kB_subscribe_without_stalling(tmp_path) -> None:
    fleet = write_fleet(tmp_path)
    with ExportedMosquitto(tmp_path, fleet) as mosquitto:
        with StallMeter(mosquitto.port) as meter:
            bob = RawClient(mosquitto.port)
            assert bob.login("bob-big", "bob", PW["bob"]) == 0
            try:
                bob.send(subscribe_packet([f"roslink/turtle1/state/{i}" for i in range(200_000)])[:800_000])
            except OSError:
                pass
            meter.keep_measuring(1.0)
            bob.close()
        print(f"Mosquitto, 781 kB SUBSCRIBE: worst honest round trip {meter.worst * 1000:.1f} ms")
        assert meter.p99 < STALL_BOUND and meter.worst < STALL_DEADLINE, (meter.p99, meter.worst)


@pytest.mark.parametrize("qos", [0, 1])
def test_mosquitto_and_a_client_that_never_reads(tmp_path, clients, qos: int) -> None:
    """Mosquitto 2.0.11 bounds QoS 1/2 queued for a slow client (max_queued_bytes), not QoS 0: documented gap."""
    fleet = write_fleet(tmp_path)
    with ExportedMosquitto(tmp_path, fleet) as mosquitto:
        bob = RawClient(mosquitto.port)
        bob.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        assert bob.login("bob-slow", "bob", PW["bob"]) == 0
        bob.send(subscribe_packet(["roslink/turtle1/state/#"], qos=qos))
        assert bob.recv_exactly(5)[0] == 0x90, "no SUBACK for bob"  # subscribed; he reads nothing after it
        robot = clients(mosquitto.port, "turtle1")
        before = peak = rss_bytes(mosquitto.proc.pid)
        for _ in paced(0.025, within=4.0 if qos else 8.0):  # QoS 1: 32 MB offered, 16 x its queue limit
            robot.client.publish("roslink/turtle1/state/scan", b"s" * 200_000, qos=qos)
            peak = max(peak, rss_bytes(mosquitto.proc.pid))
            if not qos and peak - before > MEMORY_BOUND:
                break  # QoS 0 has shown the unbounded queue: no need to stream on
        bob.close()
        growth = peak - before
        print(f"Mosquitto, slow consumer at QoS {qos}: RSS +{growth / 1e6:.1f} MB over at most "
              f"{4 if qos else 8} s of 8 MB/s")
        if qos:
            assert growth < MEMORY_BOUND
        else:  # docs/safety.md: "Mosquitto 2.0.11 queues QoS 0 for a connected client without bound"
            assert growth > MEMORY_BOUND, "Mosquitto now bounds QoS 0 to slow clients: update docs/safety.md"


def test_an_offline_persistent_session_queues_a_bounded_number(tmp_path, clients) -> None:
    """bob subscribes with a persistent session and leaves; 200 QoS 1 messages later he gets at most the limit."""
    with _broker(tmp_path, "--limit", "max_offline_messages=50") as broker:
        bob = Probe(broker.port, "bob", PW["bob"], "bob-persistent", clean=False)
        assert bob.connect() == 0
        assert bob.subscribe("roslink/turtle1/state/#", qos=1) == [1]
        bob.close()
        robot, alice = clients(broker.port, "turtle1"), clients(broker.port, "alice")
        assert alice.subscribe("roslink/turtle1/state/last", qos=0) == [0]
        for i in range(200):
            robot.client.publish(f"roslink/turtle1/state/n{i}", b"x", qos=1)
        robot.publish("roslink/turtle1/state/last", b"x")
        alice.wait_for(lambda m: m.topic.endswith("/last"), 5)  # fanned out in order: bob's queue is complete
        again = Probe(broker.port, "bob", PW["bob"], "bob-persistent", clean=False)
        assert again.connect() == 0 and again.session_present
        queued = again.drain(2.0)
        again.close()
        print(f"offline queue: {len(queued)} of 201 messages kept for bob")
        assert 0 < len(queued) <= 50
        assert "offline queue of" in broker.output()
