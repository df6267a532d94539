"""One robot stack for fault injection: a broker (embedded or Mosquitto), the sim, turtle1's bridge, a viewer, and
operator processes to kill or freeze; the deadlines checked are docs/safety.md's (tests/integration/test_failsafe_*).
"""

from __future__ import annotations

import sys
import time
from contextlib import ExitStack, contextmanager
from pathlib import Path

from tests.support.embedded_broker import EmbeddedBrokerProcess
from tests.support.fleet_brokers import fleet_password_file
from tests.support.measure import record_measurement
from tests.support.mosquitto import MosquittoProcess
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe

OPERATOR_TIMEOUT, COMMAND_TIMEOUT = 1.5, 1.0  # the demo fleet's settings
BROKERS = ("embedded", "mosquitto")


def cmd_vel_probe() -> RosProbe:
    """An rclpy probe of /cmd_vel (``.cmd_vel``): what the robot was told."""
    from geometry_msgs.msg import Twist

    p = RosProbe()
    p.cmd_vel = p.watch(Twist, "/cmd_vel")
    return p


def zero(m) -> bool:
    return m.linear.x == 0 and m.linear.y == 0 and m.linear.z == 0 and m.angular.z == 0


class Stack:
    def __init__(self, tmp: Path, probe: RosProbe, exits: ExitStack, broker: str) -> None:
        self.tmp, self.probe, self.exits = tmp, probe, exits
        if broker == "embedded":
            self.broker = EmbeddedBrokerProcess(tmp)
        else:
            self.broker = MosquittoProcess(tmp, f"allow_anonymous false\npassword_file {fleet_password_file(tmp)}\n")
        exits.callback(self.broker.stop)
        self.broker.start()
        self.port = self.broker.port
        self.sim = exits.enter_context(run(["-m", "roslink_mqtt.sim"], tmp / "sim.log"))
        self.bridge = exits.enter_context(run(bridge_args("turtle1", self.port), tmp / "bridge.log",
                                              bridge_env("turtle1")))
        self.viewer = self.connect_viewer()

    def connect_viewer(self) -> TestClient:
        viewer = TestClient(self.port, "bob", "bob-demo")
        assert viewer.connect() == 0
        self.exits.callback(viewer.close)
        viewer.subscribe("roslink/turtle1/#")
        self.heartbeat = viewer.wait_for(
            lambda m: m.topic.endswith("/heartbeat") and m.json()["payload"]["system_status"] == 4, timeout=30).json()
        return viewer

    @contextmanager
    def operator(self, *extra: str):
        args = ["-m", "tests.support.operator_proc", str(self.port), "alice", "alice-demo", "turtle1", *extra]
        with run(args, self.tmp / f"operator-{time.monotonic_ns()}.log") as proc:
            yield proc

    def wait_moving(self, since: float) -> None:
        self.probe.cmd_vel.wait_for(lambda m: m.linear.x > 0, timeout=20, after=since)

    def time_to_stop(self, fault_at: float, deadline: float) -> float:
        at, _ = self.probe.cmd_vel.wait_for(zero, timeout=deadline + 3, after=fault_at)
        return at - fault_at

    def assert_no_motion_after(self, t: float, until: float | None = None) -> None:
        moving = [m for at, m in self.probe.cmd_vel.since(t) if (until is None or at < until) and not zero(m)]
        assert moving == [], f"non-zero velocity after the failsafe: {moving[:3]}"



def check(stack: Stack, what: str, measured: float, deadline: float) -> None:
    name = f"[{stack.name}] {what}"
    record_measurement(name, measured, deadline)
    print(f"{name}: {measured * 1000:.0f} ms (deadline {deadline * 1000:.0f} ms)", file=sys.stderr)
    assert measured <= deadline, f"{name}: stopped after {measured:.3f} s, deadline {deadline:.3f} s"


