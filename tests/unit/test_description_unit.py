"""The robot description without ROS: the typed body (round trip, exact refusals) and the builder from config."""

from __future__ import annotations

import orjson
import pytest

from roslink_mqtt.authorize import allowed
from roslink_mqtt.bridge.ros.description import ACK_STATE, build_description, description_message
from roslink_mqtt.config import Role, parse_fleet
from roslink_mqtt.protocol import ProtocolError
from roslink_mqtt.protocol.description import (
    DESCRIPTION,
    EXAMPLE,
    OPERATORS,
    VIEWERS,
    ActionEntry,
    CommandEntry,
    ParameterEntry,
    RobotDescription,
    ServiceEntry,
    StateEntry,
)
from roslink_mqtt.topics import TopicTree, Verb

HASH = ("$7$1000$xW9efKKgPue/EKvk$ZwAL9AkBB/xMBbq4Dx82lEIyJmioKSOjrCxvgLunoq7qt26ftAzaxpp4lV9M3Qqx9OOixdZslxwHQ8es"
        "59szvg==")
FLEET = f"""
robots:
  r1:
    system_id: 7
    key: k1
    type: quadrotor
    password: "{HASH}"
    bridge: {{limits: {{linear: 0.8, angular: 2.0}}}}
    services:
      - {{name: reset, ros_service: reset, ros_type: std_srvs/srv/Trigger}}
      - {{name: status, ros_service: status, ros_type: std_srvs/srv/Trigger, read_only: true, timeout: 2.0}}
    actions:
      - {{name: fib, ros_action: fib, ros_type: test_msgs/action/Fibonacci, viewers: true, timeout: 9.0}}
      - {{name: fib2, ros_action: fib2, ros_type: test_msgs/action/Fibonacci}}
    parameters:
      - {{name: base, node: base_controller}}
      - {{name: cam, node: /camera/driver, viewers_may_set: true, timeout: 2.0}}
    rules:
      - {{direction: ros_to_mqtt, ros_topic: odom, ros_type: nav_msgs/msg/Odometry, mqtt_topic: state/global_motion,
         preset: global_motion, max_rate: 10}}
      - {{direction: ros_to_mqtt, ros_topic: temp, ros_type: std_msgs/msg/Float32, mqtt_topic: state/temp,
         retain: true, mqtt_qos: 1}}
      - {{direction: mqtt_to_ros, mqtt_topic: cmd/twist, ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist,
         preset: twist, limits: {{linear: 0.3}}}}
      - {{direction: mqtt_to_ros, mqtt_topic: lights, ros_topic: lights, ros_type: std_msgs/msg/Bool,
         on_demand: true}}
      - {{direction: mqtt_to_ros, mqtt_topic: cmd/land, ros_topic: land, ros_type: std_srvs/srv/Trigger,
         preset: land}}
users:
  u: {{password: "{HASH}", grants: [{{key: k1, role: viewer}}]}}
"""

LAYOUTS = {
    "nav_msgs/msg/Odometry": {"child_frame_id": "string"},
    "std_msgs/msg/Float32": {"data": "float32"},
    "geometry_msgs/msg/Twist": {"linear": {"type": "geometry_msgs/msg/Vector3", "fields": {"x": "float64"}}},
    "std_msgs/msg/Bool": {"data": "bool"},
    "std_srvs/srv/Trigger": {"request": {}, "response": {"success": "bool", "message": "string"}},
    "test_msgs/action/Fibonacci": {"goal": {"order": "int32"}, "result": {"sequence": "int32[]"},
                                   "feedback": {"sequence": "int32[]"}},
}


def robot():
    return parse_fleet(FLEET).robots["r1"]


def fields_of(asked: list[str]):
    def lookup(name: str) -> dict:
        asked.append(name)
        return LAYOUTS[name]
    return lookup


# -- the builder -------------------------------------------------------------------------------------------


def test_builder_lists_every_entry_of_the_config_with_who_may_use_it() -> None:
    asked: list[str] = []
    d = build_description(robot(), fields_of(asked))
    assert (d.robot, d.system_id, d.type, d.protocol_version) == ("r1", 7, "quadrotor", 2)
    assert d.limits == {"linear": 0.8, "angular": 2.0, "mode": "norm"}
    assert d.state == (
        StateEntry("global_motion", "global_motion", "nav_msgs/msg/Odometry", max_rate=10.0, who=VIEWERS),
        StateEntry("temp", None, "std_msgs/msg/Float32", retained=True, who=VIEWERS),
        StateEntry(ACK_STATE, "ack"),
    )
    twist, lights, land = d.commands
    assert twist == CommandEntry("cmd/twist", "twist", "geometry_msgs/msg/Twist",
                                 limits={"linear": 0.3, "angular": 1.5, "mode": "norm"}, who=OPERATORS)
    assert lights == CommandEntry("lights", None, "std_msgs/msg/Bool", on_demand=True, who=OPERATORS)
    assert land.message == "land" and land.ros_type == "std_srvs/srv/Trigger" and land.limits == {}
    assert d.services == (ServiceEntry("reset", "std_srvs/srv/Trigger", False, 5.0, OPERATORS),
                          ServiceEntry("status", "std_srvs/srv/Trigger", True, 2.0, VIEWERS))
    assert d.actions == (ActionEntry("fib", "test_msgs/action/Fibonacci", True, 9.0, 10.0, VIEWERS),
                         ActionEntry("fib2", "test_msgs/action/Fibonacci", False, 60.0, 10.0, OPERATORS))
    assert d.parameters == (ParameterEntry("base", "base_controller", OPERATORS, 5.0, VIEWERS),
                            ParameterEntry("cam", "/camera/driver", VIEWERS, 2.0, VIEWERS))
    assert d.types == LAYOUTS
    assert sorted(asked) == sorted(LAYOUTS)  # each type introspected once


