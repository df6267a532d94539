"""Security matrix: principal x topic class x action, on the embedded broker and on a real Mosquitto.

Both brokers enforce the rules of robots.yaml: the embedded one through its ACL plugin, Mosquitto
through the files ``roslink-mqtt acl export`` writes. For each backend one broker runs for the
whole module and every principal connects once; all cases are observed in one pass (retained
phase, live phase, publish phase) and the parametrized tests below only look the results up.

Actions per (principal, topic class):

* ``publish``   the principal publishes; an admin observer subscribed to ``#`` sees it or not
* ``subscribe`` SUBACK for the exact topic as filter (Mosquitto 2.0 grants every filter and
  filters on delivery; the embedded broker refuses filters that cannot match anything readable)
* ``receive``   a live message published by admin arrives (through the exact filter or any of
  the wildcard filters the principal also holds: ``#``, ``roslink/#``, ...)
* ``retained``  a retained message set before the principal subscribed arrives

A final sweep checks every message any principal received against an independent oracle
written from broker/README.md ("What it enforces"): zero leaks.
"""

from __future__ import annotations

import queue
import shutil
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest

from roslink_mqtt.localproc import Mosquitto
from roslink_mqtt.mqtt import make_client
from tests.support.acl_matrix import (
    ACTIONS,
    BACKENDS,
    CLASSES,
    EXPECTED,
    LOGINS,
    MOSQUITTO_GRANTS_EVERY_FILTER,
    NEVER_RETAINED_EMBEDDED,
    PRINCIPALS,
    SELF,
    WILDCARDS,
    dynsec_presence,
    matches,
    may_read,
    may_write,
    topic_of,
)
from tests.support.broker_setup import ExportedMosquitto
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.procs import DEMO_PASSWORDS
from tests.support.waits import wait_until

# -- running the matrix ---------------------------------------------------------------------


@dataclass
class Msg:
    topic: str
    payload: bytes
    retain: bool


class Conn:
    """One paho connection (TCP_NODELAY via make_client); never retries a refused login."""

    def __init__(self, port: int, username: str | None, password: str | None, client_id: str) -> None:
        self.client = make_client(client_id, username=username, password=password, url=f"mqtt://127.0.0.1:{port}")
        self.port = port
        self.messages: queue.Queue[Msg] = queue.Queue()
        self._connack: queue.Queue[int] = queue.Queue()
        self._subacks: dict[int, list[int]] = {}
        self._suback_ready = threading.Condition()
        self.client.on_connect = self._on_connect
        self.client.on_message = lambda c, u, m: self.messages.put(Msg(m.topic, m.payload, bool(m.retain)))
        self.client.on_subscribe = self._on_subscribe

    def _on_connect(self, client, _u, _f, rc, _p) -> None:
        if rc.is_failure:
            client.disconnect()  # no automatic retry: a refused login stays refused
        self._connack.put(rc.value)

    def _on_subscribe(self, _c, _u, mid, codes, _p) -> None:
        with self._suback_ready:
            self._subacks[mid] = [c.value for c in codes]
            self._suback_ready.notify_all()

    def connect(self) -> int:
        self.client.connect("127.0.0.1", self.port, keepalive=30)
        self.client.loop_start()
        return self._connack.get(timeout=10)

    def subscribe(self, filters: list[str]) -> dict[str, int]:
        _, mid = self.client.subscribe([(f, 1) for f in filters])
        with self._suback_ready:
            assert self._suback_ready.wait_for(lambda: mid in self._subacks, 10), "no SUBACK"
            return dict(zip(filters, self._subacks.pop(mid), strict=True))

    def publish_all(self, items: list[tuple[str, bytes, bool]]) -> None:
        infos = [self.client.publish(t, p, qos=1, retain=r) for t, p, r in items]
        for info in infos:
            info.wait_for_publish(10)

    def received(self) -> list[Msg]:
        out = []
        while True:
            try:
                out.append(self.messages.get_nowait())
            except queue.Empty:
                return out

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


@dataclass
class Run:
    backend: str
    port: int
    connack: dict[str, int] = field(default_factory=dict)
    suback: dict[str, dict[str, int]] = field(default_factory=dict)
    received: dict[str, list[Msg]] = field(default_factory=dict)
    observed: list[Msg] = field(default_factory=list)
    checked: set[tuple] = field(default_factory=set)


