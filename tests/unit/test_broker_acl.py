"""The ACL rules as pure logic (roslink_mqtt.broker.acl): filter algebra, per-login rules, cache, reload."""

from __future__ import annotations

import dataclasses
import itertools

import pytest

from roslink_mqtt.broker.acl import (
    Access,
    Action,
    DecisionCache,
    FleetAcl,
    LiveFleet,
    filters_overlap,
    is_valid_filter,
    topic_matches,
)
from roslink_mqtt.config import Grant, Role, load_fleet
from tests.support.procs import CONFIG

FLEET = load_fleet(CONFIG)
ACL = FleetAcl(FLEET)
P, R, S = Action.PUBLISH, Action.RECEIVE, Action.SUBSCRIBE


def m(f: str, t: str) -> bool:
    return topic_matches(f.split("/"), t.split("/"))


@pytest.mark.parametrize("flt,topic,expected", [
    ("a/b", "a/b", True), ("a/b", "a/c", False), ("a/+", "a/b", True), ("a/+", "a/b/c", False),
    ("a/#", "a", True), ("a/#", "a/b/c", True), ("#", "a/b", True), ("+/+", "a/b", True), ("+", "a/b", False),
    ("#", "$SYS/x", False), ("+/x", "$SYS/x", False), ("$SYS/#", "$SYS/x", True), ("a/+/c", "a//c", True),
])
def test_topic_matches(flt: str, topic: str, expected: bool) -> None:
    assert m(flt, topic) is expected


def _brute_overlap(a: str, b: str) -> bool:
    """Reference: some topic over a small alphabet (up to 4 levels) matches both filters."""
    alphabet = ["x", "y", "$S"]
    for n in range(1, 5):
        for levels in itertools.product(alphabet, repeat=n):
            if levels[0] == "$S" or "$S" not in levels:  # '$' only makes sense as a first level
                if m(a, "/".join(levels)) and m(b, "/".join(levels)):
                    return True
    return False


FILTERS = ["#", "+", "x", "x/#", "x/+", "+/y", "x/y", "x/y/#", "+/+/+", "y/#", "$S/#", "$S/x", "+/#", "x/+/y/#"]


@pytest.mark.parametrize("a,b", list(itertools.combinations_with_replacement(FILTERS, 2)))
def test_filters_overlap_matches_brute_force(a: str, b: str) -> None:
    expected = _brute_overlap(a, b)
    assert filters_overlap(a.split("/"), b.split("/")) is expected
    assert filters_overlap(b.split("/"), a.split("/")) is expected


@pytest.mark.parametrize("flt,ok", [("#", True), ("a/#", True), ("a/#/b", False), ("a#", False), ("a/+b", False),
                                    ("+/+", True), ("", False)])
def test_valid_filter(flt: str, ok: bool) -> None:
    assert is_valid_filter(flt) is ok


def test_rules_per_login_follow_design() -> None:
    def table(login: str) -> set[tuple[str, Access]]:
        return {(e.pattern, e.access) for e in ACL.entries(login)}

    assert table("turtle1") == {
        ("roslink/turtle1/heartbeat", Access.READWRITE), ("roslink/turtle1/state/#", Access.WRITE),
        ("roslink/turtle1/state/bridge", Access.READ), ("roslink/turtle1/grants", Access.READ),
        ("roslink/turtle1/to/+/#", Access.WRITE), ("roslink/turtle1/from/+/#", Access.READ),
        ("roslink/operators/alice/#", Access.READ), ("roslink/operators/bob/#", Access.READ),
        ("roslink/operators/admin/#", Access.READ)}
    assert table("alice") == {
        ("roslink/operators/alice/#", Access.WRITE), ("roslink/turtle1/heartbeat", Access.READ),
        ("roslink/turtle1/state/#", Access.READ), ("roslink/turtle1/to/alice/#", Access.READ),
        ("roslink/turtle1/from/alice/#", Access.WRITE)}
    # bob is a viewer; turtle1's only service (reset) is not read-only and its action is not open to viewers:
    # his one from/ topic is the parameter node, which every granted user may read (the bridge refuses sets)
    assert table("bob") == {
        ("roslink/operators/bob/#", Access.WRITE), ("roslink/turtle1/heartbeat", Access.READ),
        ("roslink/turtle1/state/#", Access.READ), ("roslink/turtle1/to/bob/#", Access.READ),
        ("roslink/turtle1/from/bob/param/sim_robot", Access.WRITE),
        ("roslink/turtle1/from/bob/cmd/emergency_stop", Access.WRITE),  # any granted user may stop the robot
        ("roslink/turtle1/from/bob/watch/#", Access.WRITE)}  # and watch its video (the demo fleet's camera)
    assert table("admin") == {("#", Access.READWRITE), ("$SYS/#", Access.READ),
                              ("$CONTROL/roslink/#", Access.READWRITE)}
    assert ACL.entries("nobody") == () and ACL.entries(None) == ()


