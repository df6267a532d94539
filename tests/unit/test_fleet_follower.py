"""The bridge's core follows its users and grants (bridge/core/fleet_follower.py) and routes what it receives
(bridge/core/inbox.py): the demo fleet's turtle1, grants messages as the broker sends them, recording fakes for the
endpoint, the links and what users hold. The real bridge does the same in tests/integration/test_grants_*.py."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import pytest

from roslink_mqtt.bridge.core.claim import ANNOUNCE
from roslink_mqtt.bridge.core.fleet_follower import FleetFollower, LinkKind
from roslink_mqtt.bridge.core.inbox import Inbox
from roslink_mqtt.config import Fleet, Role, load_fleet
from roslink_mqtt.config.grants import with_grants
from roslink_mqtt.protocol.grants import RobotGrants
from tests.support.procs import CONFIG

ROBOT = "turtle1"
STOP_LEAF = "cmd/emergency_stop"


@dataclass
class Endpoint:
    """What the follower asks of the command endpoint: set_fleet → the users demoted from operator."""

    fleet: Fleet
    seen: list[Fleet] = field(default_factory=list)

    def set_fleet(self, fleet: Fleet) -> list[str]:
        before, after = self.fleet.users_of(ROBOT), fleet.users_of(ROBOT)
        self.fleet = fleet
        self.seen.append(fleet)
        return sorted(u for u, r in before.items() if r is Role.OPERATOR and after.get(u) is not Role.OPERATOR)


@dataclass
class Holder:
    withdrawn: list[tuple[str, str]] = field(default_factory=list)

    def withdraw_user(self, user: str, reason: str) -> None:
        self.withdrawn.append((user, reason))


@dataclass
class Link:
    events: list[tuple[str, str]] = field(default_factory=list)

    def subscribe(self, topic: str, qos: int = 1) -> None:
        self.events.append(("sub", topic))

    def unsubscribe(self, topic: str) -> None:
        self.events.append(("unsub", topic))


@dataclass
class Harness:
    follower: FleetFollower
    endpoint: Endpoint
    operators: list[Holder]
    users: Holder
    links: dict[LinkKind, Link]
    published: list[tuple[str, bytes, int, bool]]


def grants(users: dict[str, str], robot: str = ROBOT) -> bytes:
    return RobotGrants(robot, users, issued=1.0, by="broker").to_json()


@pytest.fixture
def h() -> Harness:
    fleet = with_grants(load_fleet(CONFIG), RobotGrants(ROBOT, {"alice": "operator", "bob": "viewer"}))
    endpoint = Endpoint(fleet)
    operators, users = [Holder(), Holder()], Holder()
    published: list[tuple[str, bytes, int, bool]] = []
    follower = FleetFollower(fleet, fleet.robots[ROBOT], fleet.topics, endpoint,  # type: ignore[arg-type]
                             lambda *m: published.append(m), stop_leaves=(STOP_LEAF,), operators_hold=operators,
                             users_hold=(users,))
    links = {kind: Link() for kind in LinkKind}
    follower.use_links(links)
    return Harness(follower, endpoint, operators, users, links, published)


def test_a_demoted_operator_loses_everything_an_operator_holds_through_one_path(h: Harness) -> None:
    h.follower.on_grants(grants({"alice": "viewer", "bob": "viewer"}))
    assert h.endpoint.fleet.users_of(ROBOT) == {"alice": Role.VIEWER, "bob": Role.VIEWER}
    for holder in h.operators:
        assert holder.withdrawn == [("alice", "alice is no longer an operator of turtle1")]
    assert h.users.withdrawn == []  # alice may still see turtle1: her watches stay
    assert h.follower.grants_arrived.is_set()


def test_a_user_who_loses_the_robot_loses_what_any_user_holds(h: Harness) -> None:
    h.follower.on_grants(grants({"alice": "operator"}))
    assert h.users.withdrawn == [("bob", "bob may no longer see turtle1")]
    assert all(holder.withdrawn == [] for holder in h.operators)
    topics = h.follower.topics
    assert (topics.access(ROBOT, "bob"), b"", 1, True) in h.published  # bob's report cleared
    assert any(t == topics.access(ROBOT, "alice") and body for t, body, _, _ in h.published)


def test_a_user_who_changes_role_moves_between_the_links_leaving_first(h: Harness) -> None:
    topics = h.follower.topics
    bob_in = topics.from_user_filter(ROBOT, "bob")
    assert (bob_in, 1) in h.follower.subscriptions(LinkKind.VIEWER)
    assert (bob_in, 1) not in h.follower.subscriptions(LinkKind.COMMAND)
    h.follower.on_grants(grants({"alice": "operator", "bob": "operator", "carol": "operator"}))
    viewer, command = h.links[LinkKind.VIEWER].events, h.links[LinkKind.COMMAND].events
    assert ("unsub", bob_in) in viewer and ("sub", bob_in) in command
    assert ("sub", topics.from_user(ROBOT, "carol", STOP_LEAF)) in h.links[LinkKind.STOP].events


def test_the_command_link_hears_the_robots_own_heartbeat_and_announcements(h: Harness) -> None:
    topics = h.follower.topics
    command = [t for t, _ in h.follower.subscriptions(LinkKind.COMMAND)]
    assert command[:2] == [topics.heartbeat(ROBOT), topics.state(ROBOT, ANNOUNCE)]
    assert topics.grants(ROBOT) in [t for t, _ in h.follower.subscriptions(LinkKind.VIEWER)]


@pytest.mark.parametrize(("payload", "why"), [(b"{not json", "malformed"),
                                              (grants({"mallory": "operator"}, robot="turtle2"), "another robot's")])
def test_grants_that_cannot_apply_keep_the_current_ones(h: Harness, payload: bytes, why: str) -> None:
    h.follower.on_grants(payload)
    assert h.endpoint.seen == [], why
    assert h.follower.fleet.users_of(ROBOT) == {"alice": Role.OPERATOR, "bob": Role.VIEWER}


def test_withdrawn_grants_refuse_everyone_until_new_ones_come(h: Harness) -> None:
    h.follower.on_grants(b"")
    assert h.follower.fleet.users_of(ROBOT) == {} and h.follower.fleet.grants_pending
    assert all(holder.withdrawn == [("alice", "alice is no longer an operator of turtle1")] for holder in h.operators)
    everyone = h.follower.topics.from_user_filter(ROBOT, "+")
    assert ("sub", everyone) in h.links[LinkKind.VIEWER].events  # heard, to be refused with the reason


def test_a_robot_file_reload_keeps_the_brokers_grants(h: Harness) -> None:
    h.follower.on_grants(grants({"alice": "operator", "carol": "viewer"}))
    pending = load_fleet(CONFIG)
    h.follower.reload(dataclasses.replace(pending, users={}, grants_pending=True))
    assert h.follower.fleet.users_of(ROBOT) == {"alice": Role.OPERATOR, "carol": Role.VIEWER}


# -- the inbox ---------------------------------------------------------------------------------------------------
@dataclass
class Claims:
    seen: list[tuple[str, str, bytes]] = field(default_factory=list)

    def on_heartbeat(self, robot: str, payload: bytes, retained: bool) -> None:
        self.seen.append(("heartbeat", robot, payload))

    def on_announcement(self, robot: str, payload: bytes, retained: bool) -> None:
        self.seen.append(("announcement", robot, payload))


def test_the_inbox_routes_the_bridges_own_business_and_drops_a_stops_second_copy(h: Harness) -> None:
    claims, grants_seen, delivered = Claims(), [], []
    f = h.follower
    inbox = Inbox(ROBOT, heartbeat_topic=f.heartbeat_topic, announce_topic=f.announce_topic,
                  grants_topic=f.grants_topic, claims=claims, on_grants=grants_seen.append,  # type: ignore[arg-type]
                  stop_leaves=(STOP_LEAF,), endpoint=lambda *m: delivered.append(m))
    stop = f.topics.from_user(ROBOT, "alice", STOP_LEAF)
    twist = f.topics.from_user(ROBOT, "alice", "cmd/twist")
    messages: list[tuple[str, bytes]] = [(f.heartbeat_topic, b"hb"), (f.announce_topic, b"an"),
                                         (f.grants_topic, b"g"), (stop, b"s1"), (stop, b"s1"), (twist, b"t"),
                                         (stop, b"s2")]
    for topic, payload in messages:
        inbox.on_message(topic, payload, False, 1.0)
    assert claims.seen == [("heartbeat", ROBOT, b"hb"), ("announcement", ROBOT, b"an")]
    assert grants_seen == [b"g"]
    assert [(t, p) for t, p, *_ in delivered] == [(stop, b"s1"), (twist, b"t"), (stop, b"s2")]
