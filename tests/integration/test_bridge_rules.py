"""Rule validation at bridge start: each problem is a clear error naming the rule."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace

import orjson
import pytest

from roslink_mqtt.topics import TopicTree
from tests.support.one_robot import HASH, one_robot_fleet

pytest.importorskip("rclpy")

from roslink_mqtt.bridge.ros.rules import RuleError, compile_rules  # noqa: E402

OUT = "{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom}"
IN = "{direction: mqtt_to_ros, ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist, mqtt_topic: cmd/twist}"


def robot_with(base: str, **changes):
    """A robot whose one rule is ``base`` changed past the loader (which refuses most of these itself, without
    ROS: tests/integration/test_fleet_types.py): the bridge must still refuse each on its own."""
    robot = one_robot_fleet(base).robots["r1"]
    return replace(robot, rules=(replace(robot.rules[0], **changes),))


@pytest.mark.parametrize(("base", "changes", "fragment"), [
    (OUT, {"ros_type": "nav_msgs/msg/Odometri"},
     "rules[0] (odom → state/odom): unknown type 'nav_msgs/msg/Odometri': 'nav_msgs' has no msg 'Odometri'"),
    (OUT, {"ros_type": "warp_msgs/msg/Odometry"}, "ROS package 'warp_msgs' is not installed"),
    (OUT, {"ros_type": "sensor_msgs/msg/Imu", "mqtt_topic": "state/gm", "preset": "global_motion"},
     "rules[0] (odom → state/gm): preset 'global_motion' needs ros_type nav_msgs/msg/Odometry or "
     "geometry_msgs/msg/PoseStamped or geometry_msgs/msg/PoseWithCovarianceStamped, not sensor_msgs/msg/Imu"),
    (OUT, {"ros_topic": "hb", "ros_type": "std_msgs/msg/String", "mqtt_topic": "state/hb", "preset": "heartbeat"},
     "preset 'heartbeat' is not a state preset"),
    (IN, {"ros_type": "std_msgs/msg/String", "preset": "twist"},
     "rules[0] (cmd/twist → cmd_vel): preset 'twist' needs ros_type geometry_msgs/msg/Twist"),
    (IN, {"ros_topic": "arm", "ros_type": "rcl_interfaces/srv/GetParameters", "mqtt_topic": "cmd/arm", "preset": "arm"},
     "preset 'arm' can call std_srvs/srv/Trigger or std_srvs/srv/SetBool or std_srvs/srv/Empty"),
    (OUT, {"fields": {"x": "pose.pose.positon.x"}},
     "fields.x: 'pose.pose.positon.x' is not a field of nav_msgs/msg/Odometry"),
    (IN, {"mqtt_topic": "drive", "on_demand": True},
     "rules[0] (drive → cmd_vel): on_demand is not for velocity commands"),
])
def test_bad_rules_are_refused_at_start(base: str, changes: dict, fragment: str) -> None:
    with pytest.raises(RuleError) as info:
        compile_rules(robot_with(base, **changes), TopicTree())
    assert fragment in str(info.value)


def test_good_generic_rule_with_fields_compiles() -> None:
    fleet = one_robot_fleet("{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry,"
                       " mqtt_topic: state/pos, fields: {x: pose.pose.position.x, frame: header.frame_id}}")
    outbound, inbound = compile_rules(fleet.robots["r1"], TopicTree())
    from nav_msgs.msg import Odometry
    msg = Odometry()
    msg.pose.pose.position.x, msg.header.frame_id = 1.5, "odom"
    assert outbound[0].serialize(msg) == b'{"x":1.5,"frame":"odom"}' and inbound == {}


def start_bridge(tmp_path, robot_body: str) -> tuple[object, subprocess.CompletedProcess]:
    """Run the bridge for robot r1 whose settings end with ``robot_body`` (YAML at 4 spaces)."""
    config = tmp_path / "robots.yaml"
    config.write_text(f"""
