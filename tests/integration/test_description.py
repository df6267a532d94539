"""The robot description with real processes (embedded broker, sim, bridge): what it lists, and the CLI around it.

The bridge publishes it retained on ``state/description``; this checks it lists exactly what config/robots.yaml
maps for turtle1 (every rule, service and action, with who may use it) and real field layouts from ROS
introspection, that the SDK reads it, and that ``info``, ``whoami``, ``echo --field`` and ``echo --hz`` work
as subprocesses.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import orjson
import pytest

from roslink_mqtt.bridge.ros.description import ros_fields_of
from roslink_mqtt.client import RobotClient
from roslink_mqtt.client.errors import InvalidArgument, SubscriptionFailed, WaitTimeout
from roslink_mqtt.config import Direction, load_fleet
from roslink_mqtt.protocol.description import OPERATORS, VIEWERS, RobotDescription
from tests.support.mqtt_client import TestClient
from tests.support.procs import CONFIG, ROOT
from tests.support.robot_stack import BROKERS, turtle1_online
from tests.support.waits import wait_until

pytestmark = pytest.mark.timeout(120)

TWIST = {part: {"type": "geometry_msgs/msg/Vector3", "fields": {"x": "float64", "y": "float64", "z": "float64"}}
         for part in ("linear", "angular")}
FIBONACCI = {"goal": {"order": "int32"}, "result": {"sequence": "int32[]"}, "feedback": {"sequence": "int32[]"}}


@pytest.fixture(scope="module", params=BROKERS)
def port(request, tmp_path_factory):
    """The broker's port: the description and the SDK on both brokers; the CLI tests pick the embedded one."""
    with turtle1_online(tmp_path_factory.mktemp(f"description-{request.param}"), request.param) as broker_port:
        yield broker_port


EMBEDDED_ONLY = pytest.mark.parametrize("port", ["embedded"], indirect=True)


