"""What every capability is: one operation a user sends the robot, from body to gate to port. ROS-free.

The command endpoint (:mod:`roslink_mqtt.bridge.core.endpoint`) reads the topic, finds the capability of its verb
and runs the same three steps for every one of them:

1. :meth:`Capability.parse` reads the body (its declaration in :mod:`roslink_mqtt.protocol`); a malformed body is
   refused with the parser's reason;
2. :meth:`Capability.gate` decides, without side effects beyond claiming a free control lease, whether this user
   may do this now: role, presence, the control lease, the robot's own rules;
3. :meth:`Capability.run` carries it out through the capability's port: a narrow typed interface that the ROS
   adapter implements (``ServicePort`` for services...) or, for the lease, the endpoint's motion state.

A capability whose operation may move the robot sets ``MOVES_ROBOT = True``: its gate and run then happen under the
endpoint's motion lock, so an emergency stop comes either before (the gate refuses) or after (the stop cancels
what was handed over), never between.

A refusal goes where the operation's user looks for it: :meth:`Capability.refuse` decides (a call's reply topic,
or ``to/<user>/error``). docs/architecture.md shows how to add an operation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, Protocol, TypeVar

if TYPE_CHECKING:
    from ....config import Robot, Role
    from ....topics import Verb

B = TypeVar("B")


@dataclass(frozen=True, slots=True)
class Request(Generic[B]):
    """One input, read: who sent it, on which topic, the level after the verb (``name``) and its parsed body.

    ``body`` is None only on the refusal path of a body that did not parse.
    """

    user: str
    name: str
    topic: str
    payload: bytes
    body: B | None
    role: Role | None


@dataclass(frozen=True, slots=True)
class Refusal:
    """Why an input is refused. ``report``: on ``to/<user>/error`` (the way every verb can be refused, e.g. by the
    control lease) rather than on the operation's own answer topic."""

    reason: str
    report: bool = False
    # what a body that did not parse said about itself (ProtocolError.naming), so nothing parses it again
    request_id: str | int | None = None
    client_id: str | None = None


@dataclass(frozen=True, slots=True)
class Withdrawal:
    """An empty retained offer or advertisement: the user withdraws what they offered."""


class Gates(Protocol):
    """What a gate may ask about the robot's state (the command endpoint answers)."""

    @property
    def robot(self) -> Robot: ...

    def role_of(self, user: str) -> Role | None:
        """The user's role on this robot (None: not granted)."""
        ...

    def is_live(self, user: str) -> bool:
        """Whether the user's presence heartbeat is live."""
        ...

    @property
    def motion_blocked(self) -> str | None:
        """Why motion is refused now (an emergency stop, a disarm); None when it is not."""
        ...

    def lease_gate(self, user: str) -> str | None:
        """None when ``user`` may change the robot now (a free control lease is claimed on the way); else why not."""
        ...


class Report(Protocol):
    """An error report on ``to/<user>/error`` (the endpoint's ``refuse``)."""

    def __call__(self, user: str, topic: str, reason: str, *, payload: bytes | None = None,
                 client_id: str | None = None, request_id: str | int | None = None) -> None: ...


class Capability(Protocol[B]):
    """One operation: its verb, its body, its gate and what carries it out."""

    verb: Verb

    def parse(self, name: str, payload: bytes) -> B:
        """The body of ``payload`` (raises :class:`~roslink_mqtt.protocol.errors.ProtocolError` with the reason)."""
        ...

    def gate(self, request: Request[B], gates: Gates) -> Refusal | None:
        """None when ``request`` may be carried out now; else the refusal."""
        ...

    def run(self, request: Request[B]) -> None:
        """Carry out a parsed request that passed the gate (MQTT thread: never blocks)."""
        ...

    def refuse(self, request: Request[B], refusal: Refusal) -> None:
        """Tell the sender why not."""
        ...
