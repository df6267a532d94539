"""Who may read and write which topic: broker/README.md's table as pure logic, derived from a :class:`Fleet`.

One list of :class:`AclEntry` per login is the single source of truth. The embedded
broker's topic plugin decides from it, and ``roslink-mqtt acl export`` writes the same
list as a Mosquitto ACL file, so the two brokers cannot drift apart.

With ``P`` the fleet prefix (``roslink``):

* robot ``R`` writes ``P/R/heartbeat``, ``P/R/state/#`` and ``P/R/to/+/#``, and reads
  ``P/R/from/+/#``, ``P/R/heartbeat``, ``P/R/state/bridge`` (where a second bridge of ``R`` shows itself:
  one live bridge per robot) and ``P/R/grants`` (its users, written by admins only) plus
  ``P/operators/<u>/#`` for every user ``u`` granted ``R``.
* user ``U`` granted ``R`` reads ``P/R/heartbeat``, ``P/R/state/#`` and ``P/R/to/U/#``, and
  writes ``P/operators/U/#``. An operator also writes ``P/R/from/U/#``; a viewer only
  ``P/R/from/U/call/<svc>`` for the services of ``R`` marked ``read_only``, and ``P/R/from/U/goal/<a>`` and
  ``P/R/from/U/cancel/<a>`` for its actions marked ``viewers: true``, ``P/R/from/U/param/<n>`` for
  its exposed parameter nodes (reads; the bridge refuses a viewer's set unless ``viewers_may_set``), and the
  robot's emergency-stop inputs (``P/R/from/U/cmd/emergency_stop``) unless the robot says ``estop: operators``.
* a robot with a ``vda5050`` profile (manufacturer ``M``, serial number ``S``) reads ``uagv/v2/M/S/order`` and
  ``…/instantActions`` and writes ``…/state``, ``…/visualization``, ``…/connection`` and ``…/factsheet``; the
  profile's master control (an operator of the robot) the other way round; no other user has them.
* an admin reads and writes ``#`` and ``$CONTROL/roslink/#`` (``fleet apply``: broker/admin.py) and reads
  ``$SYS/#``. Nobody writes ``$SYS`` (brokers refuse it).
* an unknown login (and anonymous) may do nothing.

The three actions a broker asks about:

* ``publish`` / ``receive``: the concrete topic must match a WRITE / READ pattern.
* ``subscribe``: the topic *filter* is accepted when it can match at least one topic the
  login may read (so ``roslink/#`` and ``roslink/+/heartbeat`` work for discovery). That
  alone would leak, so the broker must also check ``receive`` on every delivery, live
  and retained. Mosquitto 2.0 accepts every filter and filters on delivery; both
  deliver exactly the readable messages.

Nothing here imports amqtt: this module is the unit-testable part of the broker.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntFlag
from typing import TYPE_CHECKING

from ..compat import StrEnum
from ..config import Fleet, Role
from ..topics import ANY, FLEET_CONTROL_FILTER, SYS_TOPICS, Kind, Verb, filter_levels
from ..vda5050 import wire

if TYPE_CHECKING:
    from .limits import BrokerLimits


class Access(IntFlag):
    READ = 1
    WRITE = 2
    READWRITE = 3

    @property
    def mosquitto(self) -> str:
        """The word a Mosquitto ACL file uses for this access."""
        return {Access.READ: "read", Access.WRITE: "write", Access.READWRITE: "readwrite"}[self]


class Action(StrEnum):
    """What a broker asks about; the values equal amqtt's ``amqtt.contexts.Action``."""

    PUBLISH = "publish"
    SUBSCRIBE = "subscribe"
    RECEIVE = "receive"


@dataclass(frozen=True, slots=True)
class AclEntry:
    """One pattern (an MQTT topic filter) and what the login may do on topics it matches."""

    pattern: str
    access: Access
    levels: tuple[str, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "levels", filter_levels(self.pattern))


# -- MQTT filter algebra --------------------------------------------------------------


def topic_matches(pattern: tuple[str, ...] | list[str], topic_levels: tuple[str, ...] | list[str]) -> bool:
    """MQTT 3.1.1 §4.7 matching of a concrete topic against a filter, both split at ``/``.

    A topic starting with ``$`` is never matched by a filter whose first level is a
    wildcard (MQTT-4.7.2-1), so ``#`` does not reach ``$SYS``.
    """
    if topic_levels[0][:1] == "$" and pattern[0] in ("+", "#"):
        return False
    n = len(topic_levels)
    for i, level in enumerate(pattern):
        if level == "#":
            return True  # also matches the parent level: 'a/#' matches 'a'
        if i >= n:
            return False
        if level != "+" and level != topic_levels[i]:
            return False
    return len(pattern) == n