def settle(conns: list[Conn], minimum: float, quiet: float = 0.5, maximum: float = 15.0) -> None:
    """Wait at least ``minimum`` s, then until no connection got anything for ``quiet`` s (a slow,
    busy host delays messages; it must not turn an expected delivery into a 'denied')."""
    start = last_change = time.monotonic()
    sizes = [c.messages.qsize() for c in conns]

    def settled() -> bool:  # true at ``maximum`` at the latest: settling never fails, it only stops waiting
        nonlocal sizes, last_change
        now = time.monotonic()
        current = [c.messages.qsize() for c in conns]
        if current != sizes:
            sizes, last_change = current, now
        return (now - start >= minimum and now - last_change >= quiet) or now - start >= maximum

    wait_until("the connections to settle", settled, timeout=maximum + 10)


def exact_filter(cls: str, me: str) -> str:
    return topic_of(cls, me)


def run_matrix(backend: str, port: int) -> Run:
    run = Run(backend, port)
    universe = sorted({topic_of(c, SELF[p]) for p in PRINCIPALS for c in CLASSES if c != "$SYS"})
    admin = Conn(port, "admin", DEMO_PASSWORDS["admin"], f"matrix-setup-{backend}")
    assert admin.connect() == 0
    admin.publish_all([(t, f"R|{t}".encode(), True) for t in universe])  # the retained phase's messages

    conns: dict[str, Conn] = {}
    for p in PRINCIPALS:
        conn = Conn(port, *LOGINS[p], client_id=f"matrix-{backend}-{p}")
        run.connack[p] = conn.connect()
        if run.connack[p] == 0:
            conns[p] = conn
        else:
            conn.client.loop_stop()
    for p, conn in conns.items():
        run.suback[p] = conn.subscribe(sorted({exact_filter(c, SELF[p]) for c in CLASSES} | set(WILDCARDS)))
    settle(list(conns.values()), minimum=0.5)  # retained messages arrive after SUBACK

    observer = Conn(port, "admin", DEMO_PASSWORDS["admin"], f"matrix-observer-{backend}")
    assert observer.connect() == 0
    observer.subscribe(["#", "$SYS/#"])
    admin.publish_all([(t, f"L|{t}".encode(), False) for t in universe])  # the live phase
    for p, conn in conns.items():
        conn.publish_all([(topic_of(c, SELF[p], publish=True), f"P|{p}|{c}".encode(), False) for c in CLASSES])
    # at least one $SYS interval (1 s on both brokers), and every publish has gone through
    settle([*conns.values(), observer], minimum=1.2)

    for p, conn in conns.items():
        run.received[p] = conn.received()
        conn.close()
    run.observed = observer.received()
    observer.close()
    admin.close()
    return run


@pytest.fixture(scope="module")
def embedded(acl_embedded: EmbeddedBrokerProcess) -> EmbeddedBrokerProcess:
    return acl_embedded  # shared with test_broker_mqtt_conformance.py (tests/integration/conftest.py)


@pytest.fixture(scope="module")
def mosquitto(acl_mosquitto: ExportedMosquitto) -> ExportedMosquitto:
    return acl_mosquitto


RUNS: dict[str, Run] = {}
PORTS: dict[str, int] = {}  # backend → port, set by the runs fixture


@pytest.fixture(scope="module")
def runs(request, embedded: EmbeddedBrokerProcess, mosquitto: ExportedMosquitto,
         acl_mosquitto_dynsec: Mosquitto) -> Iterator[dict[str, Run]]:
    PORTS.update({"embedded": embedded.port, "mosquitto": mosquitto.port,
                  "mosquitto-dynsec": acl_mosquitto_dynsec.port})
    ports = PORTS
    threads = [threading.Thread(target=lambda b=b: RUNS.__setitem__(b, run_matrix(b, ports[b]))) for b in BACKENDS]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert set(RUNS) == set(BACKENDS), "a matrix run failed; see the log above"
    yield RUNS
    total = sum(len(r.checked) for r in RUNS.values())
    leaks = sum(len(leaks_of(r, b)) for b, r in RUNS.items())
    line = (f"security matrix: {total} cases checked ("
            + ", ".join(f"{b} {len(RUNS[b].checked)}" for b in BACKENDS) + f"), {leaks} leaks")
    capture = request.config.pluginmanager.get_plugin("capturemanager")
    with capture.global_and_fixture_disabled():  # show it even without -s
        print(f"\n{line}")


