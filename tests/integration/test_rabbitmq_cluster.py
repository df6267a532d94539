"""A real three-node RabbitMQ cluster (Debian's rabbitmq-server 3.10, MQTT plugin) running the fleet.

The fleet's logins and ACLs come from ``roslink-mqtt acl export --format rabbitmq``; the nodes run on 127.0.0.1
with their own names, ports and data (roslink_mqtt/rabbit_cluster.py) and are stopped at the end. The bridge
starts on node 1, the operator on node 2, the viewer on node 3: state must reach the viewer, commands the robot,
stops must work, the ACL matrix must hold on every node, and killing the node the bridge and operator are on
must stop the robot and bring both back through another node within 5 s.
"""

from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from contextlib import ExitStack

import paho.mqtt.client as mqtt
import pytest

from roslink_mqtt.bridge.core.claim import EXIT_DUPLICATE
from roslink_mqtt.client import RobotClient
from roslink_mqtt.config.split import split_fleet
from roslink_mqtt.rabbit_cluster import RABBIT_BIN, RabbitCluster, rabbitmq_available
from tests.support.acl_matrix import CLASSES, EXPECTED, LOGINS, PRINCIPALS, SELF, may_read, topic_of
from tests.support.broker_setup import write_fleet
from tests.support.failover import drive, kill_and_measure, moving, zero
from tests.support.fleet_apply import Apply
from tests.support.measure import record_measurement
from tests.support.mqtt_client import TestClient
from tests.support.procs import DEMO_PASSWORDS, ROOT, bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced, wait_until

pytestmark = [pytest.mark.timeout(300), pytest.mark.cluster]

HEARTBEAT_PERIOD = 1.0  # the demo fleet's: presence must converge within one period on any node


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    if not rabbitmq_available():
        pytest.fail("rabbitmq-server is not installed: `apt-get install rabbitmq-server` (.ci/run does it)")
    work = tmp_path_factory.mktemp("rabbit")
    # the description and access reports re-published every 2 s: clients on other nodes than the bridge's get them
    period = "      heartbeat_period: 1.0\n"
    fleet = write_fleet(work, edit=lambda text: text.replace(period, period + "      retained_refresh: 2\n", 1))
    passwords = work / "passwords.yaml"
    passwords.write_text("".join(f"{k}: {v}\n" for k, v in DEMO_PASSWORDS.items()))
    export = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "acl", "export", "--format", "rabbitmq",
                             "--config", str(fleet), "--passwords", str(passwords), "--out", str(work / "export")],
                            capture_output=True, text=True, cwd=ROOT)
    assert export.returncode == 0, export.stderr
    rabbit = RabbitCluster(work / "cluster", work / "export")
    with ExitStack() as exits:
        exits.callback(rabbit.stop)
        took = rabbit.start()
        rabbit.wait_for_login("admin", DEMO_PASSWORDS["admin"])
        print(f"three RabbitMQ nodes up and clustered in {took:.1f} s", file=sys.stderr)
        assert len(rabbit.running_nodes()) == 3
        rabbit.fleet = fleet
        yield rabbit


@pytest.fixture(scope="module")
def probe():
    from geometry_msgs.msg import Twist

    p = RosProbe()
    p.cmd_vel = p.watch(Twist, "/cmd_vel")
    yield p
    p.close()


def _urls(rabbit: RabbitCluster, first: int) -> str:
    """Every node, starting with ``first``: a client's failover list."""
    order = rabbit.nodes[first:] + rabbit.nodes[:first]
    return ",".join(n.url for n in order)


def start_robot(exits: ExitStack, cluster: RabbitCluster, tmp_path, operator_node: int) -> RobotClient:
    """The sim, its bridge on node 1 (all nodes listed from there), and alice on ``operator_node`` (index)."""
    exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
    exits.enter_context(run([*bridge_args("turtle1", 0, config=cluster.fleet)[:-1], _urls(cluster, 0)],
                            tmp_path / "bridge.log", bridge_env("turtle1")))
    alice = exits.enter_context(RobotClient("alice", "alice-demo", url=_urls(cluster, operator_node),
                                            robots=["turtle1"]))
    alice.wait_for_robot("turtle1", timeout=60)
    return alice


