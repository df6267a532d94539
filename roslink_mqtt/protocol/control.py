"""Control bodies: what the bridge tells one user, and how a request names the program that sent it.

Two bodies travel on a user's own ``to/<user>/…`` topics:

* :class:`ErrorReport` on ``to/<user>/error``: one refused input. Every program of a
  user reads that topic (MQTT does not tell the bridge which connection published),
  so a request may name its sender with ``client_id`` and the report repeats it:
  each program shows only its own reports, and reports without an id (the sender
  did not say) to everyone, since they could be anyone's.
* :class:`AccessReport`, retained on ``to/<user>/access``: what this user may do on
  the robot. A broker drops a denied PUBLISH silently (MQTT 3.1.1 has no negative
  PUBACK), so without it a viewer's command or call just vanishes. The bridge reads
  the same fleet file as the broker's ACL and publishes this snapshot for every
  granted user; a client refuses at the call site what the broker would drop.

Where the sender's id goes in a request (:func:`sender_id` reads it back):
the envelope's ``client_id`` header, the ``client_id`` of service calls, offers,
advertisements and responses, and ``$client_id`` in generic ROS JSON bodies — a key
that can never be a ROS field name (ROS field names start with a letter), so it
cannot collide with the message. The bridge strips it before conversion.

docs/protocol.md renders the field tables of these bodies from :data:`CONTROL_BODIES`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import orjson

from .codec import MAX_CLIENT_ID, loads
from .errors import ProtocolError
from .validate import describe

ACCESS = "access"  # the leaf under to/<user>/ of the AccessReport
ERROR = "error"  # the leaf under to/<user>/ of ErrorReports
GENERIC_SENDER_KEY = "$client_id"  # in generic ROS JSON bodies (never a ROS field name)
ROLES = ("operator", "viewer")
MAX_SENDER_PARSE = 64 * 1024  # bytes: a larger refused input is not parsed again for its sender (see sender_id)


def check_client_id(value: Any, where: str = "client_id") -> str:
    """A sender id as requests carry it: a string of 1..128 characters; ProtocolError otherwise."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_CLIENT_ID:
        raise ProtocolError(f"{where}: expected a string of 1..{MAX_CLIENT_ID} characters, got {describe(value)}")
    return value


def sender_id(payload: bytes | bytearray | memoryview | str | None) -> str | None:
    """The client id a request names (envelope, control body or generic JSON), None if it names none.

    Used on the refusal path only: a refused input is parsed once more to find
    out whom to address the report to, and a malformed one simply has no sender.
    Inputs over MAX_SENDER_PARSE bytes are not parsed again (their report names
    nobody): a flood of large refused messages, e.g. from a viewer on a broker
    without ACLs, must not cost the bridge's MQTT thread a second parse each.
    ``$client_id`` wins over ``client_id``: in a generic body the latter may be a
    field of the ROS message itself.
    """
    if not payload or len(payload) > MAX_SENDER_PARSE:
        return None
    try:
        body = loads(payload)
    except ProtocolError:
        return None
    if not isinstance(body, dict):
        return None
    value = body.get(GENERIC_SENDER_KEY, body.get("client_id"))
    return value if isinstance(value, str) and 0 < len(value) <= MAX_CLIENT_ID else None


def pop_generic_sender(body: Any) -> str | None:
    """Remove ``$client_id`` from a generic ROS JSON body (it is not a ROS field) and return it."""
    if isinstance(body, dict) and GENERIC_SENDER_KEY in body:
        value = body.pop(GENERIC_SENDER_KEY)
        return check_client_id(value, GENERIC_SENDER_KEY)
    return None


@dataclass(frozen=True, slots=True)
class BodyField:
    """One field of a control body, for the rendered reference."""

    name: str
    type: str
    required: bool
    doc: str


@dataclass(frozen=True, slots=True)
class ErrorReport:
    """One refused input, on ``to/<user>/error``."""

    topic: str
    error: str
    message_id: int | None = None
    sequence_number: int | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("topic", "string", True, "the topic the refused input was published to"),
        BodyField("error", "string", True, "what was wrong and where (field path)"),
        BodyField("message_id", "integer", False, "copied from the refused ROSLink message, when it had one"),
        BodyField("sequence_number", "integer", False, "copied from the refused ROSLink message, when it had one"),
        BodyField("client_id", "string", False, "the sender's id, when the request named one (envelope "
                                                "`client_id`, body `client_id` or `$client_id`); a report "
                                                "without it may concern any program of the user"),
    )

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"topic": self.topic, "error": self.error}
        if self.message_id is not None:
            body["message_id"] = int(self.message_id)
        if self.sequence_number is not None:
            body["sequence_number"] = self.sequence_number
        if self.client_id is not None:
            body["client_id"] = self.client_id
        return orjson.dumps(body)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ErrorReport:
        body = loads(data)
        if not isinstance(body, dict):
            raise ProtocolError(f"error report: expected a JSON object, got {describe(body)}")
        topic, error = body.get("topic"), body.get("error")
        if not isinstance(topic, str) or not isinstance(error, str):
            raise ProtocolError('error report: expected {"topic": "…", "error": "…"}')
        mid, seq, cid = body.get("message_id"), body.get("sequence_number"), body.get("client_id")
        return cls(topic, error, mid if _is_int(mid) else None, seq if _is_int(seq) else None,
                   cid if isinstance(cid, str) and cid else None)


@dataclass(frozen=True, slots=True)
class AccessReport:
    """What one user may do on one robot, retained on ``to/<user>/access`` by the robot's bridge."""

    role: str  # "operator" or "viewer"
    services: tuple[str, ...] = ()  # services this user may call; the broker drops calls to any other

    FIELDS = (
        BodyField("role", "string", True, "`operator` (commands, calls, provides, advertises) or `viewer` "
                                          "(reads state; calls only the services listed)"),
        BodyField("services", "array of strings", True, "the robot's services this user may call: all of them "
                                                        "for an operator, the `read_only` ones for a viewer"),
    )

    @property
    def operator(self) -> bool:
        return self.role == "operator"

    def may_call(self, service: str) -> bool:
        """An operator may call anything (the bridge answers unknown names); a viewer only the listed ones."""
        return self.operator or service in self.services

    def to_json(self) -> bytes:
        return orjson.dumps({"role": self.role, "services": list(self.services)})

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> AccessReport:
        body = loads(data)
        if not isinstance(body, dict):
            raise ProtocolError(f"access report: expected a JSON object, got {describe(body)}")
        role, services = body.get("role"), body.get("services", [])
        if role not in ROLES:
            raise ProtocolError(f"access report: role: expected one of {', '.join(ROLES)}, got {describe(role)}")
        if not isinstance(services, list) or not all(isinstance(s, str) for s in services):
            raise ProtocolError("access report: services: expected an array of strings")
        return cls(role, tuple(services))


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


CONTROL_BODIES: tuple[tuple[str, str, type], ...] = (
    ("error report", f"`roslink/<robot>/to/<user>/{ERROR}`", ErrorReport),
    ("access report", f"`roslink/<robot>/to/<user>/{ACCESS}` (retained)", AccessReport),
)
