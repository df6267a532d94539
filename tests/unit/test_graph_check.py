"""The bridge's look at the ROS graph (bridge/core/graph_check.py): which rule has nobody on the other end, and the
closest name that exists (issue 30 item 9). The live check: tests/integration/test_cli_edges.py."""

from __future__ import annotations

from roslink_mqtt.bridge.core.graph_check import SERVICE, TOPIC, Expected, changes, check, closest
from roslink_mqtt.protocol.description import RobotDescription, ServiceEntry, StateEntry

ODOM = "nav_msgs/msg/Odometry"
GRAPH = [("/odom", [ODOM]), ("/odm_raw", ["std_msgs/msg/String"]), ("/scan", ["sensor_msgs/msg/LaserScan"])]


def test_the_closest_name_prefers_the_rules_type() -> None:
    assert closest("/odm", ODOM, GRAPH) == "/odom"
    assert closest("/odm", "std_msgs/msg/String", GRAPH) == "/odm_raw"
    assert closest("/battery", ODOM, GRAPH) is None  # nothing alike: no guess
    assert closest("/odom", ODOM, GRAPH[:1]) is None  # itself is no suggestion


def test_only_names_without_a_peer_are_warned_about_and_the_graph_is_listed_once_per_kind() -> None:
    expected = [Expected("state/global_motion", TOPIC, "/odm", ODOM),
                Expected("state/range_finder_data", TOPIC, "/scan", "sensor_msgs/msg/LaserScan"),
                Expected("call/reset", SERVICE, "/resett", "std_srvs/srv/Trigger")]
    listed: list[str] = []

    def existing(kind: str) -> list[tuple[str, list[str]]]:
        listed.append(kind)
        return GRAPH if kind == TOPIC else [("/reset", ["std_srvs/srv/Trigger"])]

    found = check(expected, lambda e: e.name in ("/scan", "/odom", "/reset"), existing)
    assert found == {"state/global_motion": "reads ROS topic /odm, which has no publisher (did you mean /odom?)",
                     "call/reset": "calls ROS service /resett, which has no server (did you mean /reset?)"}
    assert listed == [TOPIC, SERVICE]
    assert check(expected, lambda e: True, existing) == {} and listed == [TOPIC, SERVICE]


def test_changes_are_told_once() -> None:
    before = {"state/a": "reads ROS topic /a, which has no publisher"}
    assert changes(before, before) == ({}, [])
    assert changes(before, {}) == ({}, ["state/a"])
    assert changes({}, before) == (before, [])


def test_the_description_carries_the_warning() -> None:
    d = RobotDescription("r1", 1, state=(StateEntry("global_motion", "global_motion", ODOM, warning="reads …"),),
                         services=(ServiceEntry("reset", "std_srvs/srv/Trigger", warning="calls …"),))
    back = RobotDescription.from_json(d.to_json())
    assert back.state_entry("global_motion").warning == "reads …" and back.services[0].warning == "calls …"
    assert back.state_entry("odom") is None
    assert b"warning" not in RobotDescription("r1", 1, state=(StateEntry("x"),)).to_json()
