"""A robot's grants, from the broker (docs/protocol.md, "Grants"): who may see and command the robot.

The broker decides who may publish what; the robot's bridge needs the same answer to refuse with a reason, to
subscribe to the right users and to stop the robot when its driver loses the right. A robot must not carry the
fleet file for that (every login's password hash, every robot's key), so the fleet's grants for one robot reach
its bridge as one retained message on ``P/<robot>/grants``:

* written only by the fleet's administrators (the broker's ACL: an admin writes ``#``; robots and users cannot);
  the embedded broker publishes it itself at start and on every reload, ``roslink-mqtt fleet apply`` publishes
  it for every broker;
* read only by the robot (and administrators); a user learns their own standing from ``to/<user>/access``.

It is not signed. The broker is already trusted with every command: it is what says a message on
``from/alice/…`` comes from alice. Whoever could forge this message past the broker's ACL could forge
alice's commands too, so a signature would add a key to manage on every robot and protect nothing more.

A bridge reads the body strictly: a malformed message (or one for another robot) keeps the grants it has and
says why in its log.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..topics import FLEET_CONTROL, FLEET_CONTROL_RESPONSE, TopicError, TopicTree, check_name
from .body import BodyField, Number, Text, TextMap, read, write
from .control import ROLES
from .errors import ProtocolError
from .fleet_control import ControlRequest, ControlResponse

_DOC = TopicTree()


@dataclass(frozen=True, slots=True)
class RobotGrants:
    """Retained on ``P/<robot>/grants`` by an administrator (or the embedded broker): the robot's users."""

    robot: str
    users: dict[str, str] = field(default_factory=dict)  # user → "operator" | "viewer" (admins: operator)
    issued: float = 0.0  # s since the epoch: when the fleet file was read (logs tell versions apart)
    by: str = ""  # who published it: an admin's login, or "broker" (the embedded broker)

    def __post_init__(self) -> None:
        object.__setattr__(self, "users", dict(sorted(self.users.items())))  # one fleet file, one message

    FIELDS = (
        BodyField("robot", Text(1), True, "the robot these grants are for (a bridge ignores another robot's)"),
        BodyField("users", TextMap(), True, "user → role (`operator` or `viewer`) for every user who may see "
                                            "the robot; administrators are operators; a user not listed may "
                                            "do nothing"),
        BodyField("issued", Number(), True, "when the fleet file was read, s since the Unix epoch"),
        BodyField("by", Text(), False, "who published it: an administrator's login, or `broker` (the embedded "
                                       "broker, at start and on every reload)", ""),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:  # users sorted by name (one fleet file, one message: __post_init__)
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> RobotGrants:
        got: dict[str, Any] = read(cls.FIELDS, data, shape='expected a JSON object {"robot": "turtle1", "users": '
                                                           '{"alice": "operator"}, "issued": 1764158585.2}',
                                   known_only=False)
        for user, role in got["users"].items():
            try:
                check_name(user, "user")
            except TopicError as err:
                raise ProtocolError(f"users: {err}") from None
            if role not in ROLES:
                raise ProtocolError(f"users.{user}: expected one of {', '.join(ROLES)}, got {role!r}")
        return cls(**got)


GRANTS_BODIES: tuple[tuple[str, str, type], ...] = (
    ("robot grants", f"`{_DOC.grants('<robot>')}`", RobotGrants),
    ("fleet control request", f"`{FLEET_CONTROL}`", ControlRequest),
    ("fleet control response", f"`{FLEET_CONTROL_RESPONSE}`", ControlResponse),
)