def filters_overlap(a: tuple[str, ...] | list[str], b: tuple[str, ...] | list[str]) -> bool:
    """True when at least one concrete topic matches both filters (split at ``/``)."""
    a_dollar, b_dollar = a[0][:1] == "$", b[0][:1] == "$"
    if (a_dollar and b[0] in ("+", "#")) or (b_dollar and a[0] in ("+", "#")):
        return False  # a wildcard first level cannot reach '$' topics
    for i in range(max(len(a), len(b))):
        if i >= len(a):
            return b[i] == "#"  # 'x' vs 'x/#': the topic 'x' matches both
        if i >= len(b):
            return a[i] == "#"
        x, y = a[i], b[i]
        if x == "#" or y == "#":
            return True
        if x != y and x != "+" and y != "+":
            return False
    return True


def is_valid_filter(topic_filter: str) -> bool:
    """MQTT-4.7.1: ``#`` only as the whole last level, ``+`` only as a whole level."""
    if not topic_filter:
        return False
    parts = filter_levels(topic_filter)
    for i, level in enumerate(parts):
        if "#" in level and (level != "#" or i != len(parts) - 1):
            return False
        if "+" in level and level != "+":
            return False
    return True


# -- rules -------------------------------------------------------------------------


def robot_entries(fleet: Fleet, robot: str) -> list[AclEntry]:
    t = fleet.topics
    entries = [
        AclEntry(t.heartbeat(robot), Access.READWRITE),  # read: another bridge of the robot shows itself there
        AclEntry(t.state(robot, "bridge"), Access.READ),  # a starting bridge's claim (bridge/core/claim.py)
        AclEntry(t.grants(robot), Access.READ),  # its users and roles (protocol/grants.py): admins write them
        AclEntry(t.state_filter(robot), Access.WRITE),
        AclEntry(t.to_user_filter(robot, ANY), Access.WRITE),
        AclEntry(t.from_user_filter(robot, ANY), Access.READ),
    ]
    entries += [AclEntry(t.operators_filter(user, deep=True), Access.READ) for user in sorted(fleet.users_of(robot))]
    return entries + vda5050_entries(fleet, robot, master=False)


def vda5050_entries(fleet: Fleet, robot: str, *, master: bool) -> list[AclEntry]:
    """A VDA 5050 robot's topics (``uagv/v2/<manufacturer>/<serial>/…``, roslink_mqtt/vda5050/wire.py): the
    master control writes ``order`` and ``instantActions`` and reads the rest, the robot the other way round;
    nobody else has them (admins through ``#``)."""
    vda = fleet.robots[robot].vda5050
    if vda is None:
        return []
    to_vehicle, from_vehicle = (Access.WRITE, Access.READ) if master else (Access.READ, Access.WRITE)
    return [AclEntry(wire.topic(vda.manufacturer, vda.serial_number, leaf), to_vehicle)
            for leaf in wire.FROM_MASTER] + [
            AclEntry(wire.topic(vda.manufacturer, vda.serial_number, leaf), from_vehicle)
            for leaf in wire.FROM_VEHICLE]


def user_entries(fleet: Fleet, user: str) -> list[AclEntry]:
    t = fleet.topics
    if fleet.users[user].admin:
        return [AclEntry("#", Access.READWRITE), AclEntry(SYS_TOPICS, Access.READ),
                AclEntry(FLEET_CONTROL_FILTER, Access.READWRITE)]  # fleet apply (broker/admin.py)
    entries = [AclEntry(t.operators_filter(user, deep=True), Access.WRITE)]
    for robot, role in sorted(fleet.roles_of(user).items()):
        entries += [
            AclEntry(t.heartbeat(robot), Access.READ),
            AclEntry(t.state_filter(robot), Access.READ),
            AclEntry(t.to_user_filter(robot, user), Access.READ),
        ]
        if role is Role.OPERATOR:
            entries.append(AclEntry(t.from_user_filter(robot, user), Access.WRITE))
        else:
            entries += [AclEntry(t.call(robot, user, svc.name), Access.WRITE)
                        for svc in fleet.robots[robot].services if svc.read_only]
            for action in fleet.robots[robot].actions:
                if action.viewers:
                    entries += [AclEntry(t.goal(robot, user, action.name), Access.WRITE),
                                AclEntry(t.cancel(robot, user, action.name), Access.WRITE)]
            # viewers read every exposed node's parameters (the bridge refuses a set unless viewers_may_set)
            entries += [AclEntry(t.param(robot, user, rule.name), Access.WRITE)
                        for rule in fleet.robots[robot].parameters]
            # snapshots, where the robot file opens them to viewers (snapshot.who: viewers)
            snapshot = fleet.robots[robot].snapshot
            if snapshot is not None and snapshot.who == "viewers":
                entries.append(AclEntry(t.verb_filter(robot, user, Verb.SNAPSHOT), Access.WRITE))
            # video: every granted user may watch (the frames are state, which they read anyway)
            if fleet.robots[robot].video:
                entries.append(AclEntry(t.verb_filter(robot, user, Verb.WATCH), Access.WRITE))
            # any granted user may stop the robot (unless robots.yaml says `estop: operators`)
            if fleet.robots[robot].estop == "viewers":
                entries += [AclEntry(t.from_user(robot, user, leaf), Access.WRITE)
                            for leaf in fleet.robots[robot].estop_inputs]
        vda = fleet.robots[robot].vda5050
        if vda is not None and vda.master == user:
            entries += vda5050_entries(fleet, robot, master=True)
    return entries