def cli(port: int, user: str, *args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    env = {**os.environ, "ROSLINK_PASSWORD": f"{user}-demo"}
    return subprocess.run([sys.executable, "-m", "roslink_mqtt.cli.main", *args, "--url", f"mqtt://127.0.0.1:{port}",
                           "-u", user], capture_output=True, text=True, env=env, cwd=ROOT, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def test_description_lists_exactly_what_the_fleet_file_maps(port) -> None:
    robot = load_fleet(CONFIG).robots["turtle1"]
    for _attempt in range(2):  # a description published while bob subscribed reaches him live (retain flag off)
        with TestClient(port, "bob", "bob-demo") as bob:  # a viewer reads it too: it is the same for everyone
            assert bob.connect() == 0
            bob.subscribe("roslink/turtle1/state/description")
            message = bob.wait_for(lambda m: True, timeout=10)
        if message.retain:
            break
    assert message.retain and message.qos == 1  # a new subscriber gets it from the broker, kept
    d = RobotDescription.from_json(message.payload)
    assert (d.robot, d.system_id, d.type, d.protocol_version) == ("turtle1", robot.system_id, "ground", 2)
    assert d.limits == {"linear": robot.bridge.limits.linear, "angular": robot.bridge.limits.angular,
                        "mode": robot.bridge.limits.mode}

    outbound = [r for r in robot.rules if r.direction is Direction.ROS_TO_MQTT]
    inbound = [r for r in robot.rules if r.direction is Direction.MQTT_TO_ROS]
    assert [(s.name, s.message, s.ros_type, s.retained, s.max_rate, s.who) for s in d.state] == [
        *((r.mqtt_topic.removeprefix("state/"), r.preset, r.ros_type, r.retain, r.max_rate, VIEWERS)
          for r in outbound),
        ("ack", "ack", None, False, None, VIEWERS)]  # the bridge's own acknowledgements
    assert [(c.name, c.message, c.ros_type, c.on_demand, c.who) for c in d.commands] == [
        (r.mqtt_topic, r.preset, r.ros_type, r.on_demand, OPERATORS) for r in inbound]
    assert [(s.name, s.ros_type, s.read_only, s.timeout) for s in d.services] == [
        (s.name, s.ros_type, s.read_only, s.timeout) for s in robot.services]
    assert [s.who for s in d.services] == [VIEWERS if s.read_only else OPERATORS for s in robot.services]
    assert [(a.name, a.ros_type, a.viewers, a.timeout, a.feedback_rate) for a in d.actions] == [
        (a.name, a.ros_type, a.viewers, a.timeout, a.feedback_rate) for a in robot.actions]
    assert [a.who for a in d.actions] == [VIEWERS if a.viewers else OPERATORS for a in robot.actions]
    assert [(p.name, p.node, p.timeout, p.set_by, p.who) for p in d.parameters] == [
        (p.name, p.node, p.timeout, VIEWERS if p.viewers_may_set else OPERATORS, VIEWERS) for p in robot.parameters]
    assert d.parameters  # the demo fleet exposes the sim's parameters
    twist = next(c for c in d.commands if c.message == "twist")
    assert twist.limits == d.limits

    mentioned = {r.ros_type for r in robot.rules} | {s.ros_type for s in robot.services} | {
        a.ros_type for a in robot.actions}
    assert set(d.types) == mentioned
    assert d.types["geometry_msgs/msg/Twist"] == TWIST
    assert d.types["test_msgs/action/Fibonacci"] == FIBONACCI
    assert d.types["std_srvs/srv/Trigger"] == {"request": {}, "response": {"success": "bool", "message": "string"}}
    odom = d.types["nav_msgs/msg/Odometry"]
    assert odom["pose"]["fields"]["covariance"] == "float64[36]"
    assert odom["header"]["fields"]["stamp"] == {"type": "builtin_interfaces/msg/Time",
                                                 "fields": {"sec": "int32", "nanosec": "uint32"}}
    assert d.types["sensor_msgs/msg/LaserScan"]["ranges"] == "float32[]"
    assert all(d.types[t] == ros_fields_of(t) for t in mentioned)  # what the robot's own ROS types say


@EMBEDDED_ONLY  # the SDK's reading: any broker shows it (both carry the retained description in other tests)
def test_sdk_reads_the_description(port, request) -> None:
    with RobotClient("alice", "alice-demo", url=f"mqtt://127.0.0.1:{port}", presence=False) as alice:
        d = alice.description("turtle1", timeout=10)
        again = alice.description("turtle1", timeout=10)  # a second call subscribes afresh
    assert d == again and d.entry("fibonacci").ros_type == "test_msgs/action/Fibonacci"
    with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{port}", presence=False) as bob:
        def offered():  # the bridge's uplink report, retained on state/link: the first may predate the sim's odometry
            link = bob.link("turtle1", timeout=10)
            motion = link.streams.get("global_motion") if link is not None else None
            return (link, motion) if motion is not None and motion.offered_hz > 0 else None

        # a new report comes every LINK_REPORT_PERIOD
        link, motion = wait_until("a link report offering global_motion", offered, timeout=20, period=0.5)
    assert link is not None and link.mode == "scheduled" and link.rate_kbit_s > 0
    assert motion is not None
    assert motion.priority == "motion" and motion.max_rate == 10 and 0 < motion.offered_hz <= 11
    assert link.streams["robot_status"].latest_only is False  # retained, QoS 1: ordered
    with RobotClient("carol", "carol-demo", url=f"mqtt://127.0.0.1:{port}", presence=False) as carol:
        # carol has no grant on turtle1: our broker refuses the subscription; Mosquitto grants it and sends nothing
        refused = SubscriptionFailed if request.node.callspec.params["port"] == "embedded" else WaitTimeout
        with pytest.raises(refused) as err:
            carol.description("turtle1", timeout=1.5)
    assert "turtle1" in str(err.value)


@EMBEDDED_ONLY
def test_a_state_name_the_robot_does_not_publish_is_refused_at_once(port) -> None:
    """A typo used to wait for ever (the CLI until killed, the SDK until its get() timed out)."""
    with RobotClient("bob", "bob-demo", url=f"mqtt://127.0.0.1:{port}", presence=False) as bob:
        bob.wait_for_robot("turtle1", timeout=10)
        with pytest.raises(InvalidArgument, match="publishes no state/global_motio; did you mean global_motion?"):
            bob.subscribe("turtle1", "global_motio")
        assert bob.subscribe("turtle1", "global_motion").get(timeout=10) is not None  # one it has
    started = time.monotonic()
    out = cli(port, "bob", "echo", "turtle1", "global_motio")  # no --timeout: it waited until killed
    assert out.returncode == 2 and "did you mean global_motion?" in out.stderr, out.stderr
    assert "It publishes: " in out.stderr and time.monotonic() - started < 20
    assert cli(port, "bob", "echo", "turtle1", "global_motion", "-n", "1").returncode == 0


@EMBEDDED_ONLY
def test_info_prints_the_description_and_marks_what_you_may_not_use(port) -> None:
    bob = cli(port, "bob", "info", "turtle1", "--types")
    assert bob.returncode == 0, bob.stderr
    out = bob.stdout
    assert "turtle1: ground robot, system_id 1" in out and "you (bob): viewer" in out
    assert "  uplink: link " in out and "kbit/s" in out and " — " in out  # state/link, one line
    assert "global_motion" in out and "ROSLink twist (geometry_msgs/msg/Twist)" in out
    reset = next(line for line in out.splitlines() if line.strip().startswith("reset "))
    assert "operators" in reset and "(not you)" in reset
    assert "(you may read, not set)" in out  # the sim's parameters: bob reads, operators set
    assert "int32 order" in out and "geometry_msgs/msg/Vector3 linear" in out  # --types: interface layouts
    alice = cli(port, "alice", "info", "turtle1")
    assert alice.returncode == 0 and "you (alice): operator" in alice.stdout and "(not you)" not in alice.stdout
    raw = cli(port, "alice", "info", "turtle1", "--json")
    assert raw.returncode == 0 and RobotDescription.from_json(raw.stdout).robot == "turtle1"
    missing = cli(port, "admin", "info", "turtle2", "--timeout", "1")  # no bridge runs for turtle2
    assert missing.returncode == 1 and "no description of turtle2 within 1 s" in missing.stderr
    refused = cli(port, "alice", "info", "turtle2", "--timeout", "1")  # not granted to alice
    assert refused.returncode == 1 and "the broker refused roslink/turtle2/state/description" in refused.stderr


@EMBEDDED_ONLY
def test_whoami_lists_role_services_and_actions_per_robot(port) -> None:
    alice = cli(port, "alice", "whoami", "--wait", "0.5")
    assert alice.returncode == 0, alice.stderr
    assert alice.stdout.splitlines()[0] == f"alice @ mqtt://127.0.0.1:{port}"
    row = next(line for line in alice.stdout.splitlines() if line.startswith("turtle1"))
    assert row.split()[:5] == ["turtle1", "online", "operator", "reset", "fibonacci"]
    bob = cli(port, "bob", "whoami", "--wait", "0.5", "--json")
    assert bob.returncode == 0, bob.stderr
    assert orjson.loads(bob.stdout)["robots"] == {"turtle1": {"online": True, "role": "viewer", "services": [],
                                                              "actions": []}}
    carol = cli(port, "carol", "whoami", "--wait", "0.5")  # turtle2's bridge is not running, and never ran here
    assert carol.returncode == 1 and "no robots seen" in carol.stdout


@EMBEDDED_ONLY
def test_echo_field_prints_one_field_and_names_a_missing_one(port) -> None:
    out = cli(port, "bob", "echo", "turtle1", "global_motion", "--field", "x", "-n", "3", "--timeout", "10")
    assert out.returncode == 0, out.stderr
    assert [type(orjson.loads(line)) for line in out.stdout.split()] == [float] * 3
    beat = cli(port, "bob", "echo", "turtle1", "heartbeat", "--field", "system_status", "-n", "1", "--timeout", "5")
    assert beat.returncode == 0 and beat.stdout.strip() == "4", beat.stderr
    bad = cli(port, "bob", "echo", "turtle1", "global_motion", "--field", "pose.x", "-n", "1", "--timeout", "10")
    assert bad.returncode == 2 and bad.stdout == ""
    assert "no field 'pose.x': the message has no 'pose' (its fields: time_boot_ms, x, y" in bad.stderr


@EMBEDDED_ONLY
def test_echo_hz_prints_the_rate(port) -> None:
    out = cli(port, "bob", "echo", "turtle1", "global_motion", "--hz", "--timeout", "3.5")
    assert out.returncode == 0, out.stderr
    rates = [float(line.split(":")[1]) for line in out.stdout.splitlines() if line.startswith("average rate:")]
    assert len(rates) >= 2, out.stdout  # once a second, and once at the end
    assert 7.0 < rates[-1] < 12.0, out.stdout  # the rule's max_rate is 10 Hz
    assert "min:" in out.stdout and "window:" in out.stdout
    counted = cli(port, "bob", "echo", "turtle1", "global_motion", "--hz", "-n", "5", "--timeout", "10")
    assert counted.returncode == 0 and "window: 5" in counted.stdout.splitlines()[-1], counted.stdout