def test_viewer_may_call_read_only_services_only() -> None:
    t1 = FLEET.robots["turtle1"]
    status = dataclasses.replace(t1.services[0], name="status", read_only=True)
    fleet = dataclasses.replace(FLEET, robots={**FLEET.robots, "turtle1": dataclasses.replace(
        t1, services=(*t1.services, status))})
    acl = FleetAcl(fleet)
    assert acl.allows("bob", "roslink/turtle1/from/bob/call/status", P)
    assert not acl.allows("bob", "roslink/turtle1/from/bob/call/reset", P)
    assert not acl.allows("bob", "roslink/turtle1/from/bob/cmd/twist", P)
    assert not acl.allows("bob", "roslink/turtle1/from/alice/call/status", P)
    assert acl.allows("alice", "roslink/turtle1/from/alice/call/reset", P)


@pytest.mark.parametrize("login,topic,action,expected", [
    ("alice", "roslink/turtle1/state/odom", R, True),
    ("alice", "roslink/turtle2/state/odom", R, False),
    ("alice", "roslink/turtle1/to/alice/reply/reset", R, True),
    ("alice", "roslink/turtle1/to/bob/reply/reset", R, False),
    ("alice", "roslink/turtle1/from/alice/cmd/twist", P, True),
    ("alice", "roslink/turtle1/from/bob/cmd/twist", P, False),  # nobody writes as somebody else
    ("alice", "roslink/turtle1/state/odom", P, False),  # users never write robot state
    ("alice", "roslink/operators/alice/c1", P, True),
    ("alice", "roslink/operators/bob/c1", P, False),
    ("alice", "roslink/operators/alice/c1", R, False),
    ("turtle1", "roslink/turtle1/heartbeat", P, True),
    ("turtle1", "roslink/turtle2/heartbeat", P, False),
    ("turtle1", "roslink/turtle1/to/anyone/x", P, True),
    ("turtle1", "roslink/turtle1/from/alice/cmd/twist", R, True),
    ("turtle1", "roslink/turtle2/from/carol/cmd/twist", R, False),
    ("turtle1", "roslink/operators/alice/c", R, True),
    ("turtle1", "roslink/operators/carol/c", R, False),  # carol is not granted turtle1
    ("turtle2", "roslink/operators/carol/c", R, True),
    ("admin", "anything/at/all", P, True),
    ("admin", "$SYS/broker/version", R, True),
    ("carol", "$SYS/broker/version", R, False),
    ("alice", "roslink/turtle1/state/+", P, False),  # wildcards are never concrete topics
    ("nobody", "roslink/turtle1/heartbeat", R, False),
    (None, "roslink/turtle1/heartbeat", R, False),
])
def test_decisions(login: str | None, topic: str, action: Action, expected: bool) -> None:
    assert ACL.allows(login, topic, action) is expected


@pytest.mark.parametrize("login,flt,expected", [
    ("alice", "#", True), ("alice", "roslink/#", True), ("alice", "roslink/+/heartbeat", True),
    ("alice", "roslink/turtle1/#", True), ("alice", "roslink/turtle2/#", False),
    ("alice", "roslink/+/to/bob/#", False), ("alice", "roslink/+/to/alice/#", True),
    ("alice", "$SYS/#", False), ("admin", "$SYS/#", True), ("admin", "#", True),
    ("bob", "roslink/turtle1/from/#", False), ("turtle1", "roslink/turtle1/from/+/#", True),
    ("turtle1", "roslink/operators/+/+", True),
    ("turtle1", "roslink/turtle1/state/#", True),  # it reads state/bridge: another bridge's claim
    ("turtle1", "roslink/turtle1/state/global_motion", False),
    ("alice", "roslink/turtle1/state/#/x", False),  # invalid filter
    ("carol", "+/+/heartbeat", True), ("nobody", "#", False),
])
def test_subscribe_accepts_filters_that_can_match_something_readable(login: str, flt: str, expected: bool) -> None:
    assert ACL.allows(login, flt, S) is expected


def test_decision_cache_and_reload() -> None:
    live = LiveFleet(FLEET)
    cache = DecisionCache(live.acl, "bob", limit=3)
    topic = "roslink/turtle1/state/robot_status"
    assert cache.lookup(topic, R) is None
    assert cache.decide(topic, R) is True
    assert cache.lookup(topic, R) is True
    for i in range(5):  # bounded
        cache.decide(f"roslink/x/{i}", R)
    assert len(cache) <= 3

    # remove bob's grant: a new FleetAcl, so every cache made from the old one is stale
    users = {**FLEET.users, "bob": dataclasses.replace(FLEET.users["bob"], grants=())}
    change = live.replace(dataclasses.replace(FLEET, users=users))
    assert change.removed_logins == () and change.changed_passwords == ()
    assert not cache.valid_for(live.acl, "bob")
    assert DecisionCache(live.acl, "bob").decide(topic, R) is False
    assert not cache.valid_for(cache.acl, "alice")  # a session resumed under another login

    users = dict(users)  # the running fleet holds the previous dict: never edit it in place
    users.pop("carol")
    users["dave"] = dataclasses.replace(FLEET.users["alice"], name="dave",
                                        grants=(Grant("demo-key-turtle2", Role.VIEWER),))
    users["alice"] = dataclasses.replace(FLEET.users["alice"], password_hash=FLEET.users["bob"].password_hash)
    change = live.replace(dataclasses.replace(FLEET, users=users))
    assert change.removed_logins == ("carol",)
    assert change.added_logins == ("dave",)
    assert change.changed_passwords == ("alice",)
    assert live.acl.allows("dave", "roslink/turtle2/heartbeat", R)