robots:
  r1:
    system_id: 1
    key: k1
    password: "{HASH}"
{robot_body}
""")
    out = subprocess.run([sys.executable, "-m", "roslink_mqtt.bridge.main", "--config", str(config), "--robot", "r1"],
                         capture_output=True, text=True, timeout=60)
    return config, out


def test_bridge_exits_with_the_rule_error(tmp_path) -> None:
    """A type outside common_interfaces passes the loader (it cannot check it) and stops the bridge at start."""
    config, out = start_bridge(tmp_path, """    bridge: {password: pw}
    rules:
      - {direction: mqtt_to_ros, ros_topic: drive, ros_type: warp_msgs/msg/Drive, mqtt_topic: cmd/drive}""")
    assert out.returncode == 2
    assert f"{config}:9 robots.r1.rules[0] (cmd/drive → drive): unknown type 'warp_msgs/msg/Drive': ROS package " \
           "'warp_msgs' is not installed" in out.stderr


@pytest.mark.parametrize(("extra", "fragment"), [
    ("    bridge: {password: pw, on_failsafe: [{ros_topic: stop, ros_type: std_msgs/msg/Bool, message: {dat: true}}]}",
     "robots.r1.bridge.on_failsafe[0]: dat: unknown field for Bool"),
    ("    bridge: {password: pw, on_failsafe: [{ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist,\n"
     "        message: {linear: {x: 0.3}}}]}",
     "robots.r1.bridge.on_failsafe[0]: a failsafe action must not move the robot"),
    ("    bridge: {password: pw}\n    services: [{ros_service: reset, ros_type: warp_srvs/srv/Reset}]",
     "robots.r1.services: unknown type 'warp_srvs/srv/Reset'"),
])
def test_bridge_exits_on_bad_failsafe_action_or_service(tmp_path, extra: str, fragment: str) -> None:
    _, out = start_bridge(tmp_path, extra)
    assert out.returncode == 2, out.stderr
    assert fragment in out.stderr


PATH_OUT = "{direction: ros_to_mqtt, ros_topic: plan, ros_type: nav_msgs/msg/Path, mqtt_topic: state/plan}"


def test_fields_path_through_a_sequence_is_a_rule_error() -> None:
    """A sequence has no one element to follow; the walk used to load 'sequence<…>' as a type and raise
    UnknownTypeError, which nothing caught."""
    with pytest.raises(RuleError) as info:
        compile_rules(robot_with(PATH_OUT, fields={"x": "poses.pose.position.x"}), TopicTree())
    assert str(info.value) == ("rules[0] (plan → state/plan): fields.x: 'poses.pose.position.x' goes through 'poses', "
                               "a sequence<geometry_msgs/PoseStamped> of nav_msgs/msg/Path (a fields path ends at a "
                               "sequence or array; it cannot reach inside one)")


def test_fields_path_ending_at_a_sequence_of_messages_compiles() -> None:
    """The loader accepts a path that ends at a sequence (config/interfaces.py); the bridge carries it as a list."""
    outbound, _ = compile_rules(robot_with(PATH_OUT, fields={"plan": "poses"}), TopicTree())
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Path
    msg = Path(poses=[PoseStamped()])
    msg.poses[0].pose.position.x = 2.5
    assert orjson.loads(outbound[0].serialize(msg))["plan"][0]["pose"]["position"]["x"] == 2.5


def test_bridge_exits_with_the_rule_named_for_a_path_through_a_sequence(tmp_path) -> None:
    """rcl_interfaces is outside the loader's table, so only the bridge can refuse this path: exit 2, no traceback."""
    config, out = start_bridge(tmp_path, """    bridge: {password: pw}
    rules:
      - {direction: ros_to_mqtt, ros_topic: /parameter_events, ros_type: rcl_interfaces/msg/ParameterEvent,
         mqtt_topic: state/params, fields: {name: new_parameters.name}}""")
    assert out.returncode == 2, out.stderr
    assert "Traceback" not in out.stderr
    assert f"{config}:9 robots.r1.rules[0] (/parameter_events → state/params): fields.name: 'new_parameters.name' " \
           "goes through 'new_parameters', a sequence<rcl_interfaces/Parameter>" in out.stderr
