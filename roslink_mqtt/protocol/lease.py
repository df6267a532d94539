"""Control of a robot (docs/protocol.md, "Control"): who drives it, and how a user claims, releases or takes over.

* ``from/<user>/control/claim`` | ``release`` | ``take_over`` (body: empty, or ``{"client_id": …}``): the request.
  A refusal comes on ``to/<user>/error`` like every other; success shows on ``state/control``.
* ``state/control`` (retained): :class:`ControlState`, republished at every change and on connecting. A holder
  displaced by a take-over is also told on its error topic ("taken over by admin").
* The heartbeat's ``owner_id`` is the holder too, so a client that only reads heartbeats sees who drives.

A client reads :class:`ControlState` leniently (unknown fields ignored), so the bridge may grow it.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import datetime
from enum import Enum
from typing import Any

import orjson

from ..topics import TopicTree, Verb, join_leaf
from .control import BodyField, _object
from .errors import ProtocolError

CONTROL = "control"  # the state name (roslink/<robot>/state/control) and the verb (from/<user>/control/<op>)
ESTOP_VIEWERS, ESTOP_OPERATORS = "viewers", "operators"
ESTOP_MODES = (ESTOP_VIEWERS, ESTOP_OPERATORS)
_DOC = TopicTree()


class ControlOp(Enum):
    """What ``from/<user>/control/<op>`` asks; the value is the topic level."""

    CLAIM = "claim"  # take control if nobody holds it (a supervisor: also from a non-supervisor)
    RELEASE = "release"  # give it back
    TAKE_OVER = "take_over"  # take it from its holder (the robot stops; the holder is told)

    @classmethod
    def parse(cls, name: str) -> ControlOp:
        try:
            return cls(name)
        except ValueError:
            raise ProtocolError(f"control/{name}: unknown request; one of "
                                f"{', '.join(join_leaf(Verb.CONTROL, o.value) for o in cls)}") from None


@dataclass(frozen=True, slots=True)
class ControlState:
    """Retained on ``state/control`` by the bridge: who holds control of the robot, since when."""

    holder: str | None
    since: float | None  # s since the epoch
    supervisor: bool = False  # the holder is one of the robot's supervisors
    mode: str = "auto"  # robots.yaml `control`: auto (a free lease is claimed by a command) or explicit
    supervisors: tuple[str, ...] = ()
    estop: str = ESTOP_VIEWERS  # who may send emergency stops besides operators: "viewers" (every granted user)
    event: str = ""  # the last change, for people: "taken over by admin from alice"

    FIELDS = (
        BodyField("holder", "string or null", True, "the user who holds control (drives the robot); null: nobody"),
        BodyField("since", "number or null", True, "when the holder's lease began, s since the Unix epoch"),
        BodyField("supervisor", "boolean", True, "the holder is a supervisor: only another supervisor can take "
                                                 "over"),
        BodyField("mode", '"auto" or "explicit"', True, "robots.yaml `control`: `auto` lets an operator's first "
                                                        "command claim a free lease; `explicit` needs "
                                                        "`control/claim` first"),
        BodyField("supervisors", "array of strings", True, "robots.yaml `supervisors`: they take over by claiming"),
        BodyField("estop", '"viewers" or "operators"', True, "who may press the emergency stop: every granted user "
                                                             "(`viewers`, the default) or operators only"),
        BodyField("event", "string", True, "the last change, for people (`claimed by alice`, `taken over by admin "
                                           "from alice`, `alice's lease ended: last-will`)"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return orjson.dumps({"holder": self.holder, "since": self.since, "supervisor": self.supervisor,
                             "mode": self.mode, "supervisors": list(self.supervisors), "estop": self.estop,
                             "event": self.event})

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ControlState:
        body = _object(data, 'expected a JSON object {"holder": "alice", "since": 1764158585.2, …}')
        try:
            holder, since = body.get("holder"), body.get("since")
            return cls(None if holder is None else str(holder), None if since is None else float(since),
                       bool(body.get("supervisor", False)), str(body.get("mode", "auto")),
                       tuple(str(s) for s in body.get("supervisors", ())), str(body.get("estop", ESTOP_VIEWERS)),
                       str(body.get("event", "")))
        except (TypeError, ValueError) as err:
            raise ProtocolError(f"missing or malformed field ({err})") from None

    def summary(self) -> str:
        """``driven by alice since 12:03:05`` or ``free``, as ``robots``, ``info`` and ``monitor`` print it."""
        if self.holder is None:
            return "free"
        when = datetime.fromtimestamp(self.since).strftime("%H:%M:%S") if self.since else "?"
        return f"driven by {self.holder}{' (supervisor)' if self.supervisor else ''} since {when}"


def control_request(client_id: str | None = None) -> bytes:
    """The body of a ``control/<op>`` request (the client id lets the refusal find the program that asked)."""
    return orjson.dumps({"client_id": client_id} if client_id else {})


def read_request(payload: bytes) -> dict[str, Any]:
    """A ``control/<op>`` body: empty, or a JSON object (ProtocolError otherwise)."""
    if not payload.strip():
        return {}
    return _object(payload, 'expected an empty message or a JSON object {"client_id": "…"}')


LEASE_BODIES: tuple[tuple[str, str, type], ...] = (
    ("control state", f"`{_DOC.state('<robot>', CONTROL)}`", ControlState),
)