def test_state_commands_and_stops_across_three_nodes(cluster, probe, tmp_path) -> None:
    stop = threading.Event()
    with ExitStack() as exits:
        alice = start_robot(exits, cluster, tmp_path, 1)
        # the viewer on node 3 connects once the robot is up: no retained heartbeat reaches it from node 1's
        # store, so presence must come from the next live heartbeat
        t0 = time.monotonic()
        bob = exits.enter_context(RobotClient("bob", "bob-demo", url=_urls(cluster, 2), robots=["turtle1"]))
        bob.wait_for_robot("turtle1", timeout=5)
        converged = time.monotonic() - t0
        record_measurement("cluster: viewer on node 3 sees the robot on node 1", converged, HEARTBEAT_PERIOD + 1.0)
        assert converged <= HEARTBEAT_PERIOD + 1.0
        assert alice.connection.url.port == cluster.nodes[1].mqtt_port
        assert bob.connection.url.port == cluster.nodes[2].mqtt_port
        assert bob.wildcard_heartbeats is False  # RabbitMQ refuses roslink/+/heartbeat to a viewer: coped with
        motion = bob.subscribe("turtle1", "global_motion")
        assert motion.get(timeout=10) is not None  # state from node 1 reached node 3
        # retained on node 1 only; re-published every retained_refresh (2 s), so node 3 has it within that
        assert bob.description("turtle1", timeout=2 + 1.5).robot == "turtle1"
        # a second bridge for turtle1 on node 3, whose retained store holds no heartbeat of it: the live bridge on
        # node 1 answers its claim across the cluster, and it refuses to start (one live bridge per robot)
        second = exits.enter_context(run([*bridge_args("turtle1", 0, config=cluster.fleet)[:-1], _urls(cluster, 2)],
                                         tmp_path / "second-bridge.log", bridge_env("turtle1")))
        assert second.popen.wait(timeout=30) == EXIT_DUPLICATE, second.output()
        assert "already has a live bridge" in second.output()

        exits.callback(stop.set)
        t0 = time.monotonic()
        driver = drive(alice, "turtle1", stop)
        probe.cmd_vel.wait_for(moving, timeout=20, after=t0)  # commands from node 2 reached the robot
        # the viewer as attacker, from every node: commands it may not send and another user's replies; RabbitMQ
        # closes only the viewer's own connections, and the robot keeps obeying its operator
        attack = time.monotonic()
        for i in range(12):
            rogue = Probe(cluster.nodes[i % 3].mqtt_port, LOGINS["bob"], "rogue")
            assert rogue.connect() == 0
            if i % 2:
                assert rogue.publish("roslink/turtle1/from/bob/cmd/twist", b'{"lx": 1.0}') is False
            else:
                assert rogue.subscribe(["roslink/turtle1/to/alice/#"]) is False
            rogue.close()
        never("the viewer's attempts stopping the robot",
              lambda: any(zero(m) for _, m in probe.cmd_vel.since(attack)), seconds=0.5)
        assert alice.connection.connected.is_set()
        assert "lost the broker" not in (tmp_path / "bridge.log").read_text()
        stop.set()
        driver.join()
        silent = time.monotonic()
        at, _ = probe.cmd_vel.wait_for(zero, timeout=5, after=silent)
        record_measurement("cluster: operator stream silent → zero twist (dead-man)", at - silent, 1.0 + 0.5)
        assert at - silent <= 1.5


# -- the ACL matrix, on the cluster ------------------------------------------------------------------------------


