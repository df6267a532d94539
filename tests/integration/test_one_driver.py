"""One bridge and one driver per robot, with real processes on the embedded broker and on the exported Mosquitto.

One stack per broker (broker, simulated turtle1 and its bridge, turtle2's bridge in a namespace of its own) plays
what the issue measured and what must hold now: a second bridge refused (and, at the end, ``--take-over`` fencing
the live one), two operators racing (only the holder's twists reach ``/cmd_vel``;
the other learns who drives within 1 s), a take-over that stops the robot and tells the old holder, a supervisor's
claim, a viewer's emergency stop that nobody but the holder can resume, the holder SIGKILLed (robot stopped, lease
kept by its user until their last client goes), claim then drive as one user (a ``pub`` beside ``control claim``),
and ``roslink-mqtt estop --all`` across two robots. The decisions themselves are unit-tested in
tests/unit/test_control_lease.py.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
from contextlib import ExitStack
from pathlib import Path

import pytest

from roslink_mqtt.bridge.core.claim import EXIT_DUPLICATE, EXIT_FENCED
from roslink_mqtt.protocol import encode_message
from roslink_mqtt.protocol.lease import ControlState
from tests.support.broker_setup import ExportedMosquitto, write_fleet
from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.measure import record_measurement
from tests.support.mqtt_client import Received, TestClient
from tests.support.procs import ROOT, bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced

pytestmark = pytest.mark.timeout(240)

SUPERVISED = "    type: ground\n    # password: turtle1-demo\n"
LEARN_WHO_WITHIN = 1.0  # s: the promise to a user who tries to drive a robot someone else drives


def _supervisors(text: str) -> str:
    head, sep, tail = text.partition(SUPERVISED)
    assert sep, "the demo fleet's turtle1 changed: update SUPERVISED"
    return head + "    type: ground\n    supervisors: [admin]\n    # password: turtle1-demo\n" + tail


@pytest.fixture(scope="module")
def probe():
    from geometry_msgs.msg import Twist
    from std_msgs.msg import Bool

    p = RosProbe()
    p.cmd_vel = p.watch(Twist, "/cmd_vel")
    p.estop = p.watch(Bool, "/emergency_stop")
    yield p
    p.close()


class Driver(TestClient):
    """An operator program: presence, and twists whose lx says who sent them."""

    seq = 0

    def twist(self, lx: float) -> None:
        Driver.seq += 1
        self.publish(f"roslink/turtle1/from/{self.username}/cmd/twist",
                     encode_message(100, {"lx": lx}, sequence_number=Driver.seq, client_id=self.client_id), qos=0)

    def control(self, op: str) -> None:
        self.publish(f"roslink/turtle1/from/{self.username}/control/{op}", b"")

    def error(self, contains: str, timeout: float = 10.0) -> Received:
        return self.wait_for(lambda m: m.topic.endswith(f"/to/{self.username}/error")
                             and contains in m.json()["error"], timeout=timeout)


def _driver(port: int, user: str, stack: ExitStack) -> Driver:
    d = Driver(port, user, f"{user}-demo", operator=True)
    d.username = user
    assert d.connect() == 0
    stack.callback(d.close)
    d.subscribe(f"roslink/turtle1/to/{user}/#")
    return d


def _what_people_see(port: int) -> None:
    robots = _cli(port, "bob", "robots", "turtle1", "--wait", "0.5")
    assert robots.returncode == 0 and re.search(r"turtle1 .* admin \(supervisor\) since \d\d:\d\d:\d\d",
                                                robots.stdout), robots
    info = _cli(port, "bob", "info", "turtle1")
    assert "control: driven by admin (supervisor) since" in info.stdout and \
        "emergency stop: every granted user" in info.stdout, info.stdout + info.stderr
    pub = _cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.4}')
    assert pub.returncode == 1 and "turtle1 is driven by admin (supervisor) since" in pub.stdout \
        and "only another supervisor" in pub.stdout, pub.stdout + pub.stderr
    claim = _cli(port, "alice", "control", "take-over", "turtle1")
    assert claim.returncode == 1 and "refused" in claim.stderr and "only another supervisor" in claim.stderr, claim
    status = _cli(port, "bob", "control", "status", "turtle1")
    assert status.returncode == 0 and "turtle1: driven by admin (supervisor) since" in status.stdout, status


def _cli(port: int, user: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], cwd=ROOT, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"})


def _control_state(watcher: TestClient, predicate, timeout: float = 10.0) -> ControlState:
    m = watcher.wait_for(lambda m: m.topic.endswith("/state/control") and m.payload
                         and predicate(ControlState.from_json(m.payload)), timeout=timeout)
    return ControlState.from_json(m.payload)


def _released(watcher: TestClient) -> None:
    _control_state(watcher, lambda s: s.holder is None, timeout=10)


@pytest.mark.parametrize("broker", ["embedded", "mosquitto"])
def test_one_driver(tmp_path: Path, probe, broker: str) -> None:
    with ExitStack() as stack:
        fleet = write_fleet(tmp_path, read_only_service=False, edit=_supervisors)
        if broker == "mosquitto":
            server = stack.enter_context(ExportedMosquitto(tmp_path, fleet))
        else:
            server = stack.enter_context(EmbeddedBrokerProcess(tmp_path, fleet))
        port = server.port
        stack.enter_context(run(["-m", "roslink_mqtt.sim"], tmp_path / "sim.log"))
        bridge1 = stack.enter_context(run(bridge_args("turtle1", port, config=fleet), tmp_path / "bridge1.log",
                                          bridge_env("turtle1")))
        stack.enter_context(run(bridge_args("turtle2", port, "--ros-args", "-r", "__ns:=/t2", config=fleet),
                                tmp_path / "bridge2.log", bridge_env("turtle2")))
        watcher = stack.enter_context(TestClient(port, "bob", "bob-demo"))
        assert watcher.connect() == 0
        watcher.subscribe("roslink/turtle1/#")
        live = watcher.wait_for(lambda m: m.topic.endswith("/heartbeat") and m.payload
                                and m.json()["payload"]["system_status"] == 4, timeout=30).json()["payload"]
        assert live["pid"] == bridge1.pid and live["host"] == socket.gethostname() and live["take_over"] == 0
        _control_state(watcher, lambda s: s.holder is None and s.supervisors == ("admin",))

        # -- one live bridge: a second one for turtle1 refuses to start, naming the live one, with an exit code
        #    systemd does not restart; the live one keeps the robot (the take-over is at the end)
        second = stack.enter_context(run(bridge_args("turtle1", port, config=fleet), tmp_path / "bridge1b.log",
                                         bridge_env("turtle1")))
        assert second.popen.wait(timeout=30) == EXIT_DUPLICATE, second.output()
        said = second.output()
        assert f"already has a live bridge on {socket.gethostname()} (pid {bridge1.pid})" in said, said
        assert "--take-over" in said and bridge1.poll() is None

        # -- two operators racing: alice drives first; admin's twists never reach /cmd_vel, and admin learns who
        alice = _driver(port, "alice", stack)
        started = time.monotonic()
        # until ROS delivers them: the probe must have matched this bridge's publisher
        for _ in paced(0.1, count=100,
                       stop=lambda: any(round(m.linear.x, 2) == 0.11 for _, m in probe.cmd_vel.since(started))):
            alice.twist(0.11)
        _control_state(watcher, lambda s: s.holder == "alice")
        admin = _driver(port, "admin", stack)
        since = time.monotonic()
        for _ in paced(0.1, count=12):  # both stream at 10 Hz for 1.2 s
            alice.twist(0.11)
            admin.twist(0.22)
        error = admin.error("turtle1 is driven by alice since", timeout=10)
        first_refused = error.at - since
        record_measurement(f"learns who drives ({broker})", first_refused, LEARN_WHO_WITHIN)
        assert first_refused < LEARN_WHO_WITHIN, first_refused
        seen = {round(m.linear.x, 2) for at, m in probe.cmd_vel.items if at >= since}
        assert 0.11 in seen and 0.22 not in seen, seen

        # -- the lease's whole life, on each broker
        # -- a take-over: alice is told at once, the robot stops, then only admin's twists move it
        admin.control("claim")  # admin is a supervisor: claiming takes over
        told = alice.error("taken over by admin from alice", timeout=10)
        assert told.json()["topic"] == "roslink/turtle1/state/control"
        state = _control_state(watcher, lambda s: s.holder == "admin")
        assert state.supervisor and state.event == "taken over by admin from alice"
        probe.cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, timeout=10, after=told.at - 0.5)
        # a non-supervisor cannot take a supervisor's lease
        alice.control("take_over")
        alice.error("only another supervisor can take it over", timeout=10)
        after = time.monotonic()
        for _ in paced(0.1, count=5):
            admin.twist(0.33)
            alice.twist(0.11)
        probe.cmd_vel.wait_for(lambda m: round(m.linear.x, 2) == 0.33, timeout=10, after=after)
        never("alice's twist reaching /cmd_vel",
              lambda: 0.11 in {round(m.linear.x, 2) for at, m in probe.cmd_vel.since(after)}, seconds=0.3)
        admin.control("release")
        _control_state(watcher, lambda s: s.holder is None and s.event == "released by admin")

        # -- a viewer's emergency stop: obeyed and acknowledged; the viewer cannot resume, the holder can
        for _ in paced(0.1, count=3):
            alice.twist(0.11)
        _control_state(watcher, lambda s: s.holder == "alice")
        stopped_at = time.monotonic()
        watcher.publish("roslink/turtle1/from/bob/cmd/emergency_stop", encode_message(108, {"reason": "viewer"}))
        probe.estop.wait_for(lambda m: m.data is True, timeout=10, after=stopped_at)
        # where people look for who drives, the stop shows (issue 43, 4): control status, info; a pub says it once
        _control_state(watcher, lambda s: s.blocked == "emergency stop by bob", timeout=10)
        status = _cli(port, "alice", "control", "status", "turtle1")
        assert "EMERGENCY STOP — emergency stop by bob" in status.stdout, status
        info = _cli(port, "alice", "info", "turtle1")
        assert "EMERGENCY STOP — emergency stop by bob" in info.stdout, info
        pub = _cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.1}')
        said = pub.stdout + pub.stderr
        assert pub.returncode == 1 and said.count("emergency stop by bob") == 1, said
        ack = watcher.wait_for(lambda m: m.topic.endswith("/state/ack") and m.json()["payload"]["command"] == 108,
                               timeout=10)
        assert "emergency stop by bob" in ack.json()["payload"]["text"]
        watcher.publish("roslink/turtle1/from/bob/cmd/arm", encode_message(104, {}))  # not an operator: no effect
        # bob's arm, had it been obeyed, would show in a heartbeat sent half a second after it
        armed = time.monotonic()
        beat = watcher.wait_for(lambda m: m.topic.endswith("/heartbeat") and not m.retain and m.at >= armed + 0.5,
                                timeout=10)
        assert beat.json()["payload"]["system_status"] == 6  # still blocked
        admin.publish("roslink/turtle1/from/admin/cmd/arm", encode_message(104, {}))
        admin.error("turtle1 is driven by alice", timeout=10)  # not the holder: cannot resume either
        alice.publish("roslink/turtle1/from/alice/cmd/arm", encode_message(104, {}))
        watcher.wait_for(lambda m: m.topic.endswith("/heartbeat") and not m.retain
                         and m.json()["payload"]["system_status"] == 4, timeout=10)
        alice.close()
        _released(watcher)

        # -- the holder (admin, a supervisor, driving from a process of his own) SIGKILLed: its last-will stops the
        #    robot; the lease is admin's, not the process's, so it ends only with admin's last client
        with run(["-m", "tests.support.operator_proc", str(port), "admin", "admin-demo", "turtle1", "--lx", "0.15",
                  "--first-seq", str(Driver.seq + 1000)], tmp_path / "operator.log") as proc:
            _control_state(watcher, lambda s: s.holder == "admin", timeout=10)
            probe.cmd_vel.wait_for(lambda m: round(m.linear.x, 2) == 0.15, timeout=5)
            # what people see (the clients' side): robots and info say who drives since when; alice's pub is
            # refused with the name
            _what_people_see(port)
            killed = time.monotonic()
            proc.kill()
            probe.cmd_vel.wait_for(lambda m: m.linear.x == 0, timeout=5, after=killed)
            status = _cli(port, "bob", "control", "status", "turtle1")  # admin's other client (`admin`) is live
            assert "turtle1: driven by admin (supervisor) since" in status.stdout, status
            admin.close()
            state = _control_state(watcher, lambda s: s.holder is None, timeout=10)
            assert "admin's lease ended" in state.event

        # -- claim, then drive: alice holds control with the CLI's claim, and her `pub` in another terminal drives
        #    and ends; the robot stops (the program that drove it signed off) and the claim holds on (issue 43)
        claim_cmd = ["-m", "roslink_mqtt.cli.main", "control", "claim", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{port}", "-u", "alice"]
        with run(claim_cmd, tmp_path / "claim0.log", {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}) as holding:
            _control_state(watcher, lambda s: s.holder == "alice", timeout=10)
            since = time.monotonic()
            pub = _cli(port, "alice", "pub", "turtle1", "twist", '{"lx": 0.12}', "--rate", "10", "--duration", "1")
            assert pub.returncode == 0, pub.stdout + pub.stderr
            moved = probe.cmd_vel.wait_for(lambda m: round(m.linear.x, 2) == 0.12, timeout=5, after=since)[0]
            probe.cmd_vel.wait_for(lambda m: m.linear.x == 0, timeout=5, after=moved)
            status = _cli(port, "bob", "control", "status", "turtle1")
            assert "turtle1: driven by alice since" in status.stdout, status
            assert holding.poll() is None and "control lost" not in holding.output(), holding.output()
            changes = [ControlState.from_json(m.payload).event for m in watcher.drain(0.01)
                       if m.topic.endswith("/state/control") and m.payload]
            assert not changes, changes  # not one change of the lease while alice's pub came and went
            holding.popen.send_signal(signal.SIGINT)  # Ctrl-C gives it back
            assert holding.popen.wait(timeout=10) == 0, holding.output()
            assert "turtle1: released" in holding.output()
        _control_state(watcher, lambda s: s.holder is None and s.event == "released by alice", timeout=10)

        # -- claiming and releasing explicitly: the CLI's claim holds control until Ctrl-C, another of alice's
        #    programs releases it (CLI), and the SDK claims, is refused while someone else holds, and releases
        claim_cmd = ["-m", "roslink_mqtt.cli.main", "control", "claim", "turtle1", "--url",
                     f"mqtt://127.0.0.1:{port}", "-u", "alice"]
        with run(claim_cmd, tmp_path / "claim.log", {**os.environ, "ROSLINK_PASSWORD": "alice-demo"}) as holding:
            _control_state(watcher, lambda s: s.holder == "alice", timeout=10)
            status = _cli(port, "bob", "control", "status", "turtle1")
            assert "turtle1: driven by alice since" in status.stdout, status
            released = _cli(port, "alice", "control", "release", "turtle1")
            assert released.returncode == 0 and "turtle1: released" in released.stdout, released
            _control_state(watcher, lambda s: s.holder is None and s.event == "released by alice")
            assert holding.popen.wait(timeout=10) == 1  # the holding command says so, and ends
            assert "turtle1: control lost — released by alice" in holding.output()
        from roslink_mqtt.client import CommandRefused, RobotClient

        viewer_sdk = RobotClient(url=f"mqtt://127.0.0.1:{port}", username="bob", password="bob-demo")
        admin_sdk = RobotClient(url=f"mqtt://127.0.0.1:{port}", username="admin", password="admin-demo")
        for client in (viewer_sdk, admin_sdk):
            stack.callback(client.close)
            client.connect()
        with pytest.raises(CommandRefused, match="viewer"):
            viewer_sdk.claim_control("turtle1", timeout=5)
        assert admin_sdk.claim_control("turtle1", timeout=5).holder == "admin"
        refused = _cli(port, "alice", "control", "claim", "turtle1")
        assert refused.returncode == 1 and "driven by admin since" in refused.stderr, refused
        assert admin_sdk.release_control("turtle1", timeout=5).holder is None
        _control_state(watcher, lambda s: s.holder is None and s.event == "released by admin")

        # -- a fleet-wide stop: both robots acknowledge within 1 s
        done = _cli(port, "admin", "estop", "--all")
        assert done.returncode == 0, done.stdout + done.stderr
        lines = done.stdout.splitlines()
        assert any(line.startswith("turtle1") and "stopped (acknowledged in" in line for line in lines), lines
        assert any(line.startswith("turtle2") and "stopped (acknowledged in" in line for line in lines), lines

        # -- --take-over: the live bridge stops its robot and exits (4); the new one runs and says it took over
        since = time.monotonic()
        third = stack.enter_context(run(bridge_args("turtle1", port, "--take-over", config=fleet),
                                        tmp_path / "bridge1c.log", bridge_env("turtle1")))
        assert bridge1.popen.wait(timeout=30) == EXIT_FENCED, bridge1.output()
        assert "taken over by the bridge" in bridge1.output()
        # the old bridge's zero (a busy machine has seen it take over 5 s from the new bridge's start)
        probe.cmd_vel.wait_for(lambda m: m.linear.x == 0 and m.angular.z == 0, timeout=10, after=since)
        new = watcher.wait_for(lambda m: m.topic.endswith("/heartbeat") and not m.retain and m.payload
                               and m.json()["payload"]["pid"] == third.pid
                               and m.json()["payload"]["system_status"] in (4, 6), timeout=30)
        assert new.json()["payload"]["take_over"] == 1
        assert "took over from the bridge" in third.output() and third.poll() is None
