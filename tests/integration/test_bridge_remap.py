"""ROS remapping and namespaces apply to the bridge's ROS side only; the MQTT side is unchanged."""

from __future__ import annotations

import time

import pytest

from roslink_mqtt.protocol import MessageId, decode
from tests.support.fleet_brokers import mosquitto_with_logins
from tests.support.mqtt_client import TestClient
from tests.support.procs import bridge_args, bridge_env, run
from tests.support.ros import RosProbe
from tests.support.waits import never, paced

pytestmark = pytest.mark.timeout(60)


def test_ros_args_remap_and_namespace(tmp_path) -> None:
    from geometry_msgs.msg import Twist

    sim_args = ["-m", "roslink_mqtt.sim", "--ros-args", "-r", "__ns:=/robot1"]
    remap = ["--ros-args", "-r", "__ns:=/robot1", "-r", "cmd_vel:=/base/cmd_vel"]
    with mosquitto_with_logins(tmp_path) as port, \
            run(sim_args, tmp_path / "sim.log"), \
            run(bridge_args("turtle2", port, *remap), tmp_path / "bridge.log", bridge_env("turtle2")):
        probe = RosProbe()
        try:
            remapped = probe.watch(Twist, "/base/cmd_vel")
            default = probe.watch(Twist, "/robot1/cmd_vel")
            with TestClient(port, "carol", "carol-demo", operator=True) as carol:
                assert carol.connect() == 0
                carol.subscribe("roslink/turtle2/#")
                # odom is read from /robot1/odom (namespace), published on the unchanged MQTT topic
                motion = carol.wait_for(lambda m: m.topic == "roslink/turtle2/state/global_motion", timeout=20)
                assert decode(motion.payload, MessageId.GLOBAL_MOTION).system_id == 2
                t0 = time.monotonic()
                for _ in paced(0.1, within=15, stop=lambda: remapped.since(t0)):  # until one arrives
                    carol.publish("roslink/turtle2/from/carol/cmd/twist", {"lx": 0.1}, qos=0)
                _, twist = remapped.wait_for(lambda m: m.linear.x == pytest.approx(0.1), timeout=1)
                assert default.since(t0) == []  # nothing on the un-remapped name
        finally:
            probe.close()


def test_retained_commands_are_never_replayed(tmp_path) -> None:
    """A twist left retained on the broker must not drive the robot when the bridge (re)connects."""
    from geometry_msgs.msg import Twist

    with mosquitto_with_logins(tmp_path) as port, \
            TestClient(port, "alice", "alice-demo", operator=True) as alice:
        assert alice.connect() == 0
        alice.subscribe("roslink/turtle1/to/alice/#")
        alice.publish("roslink/turtle1/from/alice/cmd/twist", {"lx": 0.4}, retain=True)
        probe = RosProbe()
        try:
            cmd_vel = probe.watch(Twist, "/cmd_vel")
            with run(bridge_args("turtle1", port), tmp_path / "bridge.log", bridge_env("turtle1")):
                err = alice.wait_for(lambda m: m.topic.endswith("/to/alice/error"), timeout=20).json()
                assert "ignored a retained command" in err["error"]
                never("a retained twist moving the robot", lambda: [m for _, m in cmd_vel.since(0) if m.linear.x != 0],
                      seconds=1.0)
                assert not [m for _, m in cmd_vel.since(0) if m.linear.x != 0]
        finally:
            probe.close()
            alice.publish("roslink/turtle1/from/alice/cmd/twist", b"", retain=True)
