"""The users and grants the bridge obeys, and everything that follows at once when they change. ROS-free.

They come from the fleet file at start, then from the broker's retained grants message (``P/<robot>/grants``,
written by the fleet's administrators) and from a re-read file (SIGHUP): the latest word wins. The broker applies
the same change on its side; the bridge must follow, or a newly granted operator stays refused and a revoked one
keeps control until the dead-man stops the robot.

A change applies here, in one place and in this order:

1. the endpoint (:meth:`CommandEndpoint.set_fleet`): a demoted motion owner's lease ends (the robot stops if they
   were driving) and their goals are cancelled;
2. what a user who lost a role holds on the robot is withdrawn, by one path: every :class:`Holdings` of
   ``operators_hold`` (services and actions they provide, topics they advertise, parameter nodes they declared)
   for a user who is no longer an operator, every one of ``users_hold`` (video they watch) for a user who lost the
   robot altogether;
3. the retained access reports (``to/<user>/access``; a lost user's cleared);
4. the links' subscriptions: a user who changes role moves between the command and viewer links (leaving the old
   one first: a gap of a few ms, never the same command arriving twice).
"""

from __future__ import annotations

import dataclasses
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from enum import Enum
from typing import Protocol

from ...config import Fleet, Robot, Role
from ...config.grants import with_grants
from ...protocol.errors import ProtocolError
from ...protocol.grants import RobotGrants
from ...topics import ANY, TopicTree
from .access import access_reports, cleared_reports
from .claim import ANNOUNCE
from .endpoint import CommandEndpoint

log = logging.getLogger(__name__)


class Holdings(Protocol):
    """Something a user holds on the robot while they have a role (a provided service, a watch …)."""

    def withdraw_user(self, user: str, reason: str) -> None:
        """``user`` lost the role it needs: end what they hold, telling anyone waiting on it ``reason``."""
        ...


class Subscriber(Protocol):
    """A link's subscriptions (:class:`~roslink_mqtt.bridge.core.link.MqttLink`)."""

    def subscribe(self, topic: str, qos: int = 1) -> None: ...

    def unsubscribe(self, topic: str) -> None: ...


class LinkKind(Enum):
    """The bridge's connections that carry users' traffic to it."""

    COMMAND = "command"  # operators' commands, requests and presence; the robot's own heartbeat and announcements
    VIEWER = "viewer"  # everyone else's, read at a bounded rate; the robot's grants
    STOP = "stop"  # emergency stops only, of those the endpoint obeys


Publish = Callable[[str, bytes, int, bool], object]  # topic, payload, qos, retain


def static_part(robot: Robot) -> tuple[object, ...]:
    """What a reload cannot change in a running bridge (rules and settings), ignoring line numbers."""
    return (robot.system_id, robot.type, robot.bridge, tuple(replace(r, line=None) for r in robot.rules),
            tuple(replace(s, line=None) for s in robot.services), tuple(replace(v, line=None) for v in robot.video))


