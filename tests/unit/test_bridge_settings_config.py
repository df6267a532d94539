"""Issue 12 config keys: limits.mode (8) and the provided-service queue (9); errors name file:line and key."""

from __future__ import annotations

import textwrap

import pytest

from roslink_mqtt.config import ConfigError, parse_fleet
from roslink_mqtt.config.passwords import hash_password

HASH = hash_password("pw", iterations=1)

FLEET = f"""\
robots:
  turtle1:
    system_id: 1
    key: k1
    password: "{HASH}"
    bridge:
      limits: {{linear: 0.5, angular: 1.5}}
    rules:
      - {{direction: mqtt_to_ros, ros_topic: cmd_vel, ros_type: geometry_msgs/msg/Twist, mqtt_topic: cmd/twist,
         preset: twist}}
"""


def _fleet(old: str = "", new: str = ""):
    return parse_fleet(textwrap.dedent(FLEET.replace(old, new, 1)), "robots.yaml")


def test_defaults() -> None:
    bridge = _fleet().robots["turtle1"].bridge
    assert bridge.limits.mode == "norm"  # the combined speed is what is limited unless the file says otherwise
    assert (bridge.provided_queue_depth, bridge.provided_max_calls) == (100, 64)


def test_values_are_read() -> None:
    bridge = _fleet("limits: {linear: 0.5, angular: 1.5}",
                    "limits: {linear: 0.5, angular: 1.5, mode: per_axis}\n"
                    "      provided_queue_depth: 500\n      provided_max_calls: 200").robots["turtle1"].bridge
    assert bridge.limits.mode == "per_axis"
    assert (bridge.provided_queue_depth, bridge.provided_max_calls) == (500, 200)
    rule = _fleet("preset: twist}", "preset: twist, limits: {linear: 1.0, mode: per_axis}}").robots["turtle1"].rules[0]
    assert rule.limits.mode == "per_axis" and rule.limits.linear == 1.0


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("angular: 1.5}", "angular: 1.5, mode: sphere}",
     'robots.yaml:7 robots.turtle1.bridge.limits.mode: expected one of norm, per_axis, got "sphere"'),
    ("angular: 1.5}", "angular: 1.5, mod: norm}",
     "robots.yaml:7 robots.turtle1.bridge.limits.mod: unknown key 'mod' (did you mean 'mode'?)"),
    ("preset: twist}", "preset: twist, limits: {mode: 2}}",
     "robots.yaml:10 robots.turtle1.rules[0].limits.mode: expected one of norm, per_axis, got 2"),
    ("angular: 1.5}", "angular: 1.5}\n      provided_queue_depth: 0",
     "robots.yaml:8 robots.turtle1.bridge.provided_queue_depth: expected integer 1..10000, got 0"),
    ("angular: 1.5}", "angular: 1.5}\n      provided_max_calls: many",
     'robots.yaml:8 robots.turtle1.bridge.provided_max_calls: expected integer 1..10000, got "many"'),
])
def test_errors_name_file_line_and_key(old: str, new: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        _fleet(old, new)
    assert str(info.value).startswith(expected), str(info.value)


def test_broker_may_list_a_clusters_nodes() -> None:
    """Failover (issue 18): a list, or comma-separated; one scheme for all; each must be a broker URL."""
    limits = "limits: {linear: 0.5, angular: 1.5}"
    listed = _fleet(limits, limits + "\n      broker: [mqtt://10.0.0.1:1883, 'mqtt://10.0.0.2:1883']")
    assert listed.robots["turtle1"].bridge.broker_url == "mqtt://10.0.0.1:1883,mqtt://10.0.0.2:1883"
    joined = _fleet(limits, limits + "\n      broker: 'mqtt://a:1883, mqtt://b'")
    assert joined.robots["turtle1"].bridge.broker_url == "mqtt://a:1883,mqtt://b"
    with pytest.raises(ConfigError, match="mix schemes"):
        _fleet(limits, limits + "\n      broker: [mqtts://a, mqtt://b]")
    with pytest.raises(ConfigError, match=r"robots\.yaml:\d+.*a list of them"):
        _fleet(limits, limits + "\n      broker: [mqtt://a, 42]")