class FleetAcl:
    """The access rules of one fleet, per login. Immutable: a reload builds a new one."""

    def __init__(self, fleet: Fleet) -> None:
        self.fleet = fleet
        table: dict[str, tuple[AclEntry, ...]] = {}
        for robot in fleet.robots:
            table[robot] = tuple(robot_entries(fleet, robot))
        for user in fleet.users:
            table[user] = tuple(user_entries(fleet, user))
        self._table = table
        self._read = {login: tuple(e.levels for e in entries if e.access & Access.READ)
                      for login, entries in table.items()}
        self._write = {login: tuple(e.levels for e in entries if e.access & Access.WRITE)
                       for login, entries in table.items()}

    @property
    def logins(self) -> list[str]:
        """Robots first, then users, each in fleet-file order."""
        return list(self._table)

    def entries(self, login: str | None) -> tuple[AclEntry, ...]:
        return self._table.get(login or "", ())

    def allows(self, login: str | None, topic: str, action: str) -> bool:
        """The decision for ``login`` doing ``action`` on ``topic`` (a filter for subscribe)."""
        if not login or not topic:
            return False
        if action == Action.SUBSCRIBE:
            if not is_valid_filter(topic):
                return False
            wanted = filter_levels(topic)
            return any(filters_overlap(wanted, pattern) for pattern in self._read.get(login, ()))
        if "+" in topic or "#" in topic:
            return False  # a concrete topic never contains wildcards
        patterns = self._write if action == Action.PUBLISH else self._read if action == Action.RECEIVE else None
        if patterns is None:
            return False
        concrete = filter_levels(topic)
        return any(topic_matches(pattern, concrete) for pattern in patterns.get(login, ()))


class DecisionCache:
    """Verdicts of one session, so the hot path is a dict lookup.

    The cache is tied to the :class:`FleetAcl` and login it was filled from. A reload
    builds a new FleetAcl, so every session's cache goes stale at once (callers compare
    with :meth:`valid_for`), and a persistent session resumed under another login
    cannot reuse verdicts. ``limit`` (entries) and ``limit_bytes`` bound memory against clients
    that publish to ever-new topics: 1,500 distinct 60 kB topics once held 70 MB in a cache
    bounded only by entries.
    """

    __slots__ = ("acl", "login", "limit", "limit_bytes", "_bytes", "_verdicts")

    ENTRY_OVERHEAD = 200  # bytes a dict entry, its tuple key and the key's string header take besides the text

    def __init__(self, acl: FleetAcl, login: str | None, limit: int = 4096, limit_bytes: int = 256 * 1024) -> None:
        self.acl, self.login, self.limit, self.limit_bytes = acl, login, limit, limit_bytes
        self._bytes = 0
        self._verdicts: dict[tuple[str, str], bool] = {}

    def valid_for(self, acl: FleetAcl, login: str | None) -> bool:
        return self.acl is acl and self.login == login

    def lookup(self, topic: str, action: str) -> bool | None:
        """The cached verdict, or None when it must be computed."""
        return self._verdicts.get((topic, action))

    def decide(self, topic: str, action: str) -> bool:
        verdict = self.acl.allows(self.login, topic, action)
        cost = len(topic) + self.ENTRY_OVERHEAD
        if len(self._verdicts) >= self.limit or self._bytes + cost > self.limit_bytes:
            self._verdicts.clear()
            self._bytes = 0
        if cost <= self.limit_bytes:  # a topic larger than the whole cache is decided, not kept
            self._verdicts[(topic, action)] = verdict  # amqtt's Action hashes like its str value
            self._bytes += cost
        return verdict

    @property
    def size_bytes(self) -> int:
        """Approximate memory the cached verdicts hold (topic text plus per-entry overhead)."""
        return self._bytes

    def __len__(self) -> int:
        return len(self._verdicts)


@dataclass(frozen=True, slots=True)
class FleetChange:
    """What a reload changed, for the log and for dropping sessions of removed logins."""

    removed_logins: tuple[str, ...]
    added_logins: tuple[str, ...]
    changed_passwords: tuple[str, ...]
    reduced_grants: tuple[str, ...] = ()  # users who lost a robot or an operator role: their connections close