class FleetFollower:
    """The fleet the bridge obeys (:attr:`fleet`), kept current by grants messages and reloads."""

    def __init__(self, fleet: Fleet, robot: Robot, topics: TopicTree, endpoint: CommandEndpoint, publish: Publish,
                 *, stop_leaves: Sequence[str] = (), operators_hold: Sequence[Holdings] = (),
                 users_hold: Sequence[Holdings] = ()) -> None:
        """``publish``: the command link's (retained access reports); ``stop_leaves``: the command leaves that are
        emergency stops (the stop link subscribes to them)."""
        self.fleet, self.robot, self.topics, self.endpoint = fleet, robot, topics, endpoint
        self.publish, self.stop_leaves = publish, tuple(stop_leaves)
        self.operators_hold, self.users_hold = tuple(operators_hold), tuple(users_hold)
        self.links: dict[LinkKind, Subscriber] = {}  # set once the links exist (they ask for subscriptions first)
        self.grants: RobotGrants | None = None  # the broker's latest (protocol/grants.py); None: the file's apply
        self.grants_arrived = threading.Event()  # the bridge holds its command link back until they have (briefly)
        self._lock = threading.Lock()  # SIGHUP (main thread) and a grants message (paho's) both apply a fleet
        name = robot.name
        self.heartbeat_topic, self.announce_topic = topics.heartbeat(name), topics.state(name, ANNOUNCE)
        self.grants_topic = topics.grants(name)

    # -- what changes it ------------------------------------------------------------------------------------------
    def on_grants(self, payload: bytes) -> None:
        """The robot's grants from the broker (paho's thread): they replace the users the bridge knows, at once. A
        malformed message keeps the grants the bridge has; an empty one (the retained message cleared) leaves it
        none, refusing everyone until new ones arrive."""
        robot = self.robot.name
        if not payload:
            log.warning("the grants of %s were withdrawn on the broker: every command is refused until new ones "
                        "arrive", robot)
            with self._lock:
                self.grants = None
                self._apply(dataclasses.replace(self.fleet, users={}, grants_pending=True), "grants withdrawn")
            return
        try:
            grants = RobotGrants.from_json(payload)
        except ProtocolError as err:
            log.error("ignored grants on %s, keeping the current ones: %s", self.grants_topic, err)
            return
        if grants.robot != robot:
            log.error("ignored grants for robot %s on %s, keeping the current ones", grants.robot, self.grants_topic)
            return
        with self._lock:
            self.grants = grants
            self._apply(with_grants(self.fleet, grants), f"applied grants from {grants.by or 'the broker'}")
        self.grants_arrived.set()

    def reload(self, fleet: Fleet) -> None:
        """A re-read fleet file (SIGHUP); rule changes need a restart. A fleet file's users and grants apply (until
        the broker's next grants message); a robot file has none, so the broker's grants stay."""
        with self._lock:
            grants = self.grants
            if fleet.grants_pending and grants is not None and self.robot.name in fleet.robots:
                fleet = with_grants(fleet, grants)  # (_apply says why a robot is missing)
            elif not fleet.grants_pending:
                self.grants = None  # the file's grants now; the broker's next message replaces them again
            self._apply(fleet, f"reloaded {fleet.file}")

    def _apply(self, fleet: Fleet, source: str) -> None:
        name = self.robot.name
        robot = fleet.robots.get(name)
        if robot is None:
            log.error("reload: robot %s is no longer in %s; keeping the current grants", name, fleet.file)
            return
        if static_part(robot) != static_part(self.robot):
            log.warning("reload: the rules or bridge settings of %s changed; restart the bridge to apply them "
                        "(users and grants apply now)", name)
        before, after = self.fleet.users_of(name), fleet.users_of(name)
        old_fleet, self.fleet = self.fleet, fleet
        for user in self.endpoint.set_fleet(fleet):
            for holder in self.operators_hold:
                holder.withdraw_user(user, f"{user} is no longer an operator of {name}")
        for user in sorted(set(before) - set(after)):
            for holder in self.users_hold:
                holder.withdraw_user(user, f"{user} may no longer see {name}")
        self.publish_access(cleared=cleared_reports(old_fleet, fleet, name, self.topics))
        changes = {kind: (self.subscriptions(kind, old_fleet), self.subscriptions(kind, fleet)) for kind in self.links}
        for kind, (old, new) in changes.items():
            for topic, _ in set(old) - set(new):
                self.links[kind].unsubscribe(topic)
        for kind, (old, new) in changes.items():
            for topic, qos in sorted(set(new) - set(old)):
                self.links[kind].subscribe(topic, qos)
        log.info("%s: %d users may see %s (%s)", source, len(after), name,
                 ", ".join(f"{u}:{r.value}" for u, r in sorted(after.items())) or "none")

    # -- what follows from it -------------------------------------------------------------------------------------
    def publish_access(self, cleared: Sequence[str] = ()) -> None:
        """Retained ``to/<user>/access`` for every granted user (bridge/core/access.py says why); clear ``cleared``."""
        for topic in cleared:
            self.publish(topic, b"", 1, True)
        for topic, body in access_reports(self.fleet, self.robot.name, self.topics).items():
            self.publish(topic, body, 1, True)

    def subscriptions(self, kind: LinkKind, fleet: Fleet | None = None) -> list[tuple[str, int]]:
        """What a link of ``kind`` subscribes to under ``fleet`` (default: the current one; re-read at each connect).

        Command link: the robot's own heartbeat and ``state/bridge`` (where another bridge for this robot would show
        itself, bridge/core/claim.py), operators' inputs and presence. Viewer link: the robot's grants, every other
        user's inputs (users of the fleet without a grant here too: a broker whose ACL is older than the bridge's
        grants may still let them publish, and they must hear why nothing happens instead of silence), viewers'
        presence. Stop link: the emergency-stop inputs of everyone the endpoint obeys there: operators, and viewers
        unless robots.yaml says ``estop: operators`` (then a viewer's stop comes on the viewer link and is refused
        there, with the reason)."""
        fleet = fleet or self.fleet
        name = self.robot.name
        granted = fleet.users_of(name)
        if kind is LinkKind.STOP:
            robot = fleet.robots.get(name, self.robot)
            stoppers = sorted(u for u, role in granted.items() if role is Role.OPERATOR or robot.estop == "viewers")
            return [(self.topics.from_user(name, user, leaf), 1) for user in stoppers for leaf in self.stop_leaves]
        subs = [(self.heartbeat_topic, 1), (self.announce_topic, 1)] if kind is LinkKind.COMMAND else \
            [(self.grants_topic, 1)]
        if kind is LinkKind.VIEWER and fleet.grants_pending:  # nobody known yet: hear everyone, to refuse with why
            subs.append((self.topics.from_user_filter(name, ANY), 1))
        for user in sorted(fleet.users):
            role = granted.get(user)
            if (role is Role.OPERATOR) == (kind is LinkKind.COMMAND):
                subs.append((self.topics.from_user_filter(name, user), 1))
                if role is not None:
                    subs.append((self.topics.operators_of(user), 1))
        return subs

    def subscriptions_of(self, kind: LinkKind) -> Callable[[], list[tuple[str, int]]]:
        """A link's ``subscriptions`` callback (read at each connect)."""
        return lambda: self.subscriptions(kind)

    def use_links(self, links: Mapping[LinkKind, Subscriber]) -> None:
        """The links whose subscriptions follow a change (before they start)."""
        self.links = dict(links)
