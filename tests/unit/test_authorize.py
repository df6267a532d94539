"""The one authorization rule (roslink_mqtt/authorize.py): every role x verb, and the wording, bridge and SDK.

Pure logic without rclpy: the same decisions the bridge's four checks and the access report make.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from roslink_mqtt.authorize import allowed, refusal
from roslink_mqtt.config import Role
from roslink_mqtt.protocol.control import AccessReport
from roslink_mqtt.topics import USER_VERBS, Verb

NAMES = {Verb.CMD: "cmd/twist", Verb.CALL: "reset", Verb.PROVIDE: "plan", Verb.RESPONSE: "plan",
         Verb.ADVERTISE: "lights", Verb.GOAL: "fibonacci", Verb.CANCEL: "fibonacci",
         Verb.PARAM: "sim_robot", Verb.LOG: "legacy_arm", Verb.PROVIDE_ACTION: "plan", Verb.ACTION_UPDATE: "plan",
         Verb.DECLARE: "legacy_arm", Verb.PARAM_RESULT: "legacy_arm", Verb.CONTROL: "claim",
         Verb.SNAPSHOT: "incident-1", Verb.WATCH: "camera"}
USER_VERBS = sorted(USER_VERBS, key=lambda v: v.value)  # what users send; the robot's verbs are not asked about


@pytest.mark.parametrize("verb", USER_VERBS)
@pytest.mark.parametrize("read_only", [False, True])
def test_an_operator_may_do_everything(verb: Verb, read_only: bool) -> None:
    assert allowed(Role.OPERATOR, verb, read_only=read_only)
    assert refusal("alice", Role.OPERATOR, verb, NAMES[verb], robot="turtle1", read_only=read_only) is None


@pytest.mark.parametrize(("verb", "read_only", "expected"), [
    (Verb.CALL, True, True),  # what a viewer may do besides watching, where the fleet file opens it
    (Verb.CALL, False, False),
    (Verb.GOAL, True, True), (Verb.GOAL, False, False), (Verb.CANCEL, True, True), (Verb.CANCEL, False, False),
    (Verb.PARAM, True, True), (Verb.PARAM, False, False),  # read_only: a read, or a node with viewers_may_set
    (Verb.LOG, True, False), (Verb.LOG, False, False),  # a viewer's programs do not write the robot's /rosout
    (Verb.CMD, False, False), (Verb.CMD, True, False),  # read_only means nothing outside calls
    (Verb.PROVIDE, False, False), (Verb.PROVIDE, True, False),
    (Verb.ADVERTISE, False, False), (Verb.ADVERTISE, True, False),
])
def test_a_viewer_may_only_call_read_only_services(verb: Verb, read_only: bool, expected: bool) -> None:
    assert allowed(Role.VIEWER, verb, read_only=read_only) is expected
    why = refusal("bob", Role.VIEWER, verb, NAMES[verb], robot="turtle1", read_only=read_only)
    assert (why is None) is expected


@pytest.mark.parametrize("verb", USER_VERBS)
@pytest.mark.parametrize("read_only", [False, True])
def test_no_grant_may_do_nothing(verb: Verb, read_only: bool) -> None:
    assert not allowed(None, verb, read_only=read_only)
    assert refusal("carol", None, verb, NAMES[verb], robot="turtle1", read_only=read_only) is not None


@pytest.mark.parametrize(("verb", "text"), [
    (Verb.CMD, "user 'bob' may not send 'cmd/twist' (operators only): not an operator of turtle1 (a viewer)"),
    (Verb.CALL, "user 'bob' may not call 'reset' (operators only; it is not read-only): not an operator of turtle1 "
                "(a viewer)"),
    (Verb.PROVIDE, "user 'bob' may not provide services on turtle1 (operators only): not an operator of turtle1 "
                   "(a viewer)"),
    (Verb.ADVERTISE, "user 'bob' may not publish on 'lights' (operators only): not an operator of turtle1 (a viewer)"),
])
def test_every_refusal_is_worded_the_same_way(verb: Verb, text: str) -> None:
    """docs/protocol.md quotes these, and clients and tests match on 'may not call', 'not an operator of', …"""
    assert refusal("bob", Role.VIEWER, verb, NAMES[verb], robot="turtle1") == text


def test_a_user_without_a_grant_is_told_so() -> None:
    assert refusal("carol", None, Verb.CMD, "cmd/twist", robot="turtle1") == \
        "user 'carol' may not send 'cmd/twist' (operators only): not an operator of turtle1 (no grant)"


def test_the_rule_imports_no_ros() -> None:
    """The module is the ROS-free core the bridge's rclpy handlers call; importing it must not pull rclpy in."""
    code = "import sys, roslink_mqtt.authorize; sys.exit('rclpy' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], timeout=30).returncode == 0


@pytest.mark.parametrize(("verb", "name", "report", "extra"), [
    (Verb.CMD, "cmd/twist", AccessReport("viewer", ()), ""),
    (Verb.CALL, "reset", AccessReport("viewer", ("status",)), "; you may call: status"),
    (Verb.GOAL, "dock", AccessReport("viewer", (), ("patrol",)), "; you may use: patrol"),
    (Verb.PROVIDE, "", AccessReport("viewer", ()), ""),
    (Verb.PROVIDE_ACTION, "", AccessReport("viewer", ()), ""),
    (Verb.DECLARE, "legacy_arm", AccessReport("viewer", ()), ""),
    (Verb.CONTROL, "claim", AccessReport("viewer", ()), ""),
    (Verb.CMD, "cmd/emergency_stop", AccessReport("viewer", (), estop=False), "; turtle1 says `estop: operators`"),
])
def test_the_sdk_refuses_in_the_bridges_words(verb: Verb, name: str, report: AccessReport, extra: str) -> None:
    """What the SDK refuses at once (the broker would drop it) is worded by the same rule as the bridge's refusal,
    from the role of the robot's access report, plus what a viewer may use instead."""
    from roslink_mqtt.client import RobotClient

    client = RobotClient("bob", "x", url="mqtt://127.0.0.1:1")  # never connected: the report is given
    client._access["turtle1"] = report
    expected = refusal("bob", Role.VIEWER, verb, name, robot="turtle1")
    assert expected is not None and client.refusal("turtle1", verb, name) == expected + extra
    client._access["turtle1"] = AccessReport("viewer", ("reset",), ("dock",), estop=True)  # what viewers may use
    assert client.refusal("turtle1", Verb.CALL, "reset") is None
    assert client.refusal("turtle1", Verb.GOAL, "dock") is None
    assert client.refusal("turtle1", Verb.CMD, "cmd/emergency_stop") is None
    client._access["turtle1"] = AccessReport("operator", ())
    assert client.refusal("turtle1", verb, name) is None