class LiveFleet:
    """The fleet the broker enforces right now; SIGHUP swaps it whole.

    Plugins read :attr:`acl` and :attr:`fleet` on every check. Both are replaced whole (never
    edited in place) with no ``await`` in between, so a check on the broker's event loop sees
    either the old rules or the new ones, never a mix that was never configured.
    """

    def __init__(self, fleet: Fleet) -> None:
        self.fleet = fleet
        self.acl = FleetAcl(fleet)

    def password_hash(self, login: str) -> str | None:
        return self.fleet.password_hash(login)

    def replace(self, fleet: Fleet) -> FleetChange:
        old = self.fleet
        before, after = set(old.robots) | set(old.users), set(fleet.robots) | set(fleet.users)
        # a login whose password changed is disconnected, unless the hash it had is still accepted (a robot's
        # password being rotated: the new one and the previous one both work until its bridge has moved)
        changed = tuple(sorted(login for login in before & after
                               if old.password_hash(login) != fleet.password_hash(login)
                               and old.password_hash(login) not in fleet.accepted_hashes(login)))
        self.acl = FleetAcl(fleet)
        self.fleet = fleet
        return FleetChange(tuple(sorted(before - after)), tuple(sorted(after - before)), changed,
                           reduced_grants(old, fleet))


def reduced_grants(old: Fleet, new: Fleet) -> tuple[str, ...]:
    """Users of both fleets who lost a robot, or an operator role on one (their connections are closed: what they
    subscribed to and may still hold of the robot ends with the grant)."""
    reduced = []
    for user in sorted(set(old.users) & set(new.users)):
        before, after = old.roles_of(user), new.roles_of(user)
        if any(robot not in after or role is Role.OPERATOR and after[robot] is not Role.OPERATOR
               for robot, role in before.items()):
            reduced.append(user)
    return tuple(reduced)



# Requests a user may leave retained under from/<user>/: offers that stay true while the user is there.
# Everything else under from/ is a command or a call, executed when it arrives; a retained one would be
# executed again by every bridge that subscribes later, so the broker refuses it.
RETAINABLE_VERBS = frozenset(v for v in Verb if v.sent_by_user and v.retained_by_sender)


CONTROL_STATE_NAMES = frozenset({"ack"})  # state a slow client must get every message of


class TopicPolicy:
    """Per-topic and per-login rules beyond read/write: payload caps, retain refusals, retained quotas.

    Read on every PUBLISH, so it looks at the live fleet each time (a reload applies at once)
    and keeps no per-topic state. ``limits`` is a :class:`~roslink_mqtt.broker.limits.BrokerLimits`.
    """

    def __init__(self, live: LiveFleet, limits: BrokerLimits) -> None:
        self.live, self.limits = live, limits

    def payload_limit(self, topic: str) -> int:
        """Largest payload accepted on ``topic`` (0 = only the broker's max_payload applies)."""
        # asked on every PUBLISH: a prefix test, no parse (a presence heartbeat is ~100 bytes)
        if topic.startswith(self.live.fleet.topics.operators_prefix()):
            return self.limits.max_presence_bytes
        return 0

    def conflatable(self, topic: str) -> bool:
        """Whether a slow client may get only the newest message of ``topic``: robots' state, not acknowledgements
        (asked only for clients that are backed up)."""
        parsed = self.live.fleet.topics.parse(topic)
        return parsed is not None and parsed.kind is Kind.STATE and parsed.name not in CONTROL_STATE_NAMES

    def retain_refusal(self, topic: str) -> str | None:
        """Why a retained PUBLISH on ``topic`` is refused, or None."""
        parsed = self.live.fleet.topics.parse(topic)
        if parsed is None or parsed.kind is not Kind.FROM or parsed.verb in RETAINABLE_VERBS:
            return None
        what = parsed.verb.value if parsed.verb is not None else parsed.leaf
        return (f"retained '{what}' messages are refused: a command or call is executed when it arrives, "
                "and a retained copy would run again whenever a bridge reconnects")

    def paced(self, login: str | None) -> bool:
        """Whether ``login``'s PUBLISH rate is bounded (``user_publish_rate``): users are, robots are not.

        A robot's bridge streams whatever its rules say (and is the product); a user's program sends commands
        at 10-20 Hz and presence at 1 Hz, so a bound far above that costs honest users nothing.
        """
        return login is not None and login not in self.live.fleet.robots

    def retained_limit(self, login: str | None) -> int | None:
        """Retained payload bytes ``login`` may keep (None = only the broker-wide total applies)."""
        fleet = self.live.fleet
        if login is None:
            return None  # the broker's own ($SYS)
        if login in fleet.robots:
            return self.limits.retained_bytes_robot
        user = fleet.users.get(login)
        if user is not None and user.admin:
            return None
        return self.limits.retained_bytes_user
