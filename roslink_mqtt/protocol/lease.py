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

import orjson

from ..topics import TopicTree, Verb, join_leaf
from .body import SENDER, BodyField, Boolean, Choice, Nullable, Number, Strings, Text, read, write
from .errors import ProtocolError

CONTROL = "control"  # the state name (roslink/<robot>/state/control) and the verb (from/<user>/control/<op>)
ESTOP_VIEWERS, ESTOP_OPERATORS = "viewers", "operators"
ESTOP_MODES = (ESTOP_VIEWERS, ESTOP_OPERATORS)
CONTROL_MODES = ("auto", "explicit")
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
    blocked: str = ""  # why motion is refused until an operator arms: "emergency stop by bob" ('' : it is not)

    FIELDS = (
        BodyField("holder", Nullable(Text(1)), True, "the user who holds control (drives the robot); null: nobody",
                  None, docs_type="string or null"),
        BodyField("since", Nullable(Number()), True, "when the holder's lease began, s since the Unix epoch", None),
        BodyField("supervisor", Boolean(), True, "the holder is a supervisor: only another supervisor can take "
                                                 "over", False),
        BodyField("mode", Choice(CONTROL_MODES), True, "robots.yaml `control`: `auto` lets an operator's first "
                                                       "command claim a free lease; `explicit` needs "
                                                       "`control/claim` first", "auto"),
        BodyField("supervisors", Strings(), True, "robots.yaml `supervisors`: they take over by claiming", ()),
        BodyField("estop", Choice(ESTOP_MODES), True, "who may press the emergency stop: every granted user "
                                                      "(`viewers`, the default) or operators only", ESTOP_VIEWERS),
        BodyField("event", Text(), True, "the last change, for people (`claimed by alice`, `taken over by admin "
                                         "from alice`, `alice's lease ended: last-will`)", ""),
        BodyField("blocked", Text(), False, "why motion is refused until an operator sends `cmd/arm` "
                                            "(`emergency stop by bob`); empty or absent: it is not", ""),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ControlState:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"holder": "alice", "since": 1764158585.2, '
                                                  '…}', strict=False, what="control state"))

    def summary(self) -> str:
        """``driven by alice since 12:03:05`` or ``free`` (and an emergency stop, when motion is blocked), as
        ``robots``, ``info``, ``monitor`` and ``control status`` print it."""
        stopped = f"; EMERGENCY STOP — {self.blocked} (an operator's arm resumes)" if self.blocked else ""
        return self.driver() + stopped

    def driver(self) -> str:
        """``driven by alice since 12:03:05`` or ``free``: who holds control, nothing else."""
        if self.holder is None:
            return "free"
        when = datetime.fromtimestamp(self.since).strftime("%H:%M:%S") if self.since else "?"
        return f"driven by {self.holder}{' (supervisor)' if self.supervisor else ''} since {when}"


def control_request(client_id: str | None = None) -> bytes:
    """The body of a ``control/<op>`` request (the client id lets the refusal find the program that asked)."""
    return orjson.dumps({"client_id": client_id} if client_id else {})


REQUEST_FIELDS = (BodyField("client_id", SENDER, False, "the program that asks (its refusal finds it)", None,
                            names="sender"),)


def read_request(payload: bytes) -> str | None:
    """The sender a ``control/<op>`` body names: empty, or a JSON object (ProtocolError otherwise)."""
    if not payload.strip():
        return None
    got = read(REQUEST_FIELDS, payload, shape='expected an empty message or a JSON object {"client_id": "…"}',
               strict=False)
    sender: str | None = got["client_id"]
    return sender


LEASE_BODIES: tuple[tuple[str, str, type], ...] = (
    ("control state", f"`{_DOC.state('<robot>', CONTROL)}`", ControlState),
)
