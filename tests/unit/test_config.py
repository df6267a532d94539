"""Fleet config: the demo fleet loads; every error names file:line and key path."""

from __future__ import annotations

import textwrap
from pathlib import Path

import pytest

from roslink_mqtt.config import ConfigError, Direction, Priority, Role, load_fleet, parse_fleet, verify_password
from roslink_mqtt.config.passwords import hash_password

ROOT = Path(__file__).resolve().parents[2]
HASH = hash_password("pw", iterations=1)

BASE = f"""\
robots:
  turtle1:
    system_id: 1
    key: k1
    password: "{HASH}"
    rules:
      - {{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom}}
  turtle2:
    system_id: 2
    key: k2
    password: "{HASH}"
users:
  alice:
    password: "{HASH}"
    grants:
      - {{key: k1, role: operator}}
"""


def test_demo_fleet() -> None:
    fleet = load_fleet(ROOT / "config" / "robots.yaml")
    assert set(fleet.robots) == {"turtle1", "turtle2"}
    assert fleet.robots["turtle1"].system_id == 1 and fleet.robots["turtle2"].system_id == 2
    assert fleet.roles_of("alice") == {"turtle1": Role.OPERATOR}
    assert fleet.roles_of("bob") == {"turtle1": Role.VIEWER}
    assert fleet.roles_of("carol") == {"turtle2": Role.OPERATOR}
    assert fleet.roles_of("admin") == {"turtle1": Role.OPERATOR, "turtle2": Role.OPERATOR}
    assert fleet.roles_of("nobody") == {}
    demo_passwords = {"alice": "alice-demo", "bob": "bob-demo", "carol": "carol-demo", "admin": "admin-demo",
                      "turtle1": "turtle1-demo", "turtle2": "turtle2-demo"}
    for name, password in demo_passwords.items():
        assert verify_password(password, fleet.password_hash(name)), name
        assert not verify_password(password + "x", fleet.password_hash(name))
    rules = fleet.robots["turtle1"].rules
    assert {r.mqtt_topic for r in rules if r.direction is Direction.ROS_TO_MQTT} == {
        "state/global_motion", "state/robot_status", "state/range_finder_data", "state/gps_raw_info"}
    assert fleet.robots["turtle1"].service("reset").ros_type == "std_srvs/srv/Trigger"


def test_base_is_valid() -> None:
    fleet = parse_fleet(BASE, "robots.yaml")
    assert fleet.robots["turtle1"].rules[0].line == 7


def _error(text: str) -> str:
    with pytest.raises(ConfigError) as info:
        parse_fleet(textwrap.dedent(text), "robots.yaml")
    return str(info.value)


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("system_id: 1", 'system_id: "one"', 'robots.yaml:3 robots.turtle1.system_id: expected integer 0..65535, '
                                         'got "one"'),
    ("system_id: 1", "system_id: 70000", "robots.yaml:3 robots.turtle1.system_id: expected integer 0..65535"),
    ("system_id: 2", "system_id: 1", "robots.yaml:9 robots.turtle2.system_id: system_id 1 is already used by robot "
                                     "'turtle1'"),
    ("key: k2", "key: k1", "robots.yaml:10 robots.turtle2.key: key is already used by robot 'turtle1'"),
    ("    key: k1\n", "", "robots.yaml:2 robots.turtle1: missing required key 'key'"),
    ("system_id: 1", "sytem_id: 1", "robots.yaml:3 robots.turtle1.sytem_id: unknown key 'sytem_id' "
                                    "(did you mean 'system_id'?)"),
    (f'password: "{HASH}"\n    rules', 'password: "hunter2"\n    rules',
     "robots.yaml:5 robots.turtle1.password: not a Mosquitto password hash"),
    ("role: operator", "role: driver", "robots.yaml:16 users.alice.grants[0].role: expected one of operator, "
                                       "viewer, got \"driver\""),
    ("{key: k1,", "{key: k9,", "robots.yaml:16 users.alice.grants[0].key: no robot has this key"),
    ("  alice:", "  turtle1:", "robots.yaml:13 users.turtle1: 'turtle1' is both a robot and a user"),
    ("  turtle2:", "  tur+tle2:", "robots.yaml:8 robots.tur+tle2: robot name 'tur+tle2' must not contain '+'"),
    ("  turtle2:", "  operators:", "robots.yaml:8 robots.operators: 'operators' is reserved"),
    ("mqtt_topic: state/odom", "mqtt_topic: odom", "robots.yaml:7 robots.turtle1.rules[0].mqtt_topic: a ros_to_mqtt "
                                                   "rule publishes under state/"),
    ("ros_type: nav_msgs/msg/Odometry", "ros_type: Odometry", "robots.yaml:7 robots.turtle1.rules[0].ros_type: "
                                                              "expected a ROS msg type"),
    ("direction: ros_to_mqtt", "direction: up", "robots.yaml:7 robots.turtle1.rules[0].direction: expected one of"),
    ("mqtt_topic: state/odom}", "mqtt_topic: state/odom, preset: twist}",
     "robots.yaml:7 robots.turtle1.rules[0].preset: preset 'twist' is a command message and cannot be used in a "
     "ros_to_mqtt rule"),
    ("mqtt_topic: state/odom}", "mqtt_topic: state/odom, preset: warp}",
     "robots.yaml:7 robots.turtle1.rules[0].preset: expected one of heartbeat"),
    ("mqtt_topic: state/odom}", "mqtt_topic: state/odom, max_rate: -1}",
     "robots.yaml:7 robots.turtle1.rules[0].max_rate: expected a finite number > 0"),
    ("    system_id: 2", "    system_id: [2", "robots.yaml:9: invalid YAML"),
    ("  turtle2:\n", "  turtle1:\n", "robots.yaml:8 robots: duplicate key 'turtle1'"),
])
def test_errors_name_file_line_and_path(old: str, new: str, expected: str) -> None:
    assert old in BASE
    message = _error(BASE.replace(old, new, 1))
    assert message.startswith(expected), message


