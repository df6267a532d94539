"""The MQTT topic tree (docs/protocol.md, "Topic tree"): build and parse every topic ROSLink uses.

Builders refuse names that would change a topic's meaning: a robot called
``+`` or a user called ``a/b`` would let one principal's topic match
another's ACL. Parsing returns None for topics outside the tree so callers can
ignore foreign traffic cheaply.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

DEFAULT_PREFIX = "roslink"
OPERATORS = "operators"


class TopicError(ValueError):
    """A name cannot be used in a topic (empty, or contains ``+``, ``#`` or ``/``)."""


def check_name(name: str, what: str = "name") -> str:
    """Validate one topic level (robot, user, client id, service name)."""
    if not isinstance(name, str) or not name:
        raise TopicError(f"{what} must be a non-empty string, got {name!r}")
    for bad in ("+", "#", "/", "\0"):
        if bad in name:
            raise TopicError(f"{what} {name!r} must not contain {bad!r}")
    if name.startswith("$"):
        raise TopicError(f"{what} {name!r} must not start with '$' (reserved for broker topics)")
    return name


def check_path(path: str, what: str = "name") -> str:
    """Validate a multi-level leaf such as ``cmd/twist`` (each level as :func:`check_name`)."""
    if not isinstance(path, str) or not path:
        raise TopicError(f"{what} must be a non-empty string, got {path!r}")
    for level in path.split("/"):
        check_name(level, f"{what} level in {path!r}")
    return path


class Kind(Enum):
    HEARTBEAT = "heartbeat"
    STATE = "state"
    FROM = "from"  # user → robot
    TO = "to"  # robot → user
    OPERATOR = "operator"


@dataclass(frozen=True, slots=True)
class ParsedTopic:
    kind: Kind
    robot: str | None = None
    user: str | None = None
    name: str | None = None  # the leaf: state name, or e.g. cmd/twist, call/reset
    client_id: str | None = None


class TopicTree:
    """Topic builder/parser for one prefix (``roslink`` unless configured)."""

    def __init__(self, prefix: str = DEFAULT_PREFIX) -> None:
        self.prefix = check_path(prefix, "prefix")
        self._levels = len(prefix.split("/"))

    # -- builders ---------------------------------------------------------
    def robot_root(self, robot: str) -> str:
        return f"{self.prefix}/{check_name(robot, 'robot')}"

    def heartbeat(self, robot: str) -> str:
        return f"{self.robot_root(robot)}/heartbeat"

    def state(self, robot: str, name: str) -> str:
        return f"{self.robot_root(robot)}/state/{check_path(name, 'state name')}"

    def from_user(self, robot: str, user: str, name: str) -> str:
        return f"{self.robot_root(robot)}/from/{check_name(user, 'user')}/{check_path(name)}"

    def to_user(self, robot: str, user: str, name: str) -> str:
        return f"{self.robot_root(robot)}/to/{check_name(user, 'user')}/{check_path(name)}"

    def command(self, robot: str, user: str, command: str) -> str:
        return self.from_user(robot, user, f"cmd/{check_name(command, 'command')}")

    def call(self, robot: str, user: str, service: str) -> str:
        return self.from_user(robot, user, f"call/{check_path(service, 'service')}")

    def reply(self, robot: str, user: str, service: str) -> str:
        return self.to_user(robot, user, f"reply/{check_path(service, 'service')}")

    def provide(self, robot: str, user: str, service: str) -> str:
        return self.from_user(robot, user, f"provide/{check_path(service, 'service')}")

    def advertise(self, robot: str, user: str, name: str) -> str:
        """Retained: the user publishes on the generic rule ``name`` (its ROS publisher exists meanwhile)."""
        return self.from_user(robot, user, f"advertise/{check_path(name, 'topic')}")

    def request(self, robot: str, user: str, service: str) -> str:
        return self.to_user(robot, user, f"request/{check_path(service, 'service')}")

    def response(self, robot: str, user: str, service: str) -> str:
        return self.from_user(robot, user, f"response/{check_path(service, 'service')}")

    def error(self, robot: str, user: str) -> str:
        return self.to_user(robot, user, "error")

    def operator(self, user: str, client_id: str) -> str:
        return f"{self.prefix}/{OPERATORS}/{check_name(user, 'user')}/{check_name(client_id, 'client id')}"

    # -- subscription filters ---------------------------------------------
    def all_from_users(self, robot: str) -> str:
        """What a bridge subscribes to: every user's commands for its robot."""
        return f"{self.robot_root(robot)}/from/+/#"

    def operators_of(self, user: str) -> str:
        return f"{self.prefix}/{OPERATORS}/{check_name(user, 'user')}/+"

    def all_state(self, robot: str = "+") -> str:
        root = f"{self.prefix}/{robot}" if robot == "+" else self.robot_root(robot)
        return f"{root}/state/#"

    def all_heartbeats(self) -> str:
        return f"{self.prefix}/+/heartbeat"

    # -- parsing -----------------------------------------------------------
    def parse(self, topic: str) -> ParsedTopic | None:
        """Classify a concrete topic; None if it is not part of the tree."""
        levels = topic.split("/")
        if "/".join(levels[: self._levels]) != self.prefix:
            return None
        rest = levels[self._levels:]
        if not rest or any(not level for level in rest):
            return None
        if rest[0] == OPERATORS:
            if len(rest) != 3:
                return None
            return ParsedTopic(Kind.OPERATOR, user=rest[1], client_id=rest[2])
        robot = rest[0]
        if len(rest) == 2 and rest[1] == "heartbeat":
            return ParsedTopic(Kind.HEARTBEAT, robot=robot)
        if len(rest) >= 3 and rest[1] == "state":
            return ParsedTopic(Kind.STATE, robot=robot, name="/".join(rest[2:]))
        if len(rest) >= 4 and rest[1] in ("from", "to"):
            kind = Kind.FROM if rest[1] == "from" else Kind.TO
            return ParsedTopic(kind, robot=robot, user=rest[2], name="/".join(rest[3:]))
        return None