def _got(run: Run, p: str, predicate) -> bool:
    return any(predicate(m) for m in run.received.get(p, ()))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("principal", PRINCIPALS)
@pytest.mark.parametrize("cls", CLASSES)
@pytest.mark.parametrize("action", ACTIONS)
def test_matrix(runs: dict[str, Run], backend: str, principal: str, cls: str, action: str) -> None:
    run = runs[backend]
    exp = EXPECTED[principal].get(cls, "")
    me = SELF[principal]
    connected = run.connack[principal] == 0
    if principal in ("wrong-password", "anonymous"):
        assert not connected, f"{principal} was let in"
        assert run.connack[principal] == 135  # CONNACK 5, not authorized
        outcome = False
    elif action == "publish":
        marker = f"P|{principal}|{cls}".encode()
        outcome = any(m.payload == marker for m in run.observed)
    elif action == "subscribe":
        outcome = run.suback[principal][exact_filter(cls, me)] < 128
    elif action == "receive":
        if cls == "$SYS":
            outcome = _got(run, principal, lambda m: m.topic.startswith("$SYS/") and not m.retain)
        else:
            topic = topic_of(cls, me)
            outcome = _got(run, principal, lambda m: m.topic == topic and m.payload == f"L|{topic}".encode())
    else:  # retained
        topic = topic_of(cls, me)
        want = None if cls == "$SYS" else f"R|{topic}".encode()
        outcome = _got(run, principal, lambda m: m.topic == topic and m.retain and want in (None, m.payload))

    if action == "publish":
        expected = "w" in exp
    elif action == "subscribe" and backend.startswith("mosquitto") and connected:
        expected = MOSQUITTO_GRANTS_EVERY_FILTER or "r" in exp
    elif action == "retained" and backend == "embedded" and cls.split("@")[0] in NEVER_RETAINED_EMBEDDED:
        expected = False
    elif action in ("receive", "retained") and backend == "mosquitto-dynsec" and connected and cls != "$SYS" \
            and dynsec_presence(principal, topic_of(cls, me)):
        expected = True
    else:
        expected = "r" in exp
    run.checked.add((principal, cls, action))
    assert outcome is expected, f"{backend}: {principal} {action} {topic_of(cls, me)}: expected {expected}"


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("principal", [p for p in PRINCIPALS if p in DEMO_PASSWORDS])
@pytest.mark.parametrize("flt", WILDCARDS)
def test_wildcard_subscriptions(runs: dict[str, Run], backend: str, principal: str, flt: str) -> None:
    """Embedded: a filter is granted iff it can match something readable. Mosquitto grants all."""
    run = runs[backend]
    universe = {topic_of(c, SELF[p]) for p in PRINCIPALS for c in CLASSES}
    readable_match = any(matches(flt, t) and may_read(principal, t) for t in universe)
    expected = True if backend.startswith("mosquitto") and MOSQUITTO_GRANTS_EVERY_FILTER else readable_match
    run.checked.add((principal, flt, "subscribe-wildcard"))
    assert (run.suback[principal][flt] < 128) is expected


def leaks_of(run: Run, backend: str) -> list[tuple[str, str, str]]:
    """(principal, action, topic) for every message received that may not be read, and every
    publish that reached the observer although the publisher may not write there."""
    def readable(p: str, topic: str) -> bool:
        return may_read(p, topic) or (backend == "mosquitto-dynsec" and dynsec_presence(p, topic))

    leaks = [(p, "receive", m.topic) for p, msgs in run.received.items() for m in msgs if not readable(p, m.topic)]
    for m in run.observed:
        if m.payload.startswith(b"P|"):
            p = m.payload.decode().split("|")[1]
            if not may_write(p, m.topic):
                leaks.append((p, "publish", m.topic))
    return leaks