class Probe:
    """One connection that reports how it ended: RabbitMQ closes a connection over a refused act."""

    def __init__(self, port: int, login: tuple[str | None, str | None], tag: str) -> None:
        user, password = login
        # no reconnect: a connection the broker closed stays closed, and its network thread ends at once
        self.client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"m-{tag}-{time.monotonic_ns()}",
                                  protocol=mqtt.MQTTv311, reconnect_on_failure=False)
        if user is not None:
            self.client.username_pw_set(user, password)
        self.port, self.messages, self.connack = port, queue.Queue(), queue.Queue()
        self.closed, self.subacks, self.acked = threading.Event(), queue.Queue(), set()
        self.client.on_connect = lambda c, u, f, rc, p: self.connack.put(rc.value)
        self.client.on_disconnect = lambda *a: self.closed.set()
        self.client.on_message = lambda c, u, m: self.messages.put((m.topic, m.payload))
        self.client.on_subscribe = lambda c, u, mid, codes, p: self.subacks.put([x.value for x in codes])
        self.client.on_publish = lambda c, u, mid, rc, p: self.acked.add(mid)

    def connect(self) -> int:
        self.client.connect("127.0.0.1", self.port, keepalive=30)
        self.client.loop_start()
        return self.connack.get(timeout=10)

    def subscribe(self, filters: list[str]) -> bool:
        """True: granted; False: the broker closed the connection (its answer to a refused filter)."""
        self.client.subscribe([(f, 1) for f in filters])
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if self.closed.is_set():
                return False
            try:
                return all(code < 0x80 for code in self.subacks.get(timeout=0.05))
            except queue.Empty:
                pass
        raise AssertionError(f"neither SUBACK nor a closed connection for {filters}")

    def publish(self, topic: str, payload: bytes = b"matrix") -> bool:
        """True: PUBACKed; False: the broker closed the connection instead (a refused publish)."""
        mid = self.client.publish(topic, payload, qos=1).mid
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if mid in self.acked:
                return True
            if self.closed.wait(0.05):
                return False
        raise AssertionError(f"neither PUBACK nor a closed connection for {topic}")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def test_acl_matrix_on_every_node(cluster) -> None:
    """Each principal on its own node: may it log in, subscribe, receive, publish — as EXPECTED says."""
    nodes = [n.mqtt_port for n in cluster.nodes]
    observer = Probe(nodes[2], LOGINS["admin"], "observer")
    assert observer.connect() == 0 and observer.subscribe(["#"])
    admin = Probe(nodes[0], LOGINS["admin"], "admin")
    assert admin.connect() == 0
    listeners, checked, wrong, refused_payloads = [], 0, [], set()
    for i, p in enumerate(PRINCIPALS):
        port, me = nodes[i % 3], SELF[p]
        first = Probe(port, LOGINS[p], p)
        code = first.connect()
        checked += 1
        if p in ("wrong-password", "anonymous"):
            assert code != 0, f"{p} logged in"
            first.close()
            continue
        assert code == 0, f"{p} refused on node {i % 3 + 1}"
        readable = [c for c in CLASSES if c != "$SYS" and "r" in EXPECTED[p].get(c, "")]
        if readable:  # what it may read, in one SUBSCRIBE: granted as a whole
            assert first.subscribe([topic_of(c, me) for c in readable]), f"{p}: readable filters refused"
            listeners.append((p, first, {topic_of(c, me) for c in readable}))
        else:
            first.close()
        for cls in CLASSES:
            if cls == "$SYS":
                continue
            rights = EXPECTED[p].get(cls, "")
            if "r" not in rights:  # a refused filter: RabbitMQ closes the connection (no SUBACK 0x80)
                one = Probe(port, LOGINS[p], p)
                assert one.connect() == 0
                if one.subscribe([topic_of(cls, me)]):
                    wrong.append((p, cls, "subscribe granted"))
                one.close()
                checked += 1
            one = Probe(port, LOGINS[p], p)
            assert one.connect() == 0
            payload = f"P|{p}|{cls}".encode()
            if one.publish(topic_of(cls, me, publish=True), payload) != ("w" in rights):
                wrong.append((p, cls, "publish"))
            if "w" not in rights:
                refused_payloads.add(payload)
            one.close()
            checked += 1
    # live delivery across nodes: admin publishes every topic on node 1; each principal gets what it subscribed
    # and may read, nothing else
    universe = sorted({topic_of(c, SELF[p]) for p in PRINCIPALS for c in CLASSES if c != "$SYS"})
    for topic in universe:
        assert admin.publish(topic, b"L")
    published = time.monotonic()
    want = {p: {t for t in universe if t in subscribed and may_read(p, t)} for p, _, subscribed in listeners}
    got: dict[str, set[str]] = {p: set() for p in want}

    def collect() -> None:
        for p, conn, _ in listeners:
            got[p] |= {t for t, payload in _drain(conn.messages) if payload == b"L"}

    def missing() -> list[str]:
        collect()
        return [p for p in want if not want[p] <= got[p]]

    def extra() -> list[str]:
        collect()
        return [p for p in want if got[p] - want[p]]

    try:
        wait_until("every principal's deliveries", lambda: not missing(), timeout=20)
    except AssertionError:
        pass  # what did not come is listed with the rest of what is wrong, below
    # what may not be read: nothing of it within a second of the publishes (the old window, from the same start)
    try:
        never("a delivery beyond what a principal may read", extra,
              seconds=max(0.0, published + 1.0 - time.monotonic()))
    except AssertionError:
        pass  # listed with the rest of what is wrong, below (and the connections closed first)
    for p, conn, _ in listeners:
        if got[p] != want[p]:
            wrong.append((p, "receive", sorted(got[p] ^ want[p])))
        checked += len(universe)
        conn.close()
    leaked = [(t, payload) for t, payload in _drain(observer.messages) if payload in refused_payloads]
    wrong += [("observer", "refused publish delivered", item) for item in leaked]
    observer.close()
    admin.close()
    print(f"cluster ACL matrix: {checked} cases on 3 nodes, {len(wrong)} wrong", file=sys.stderr)
    assert wrong == []