def test_duplicate_and_looping_rules() -> None:
    dup = BASE.replace(
        "mqtt_topic: state/odom}",
        "mqtt_topic: state/odom}\n      - {direction: ros_to_mqtt, ros_topic: odom2, "
        "ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom}")
    assert "robots.yaml:8 robots.turtle1.rules[1].mqtt_topic: rules[1] (odom2 → state/odom) duplicates rules[0]" \
        in _error(dup)
    loop = BASE.replace(
        "mqtt_topic: state/odom}",
        "mqtt_topic: state/odom}\n      - {direction: mqtt_to_ros, ros_topic: odom, "
        "ros_type: nav_msgs/msg/Odometry, mqtt_topic: cmd/odom}")
    assert "robots.yaml:8 robots.turtle1.rules[1].ros_topic: rules[1] (cmd/odom → odom) and rules[0]" \
           " (odom → state/odom) loop" in _error(loop)
    reserved = BASE.replace("direction: ros_to_mqtt, ros_topic: odom", "direction: mqtt_to_ros, ros_topic: odom")
    reserved = reserved.replace("mqtt_topic: state/odom", "mqtt_topic: call/odom")
    assert "'call/' is reserved" in _error(reserved)


def test_service_targets_only_for_command_presets() -> None:
    odom = "{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom}"
    ok = BASE.replace(odom,
                      "{direction: mqtt_to_ros, ros_topic: arm, ros_type: std_srvs/srv/SetBool, mqtt_topic: cmd/arm,"
                      " preset: arm}")
    assert parse_fleet(ok, "robots.yaml").robots["turtle1"].rules[0].ros_type == "std_srvs/srv/SetBool"
    twist = ok.replace("preset: arm", "preset: twist")
    assert "rules[0].ros_type: expected a ROS msg type" in _error(twist)


def test_on_demand_only_for_generic_commands() -> None:
    odom = "{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/odom}"
    ok = BASE.replace(odom, "{direction: mqtt_to_ros, ros_topic: lights, ros_type: std_msgs/msg/Bool,"
                            " mqtt_topic: lights, on_demand: true}")
    assert parse_fleet(ok, "robots.yaml").robots["turtle1"].rules[0].on_demand is True
    assert "rules[0].on_demand: on_demand applies to generic mqtt_to_ros rules only" in _error(
        BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, on_demand: true}"))
    preset = ok.replace("ros_type: std_msgs/msg/Bool, mqtt_topic: lights", "ros_type: std_msgs/msg/Bool, "
                        "mqtt_topic: cmd/arm, preset: arm")
    assert "on_demand applies to generic mqtt_to_ros rules only" in _error(preset)
    assert "'advertise/' is reserved" in _error(ok.replace("mqtt_topic: lights", "mqtt_topic: advertise/x"))