@pytest.mark.parametrize("backend", BACKENDS)
def test_zero_leaks(runs: dict[str, Run], backend: str) -> None:
    """Every message any principal received is one it may read; every publish seen was allowed."""
    run = runs[backend]
    assert leaks_of(run, backend) == []
    assert sum(len(v) for v in run.received.values()) > 100  # the matrix did deliver things


# -- a few cases with the real mosquitto_sub / mosquitto_pub clients --------------------------

MOSQUITTO_SUB = shutil.which("mosquitto_sub")
MOSQUITTO_PUB = shutil.which("mosquitto_pub")
needs_clients = pytest.mark.skipif(not (MOSQUITTO_SUB and MOSQUITTO_PUB), reason="mosquitto-clients not installed")


def _port(backend: str, embedded: EmbeddedBrokerProcess, mosquitto: ExportedMosquitto) -> int:
    return PORTS[backend]


def _sub(port: int, user: str | None, password: str | None, *args: str,
         timeout: float = 2) -> subprocess.CompletedProcess:
    auth = ["-u", user, "-P", password] if user else []
    return subprocess.run([MOSQUITTO_SUB, "-h", "127.0.0.1", "-p", str(port), *auth, "-v", "-W", str(int(timeout)),
                           *args], capture_output=True, text=True, timeout=timeout + 10)


@needs_clients
@pytest.mark.parametrize("backend", BACKENDS)
def test_mosquitto_sub_sees_only_its_robot(runs, embedded, mosquitto, backend: str) -> None:
    port = _port(backend, embedded, mosquitto)
    out = _sub(port, "bob", DEMO_PASSWORDS["bob"], "-t", "roslink/#", timeout=1).stdout
    topics = {line.split(" ", 1)[0] for line in out.splitlines()}
    assert "roslink/turtle1/heartbeat" in topics and "roslink/turtle1/state/matrix" in topics
    assert "roslink/turtle1/to/bob/reply/reset" in topics
    assert all(may_read("bob", t) for t in topics), topics
    assert not any(t.startswith("roslink/turtle2/") for t in topics)


@needs_clients
@pytest.mark.parametrize("backend", BACKENDS)
def test_mosquitto_pub_commands_only_as_allowed(runs, embedded, mosquitto, backend: str) -> None:
    port = _port(backend, embedded, mosquitto)
    watch = Conn(port, "turtle1", DEMO_PASSWORDS["turtle1"], f"cli-watch-{backend}")  # the robot's view
    assert watch.connect() == 0
    watch.subscribe(["roslink/turtle1/from/+/#"])
    for user, topic in (("alice", "roslink/turtle1/from/alice/cmd/twist"),  # operator: allowed
                        ("bob", "roslink/turtle1/from/bob/cmd/twist"),  # viewer: refused
                        ("bob", "roslink/turtle1/from/bob/call/status"),  # viewer, read-only service: allowed
                        ("carol", "roslink/turtle1/from/carol/cmd/twist"),  # not granted turtle1: refused
                        ("alice", "roslink/turtle1/from/bob/cmd/twist")):  # impersonation: refused
        done = subprocess.run([MOSQUITTO_PUB, "-h", "127.0.0.1", "-p", str(port), "-u", user, "-P",
                               DEMO_PASSWORDS[user], "-q", "1", "-t", topic, "-m", f"cli-{user}"],
                              capture_output=True, text=True, timeout=10)
        assert done.returncode == 0, done.stderr  # MQTT 3.1.1 has no publish NACK: refused = dropped
    settle([watch], minimum=0.3)
    watch.close()
    got = sorted(f"{m.topic} {m.payload.decode()}" for m in watch.received() if m.payload.startswith(b"cli-"))
    assert got == ["roslink/turtle1/from/alice/cmd/twist cli-alice", "roslink/turtle1/from/bob/call/status cli-bob"]


@needs_clients
@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("user,password", [("alice", "wrong"), (None, None), ("mallory", "x")])
def test_mosquitto_sub_refused_logins(runs, embedded, mosquitto, backend: str, user, password) -> None:
    done = _sub(_port(backend, embedded, mosquitto), user, password, "-t", "#", timeout=1)
    assert done.returncode != 0
    assert "not authori" in done.stderr.lower()
    assert done.stdout == ""