def _drain(q: queue.Queue) -> list:
    out = []
    while not q.empty():
        out.append(q.get())
    return out


def test_fleet_apply_changes_users_and_grants_across_the_cluster(cluster, probe, tmp_path) -> None:
    """``fleet apply --broker-kind rabbitmq``: the bridge (on node 1, from its robot file) has no grants until apply
    publishes them on every node; a user added then drives from node 2; revoked while driving, the robot stops at
    once and RabbitMQ closes the user's connection. Leaves the cluster's users as it found them."""
    fleet = tmp_path / "robots.yaml"
    fleet.write_text(cluster.fleet.read_text())
    robot_file = split_fleet(fleet, tmp_path / "robot-files", ["turtle1"])[0]
    node1, node2 = cluster.nodes[0], cluster.nodes[1]
    ctl = ("--broker-kind", "rabbitmq", "--rabbitmqctl", f"{RABBIT_BIN / 'rabbitmqctl'} -n {node1.name}")
    passwords = tmp_path / "passwords.yaml"
    passwords.write_text("{}\n")
    options = (*ctl, "--passwords", str(passwords))

    def edit(*args: str) -> None:
        done = subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", "fleet", *args, "--config", str(fleet)],
                              capture_output=True, text=True, cwd=ROOT, timeout=60)
        assert done.returncode == 0, done.stderr

    stop = threading.Event()
    with ExitStack() as exits:
        exits.callback(stop.set)
        exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        bridge = exits.enter_context(run([*bridge_args("turtle1", 0, config=robot_file)[:-1], _urls(cluster, 0)],
                                         tmp_path / "bridge.log", bridge_env("turtle1")))
        alice = exits.enter_context(TestClient(node1.mqtt_port, "alice", "alice-demo", operator=True))
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/to/alice/error")
        deadline = time.monotonic() + 60
        try:
            wait_until("the bridge to connect", lambda: "viewer link" in bridge.output()
                       or "connected" in bridge.output(), timeout=60, period=0.2)
        except AssertionError as err:
            raise AssertionError(bridge.output()) from err
        refusal = None
        while refusal is None:  # until the bridge hears alice: it has no grants, and says so
            alice.publish("roslink/turtle1/from/alice/cmd/twist", {"lx": 0.1})
            try:
                refusal = alice.wait_for(lambda m: "has no grants from the broker yet" in m.json().get("error", ""),
                                         timeout=1)
            except TimeoutError:
                assert time.monotonic() < deadline, bridge.output()
        first = Apply(fleet, _urls(cluster, 0), *options, env=node1.env)
        assert first.output.count("bridge   turtle1: grants published") == 3, first.output  # one per node
        assert "nothing to change" in first.output

        edit("user", "add", "dave", "--password-file", str(tmp_path / "dave.password"), "--iterations", "1000")
        edit("grant", "dave", "turtle1")
        password = (tmp_path / "dave.password").read_text().strip()
        passwords.write_text(f"dave: {password}\n")
        added = Apply(fleet, _urls(cluster, 0), *options, env=node1.env)
        assert "add      dave" in added.output and "acl      turtle1" in added.output, added.output
        dave = exits.enter_context(TestClient(node2.mqtt_port, "dave", password, operator=True))
        assert dave.connect() == 0
        t0 = time.monotonic()

        def stream() -> None:
            for _ in paced(0.05, within=300, stop=stop.is_set):  # 300 s: the test's own timeout
                dave.publish("roslink/turtle1/from/dave/cmd/twist", {"lx": 0.27}, qos=0)

        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        drove_at, _ = probe.cmd_vel.wait_for(lambda m: m.linear.x == pytest.approx(0.27), after=t0, timeout=15)
        record_measurement("cluster: fleet apply adds a user, who drives from node 2 (from apply's start)",
                           drove_at - added.started, 30.0)
        assert added.planned is not None
        record_measurement("cluster: fleet apply adds a user, who drives from node 2 (after the plan was printed)",
                           drove_at - added.planned, 3.0)
        assert drove_at - added.planned < 3.0
        closed = threading.Event()
        dave.client.on_disconnect = lambda *a: closed.set()

        edit("revoke", "dave", "turtle1")
        revoked = Apply(fleet, _urls(cluster, 0), *options, env=node1.env)
        assert revoked.planned is not None
        stopped_at, _ = probe.cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0,
                                               after=revoked.planned, timeout=10)
        assert closed.wait(10), f"RabbitMQ did not close the revoked user's connection:\n{revoked.output}"
        closed_at = time.monotonic()
        never("a non-zero twist reaching the robot after the revocation",
              lambda: [m for _, m in probe.cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0], seconds=1.0)
        stop.set()
        streamer.join()
        record_measurement("cluster: fleet apply revokes a driver: the robot stops, after the plan was printed",
                           stopped_at - revoked.planned, 1.0)
        record_measurement("cluster: fleet apply revokes a driver: RabbitMQ closes their connection (rabbitmqctl)",
                           closed_at - revoked.planned, 10.0)
        assert stopped_at - revoked.planned < 1.0
        late = [m for _, m in probe.cmd_vel.since(stopped_at + 0.1) if m.linear.x != 0]
        assert not late, f"{len(late)} non-zero twists reached the robot after the revocation"

        edit("user", "remove", "dave")
        removed = Apply(fleet, _urls(cluster, 0), *options, env=node1.env)
        assert "remove   dave" in removed.output
        assert "dave" not in cluster.ctl("list_users")


def test_killing_the_node_the_bridge_and_operator_are_on(cluster, probe, tmp_path) -> None:
    """Last in the module: it takes node 1 down. The robot stops; both are back via another node within 5 s."""
    stop = threading.Event()
    with ExitStack() as exits:
        alice = start_robot(exits, cluster, tmp_path, 0)
        exits.callback(stop.set)
        t0 = time.monotonic()
        drive(alice, "turtle1", stop)
        probe.cmd_vel.wait_for(moving, timeout=20, after=t0)
        assert alice.connection.url.port == cluster.nodes[0].mqtt_port
        kill_and_measure(probe.cmd_vel, cluster.nodes[0].kill, "RabbitMQ cluster node")
        assert alice.connection.url.port != cluster.nodes[0].mqtt_port
        assert f"lost the broker {cluster.nodes[0].url}" in (tmp_path / "bridge.log").read_text()