def test_uplink_priority_and_latest_only() -> None:
    """The rule's class and latest-wins (docs/config.md, "Weak links"): defaults by preset and type, overrides,
    clear errors for a bad class or for commands (what the robot receives is not scheduled on its uplink)."""
    rule = parse_fleet(BASE, "robots.yaml").robots["turtle1"].rules[0]
    assert rule.priority is Priority.MOTION and rule.latest_only  # odometry
    custom = parse_fleet(BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, priority: bulk, "
                                      "latest_only: false}"), "robots.yaml").robots["turtle1"].rules[0]
    assert custom.priority is Priority.BULK and not custom.latest_only
    retained = parse_fleet(BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, retain: true}"),
                           "robots.yaml").robots["turtle1"].rules[0]
    assert not retained.latest_only  # retained and QoS 1 streams are ordered unless they say otherwise
    assert "robots.yaml:7 robots.turtle1.rules[0].priority: expected one of control, motion, state, bulk" in _error(
        BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, priority: urgent}"))
    command = BASE.replace("{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: "
                           "state/odom}", "{direction: mqtt_to_ros, ros_topic: lights, ros_type: std_msgs/msg/Bool, "
                                          "mqtt_topic: lights, latest_only: true}")
    assert "rules[0].latest_only: latest_only applies to ros_to_mqtt rules only" in _error(command)
    buffered = parse_fleet(BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, buffer: disk}"),
                           "robots.yaml").robots["turtle1"]
    assert buffered.rules[0].buffer == "disk" and buffered.bridge.buffer_max_bytes == 64 * 1024 * 1024
    assert "rules[0].buffer: expected one of none, disk" in _error(
        BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/odom, buffer: ram}"))
    assert "'state/link' is written by the bridge itself" in _error(
        BASE.replace("mqtt_topic: state/odom}", "mqtt_topic: state/link}"))
    assert "bridge.uplink: expected one of scheduled, fifo" in _error(
        BASE.replace("    key: k1\n", "    key: k1\n    bridge: {uplink: lifo}\n"))


def test_missing_and_unreadable_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nope.yaml: cannot read fleet file"):
        load_fleet(tmp_path / "nope.yaml")
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    with pytest.raises(ConfigError, match="missing required key 'robots'"):
        load_fleet(empty)


SNAPSHOT_RULE = ("      - {direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, "
                 "mqtt_topic: state/odom}\n")


def _with_snapshot(section: str) -> str:
    return BASE.replace(SNAPSHOT_RULE, SNAPSHOT_RULE + textwrap.indent(textwrap.dedent(section), "    "), 1)


def test_a_snapshot_topic_named_by_a_rule_takes_its_type() -> None:
    fleet = parse_fleet(_with_snapshot("""\
        snapshot:
          topics: [odom, {ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist}]
          seconds: 12
          who: viewers
        """), "robots.yaml")
    snapshot = fleet.robots["turtle1"].snapshot
    assert snapshot is not None and [(t.ros_topic, t.ros_type) for t in snapshot.topics] == [
        ("odom", "nav_msgs/msg/Odometry"), ("cmd_vel", "geometry_msgs/msg/Twist")]
    assert (snapshot.seconds, snapshot.who, snapshot.on_failsafe, snapshot.keep) == (12.0, "viewers", True, 20)
    assert fleet.robots["turtle2"].snapshot is None


@pytest.mark.parametrize(("section", "expected"), [
    ("snapshot:\n  topics: [scan]\n", "robots.turtle1.snapshot.topics[0]: 'scan' is not the ros_topic of a "
                                      "ros_to_mqtt rule of this robot: give its type"),
    ("snapshot:\n  topics: []\n", "robots.turtle1.snapshot.topics: a snapshot needs at least one ROS topic"),
    ("snapshot:\n  topics: [odom, odom]\n", "robots.turtle1.snapshot.topics[1]: 'odom' is listed twice"),
    ("snapshot:\n  topics: [odom]\n  seconds: 0\n", "robots.turtle1.snapshot.seconds: expected a finite number > 0"),
    ("snapshot:\n  topics: [odom]\n  who: everyone\n", "robots.turtle1.snapshot.who: expected one of"),
    ("snapshot:\n  topics: [{ros_topic: x, ros_type: nav_msgs/Odometry}]\n",
     "robots.turtle1.snapshot.topics[0].ros_type"),
    ("snapshot:\n  topics: [odom]\n  second: 5\n", "robots.turtle1.snapshot.second: unknown key 'second' (did you "
                                                 "mean 'seconds'?)"),
])
def test_a_bad_snapshot_section_says_where(section: str, expected: str) -> None:
    assert expected in _error(_with_snapshot(section))