def test_who_is_the_authorization_rule_for_a_viewer() -> None:
    d = build_description(robot(), fields_of([]))
    for s in d.services:
        assert (s.who == VIEWERS) is allowed(Role.VIEWER, Verb.CALL, read_only=s.read_only)
    for a in d.actions:
        assert (a.who == VIEWERS) is allowed(Role.VIEWER, Verb.GOAL, read_only=a.viewers)
    assert all(c.who == OPERATORS for c in d.commands) and all(s.who == VIEWERS for s in d.state)
    for p in d.parameters:
        assert p.who == VIEWERS and allowed(Role.VIEWER, Verb.PARAM, read_only=True)
        assert (p.set_by == VIEWERS) is allowed(Role.VIEWER, Verb.PARAM, read_only=p.node == "/camera/driver")


def test_a_type_without_layout_is_left_out_not_fatal(caplog) -> None:
    def partial(name: str) -> dict:
        if name == "std_msgs/msg/Float32":
            raise ValueError("not installed")
        return LAYOUTS[name]

    d = build_description(robot(), partial)
    assert "std_msgs/msg/Float32" not in d.types and "nav_msgs/msg/Odometry" in d.types
    assert "no field layout for std_msgs/msg/Float32" in caplog.text


def test_message_goes_to_the_retained_state_topic() -> None:
    topic, body = description_message(robot(), TopicTree("fleet/a"), fields_of([]))
    assert topic == TopicTree("fleet/a").state("r1", DESCRIPTION)
    assert RobotDescription.from_json(body) == build_description(robot(), fields_of([]))
    assert RobotDescription.QOS == 1 and RobotDescription.RETAINED is True


# -- the body --------------------------------------------------------------------------------------------


def test_round_trip_and_lookup() -> None:
    again = RobotDescription.from_json(EXAMPLE.to_json())
    assert again == EXAMPLE
    assert again.entry("fibonacci").who == OPERATORS and again.entry("nope") is None
    assert again.layout("std_msgs/msg/Bool") == {"data": "bool"} and again.layout(None) is None


def test_unknown_fields_are_ignored_missing_lists_are_empty() -> None:
    d = RobotDescription.from_json(b'{"robot": "r", "system_id": 3, "future": 1, "state": [{"name": "x", "new": 2}]}')
    assert d.state == (StateEntry("x"),) and d.commands == () and d.types == {}


@pytest.mark.parametrize("body, reason", [
    (b"[]", "description: expected a JSON object, got an array of 0"),
    (b'{"system_id": 1}', "description: robot: missing (expected non-empty string)"),
    (b'{"robot": "r", "system_id": "1"}', 'description: system_id: expected integer, got "1"'),
    (b'{"robot": "r", "system_id": 1, "services": [{"ros_type": "t"}]}',
     "description: services[0].name: missing; expected an object"),
    (b'{"robot": "r", "system_id": 1, "commands": [{"name": "c", "fields": {"lx": 1}}]}',
     "description: commands[0].fields: expected object of strings (MQTT field → ROS field path), got an object"),
    (b'{"robot": "r", "system_id": 1, "state": [{"name": 5}]}',
     "description: state[0].name: expected non-empty string, got 5"),
    (b'{"robot": "r", "system_id": 1, "services": [{"name": "s", "ros_type": "t", "who": "admins"}]}',
     'description: services[0].who: expected "operators" or "viewers", got "admins"'),
    (b'{"robot": "r", "system_id": 1, "actions": [{"name": "a", "ros_type": "t", "timeout": "long"}]}',
     'description: actions[0].timeout: expected number or null, got "long"'),
    (b'{"robot": "r", "system_id": 1, "commands": [{"name": "c", "on_demand": 1}]}',
     "description: commands[0].on_demand: expected boolean, got 1"),
    (b'{"robot": "r", "system_id": 1, "parameters": [{"name": "p", "node": "n", "set_by": "all"}]}',
     'description: parameters[0].set_by: expected "operators" or "viewers", got "all"'),
    (b'{"robot": "r", "system_id": 1, "types": {"a/msg/B": 3}}',
     "description: types: expected an object of ROS type → field layout, got an object"),
])
def test_malformed_bodies_are_refused_with_the_reason(body: bytes, reason: str) -> None:
    with pytest.raises(ProtocolError) as err:
        RobotDescription.from_json(body)
    assert str(err.value) == reason


def test_optional_keys_that_say_nothing_stay_off_the_wire() -> None:
    assert StateEntry("x", None, "std_msgs/msg/Bool").to_body() == {"name": "x", "ros_type": "std_msgs/msg/Bool",
                                                                     "who": VIEWERS}
    body = orjson.loads(EXAMPLE.to_json())
    assert set(body) == {f.name for f in RobotDescription.FIELDS}


def test_an_entry_that_is_not_an_object_is_refused_where_it_is() -> None:
    with pytest.raises(ProtocolError) as err:
        StateEntry.from_body(5, "state[0]")
    assert str(err.value) == "description: state[0]: expected an object, got 5"
