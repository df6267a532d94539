"""Control bodies: every JSON body on the robot's topics that is not a ROSLink message, one frozen type each.

Services and on-demand publishers use six: :class:`CallRequest` / :class:`CallReply`
(a user calls a robot's ROS service), :class:`ServiceOffer`, :class:`ProviderRequest`
and :class:`ProviderResponse` (a user provides a ROS service), and
:class:`Advertisement` (a user's publisher keeps an on-demand ROS publisher alive).
The bridge and the SDK both parse and write them only through these types, so the
two ends of the wire cannot disagree and every refusal reason is worded in one
place. Bodies the bridge reads are strict (unknown fields refused, except in a
provider response); bodies a client reads are lenient (unknown fields ignored) so
the bridge may grow them.

Three more travel on a user's own ``to/<user>/…`` topics:

* :class:`ErrorReport` on ``to/<user>/error``: one refused input. Every program of a
  user reads that topic (MQTT does not tell the bridge which connection published),
  so a request may name its sender with ``client_id`` and the report repeats it:
  each program shows only its own reports, and reports without an id (the sender
  did not say) to everyone, since they could be anyone's.
* :class:`Notice` on ``to/<user>/notice``: something the user sent was carried out, but not
  as sent (a twist clamped to the robot's limits). Not an error: a client that waits for
  refusals does not raise for it. Addressed to the sender like an error report.
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

docs/protocol.md renders the reference of these bodies (fields, topic, QoS, retain flag, id and version
rules) from :data:`CONTROL_BODIES`; tests/unit/test_docs.py fails when it drifts.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..ros_names import is_interface
from ..topics import TopicTree
from .body import (
    SENDER,
    AnyJson,
    BodyField,
    Boolean,
    Choice,
    Id,
    Integer,
    Nullable,
    Number,
    Obj,
    Strings,
    Text,
    read,
    refuse,
    write,
)
from .codec import GENERIC_SENDER_KEY, MAX_CLIENT_ID, loads
from .errors import ProtocolError
from .validate import describe

_DOC = TopicTree()  # topics as docs/protocol.md shows them: placeholders in angle brackets
_R, _U = "<robot>", "<user>"

ROLES = ("operator", "viewer")
MAX_CALL_ID = 128  # characters of a string call id
MAX_SENDER_PARSE = 64 * 1024  # bytes: a larger refused input is not parsed again for its sender (see sender_id)


def check_client_id(value: Any, where: str = "client_id") -> str:
    """A sender id as requests carry it: a string of 1..128 characters; ProtocolError otherwise."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_CLIENT_ID:
        raise ProtocolError(f"{where}: expected a string of 1..{MAX_CLIENT_ID} characters, got {describe(value)}")
    return value


def sender_id(payload: bytes | bytearray | memoryview | str | None) -> str | None:
    """The client id a request names (envelope, control body or generic JSON), None if it names none.

    Used on the refusal path only, for inputs refused before their body was
    parsed (a verb this bridge does not serve, a role that may not send it, a
    retained command): the one parse, to find out whom to address the report to.
    Inputs refused while parsing name their sender through ``ProtocolError``
    (``err.client_id``) or the parser's own result, so nothing is parsed twice.
    A malformed input simply has no sender.
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
class ErrorReport:
    """One refused input, on ``to/<user>/error``."""

    topic: str
    error: str
    message_id: int | None = None
    sequence_number: int | None = None
    client_id: str | None = None
    id: str | int | None = None  # the refused request's own id (a goal, a cancel), when it had one

    FIELDS = (
        BodyField("topic", Text(), True, "the topic the refused input was published to"),
        BodyField("error", Text(), True, "what was wrong and where (field path)"),
        BodyField("message_id", Integer(), False, "copied from the refused ROSLink message, when it had one",
                  None),
        BodyField("sequence_number", Integer(), False, "copied from the refused ROSLink message, when it had one",
                  None),
        BodyField("client_id", SENDER, False, "the sender's id, when the request named one (envelope "
                                              "`client_id`, body `client_id` or `$client_id`); a report "
                                              "without it may concern any program of the user", None),
        BodyField("id", Id(MAX_CALL_ID), False, "the refused request's `id` (a goal, a cancel), when it had "
                                                "one: which of your requests this is about", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ErrorReport:
        return cls.from_body(loads(data))

    @classmethod
    def from_body(cls, body: Any) -> ErrorReport:
        """The same check on a body already decoded, or on the payload itself."""
        return cls(**read(cls.FIELDS, body, shape="error report: expected a JSON object", strict=False,
                          what="error report"))


@dataclass(frozen=True, slots=True)
class Notice:
    """Something the user sent was carried out, but changed on the way (``to/<user>/notice``); not a refusal."""

    topic: str
    notice: str
    message_id: int | None = None
    sequence_number: int | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("topic", Text(), True, "the topic the input was published to"),
        BodyField("notice", Text(), True, "what the robot changed, and why (a twist clamped to its limits: sent "
                                          "for the first clamped twist of a stream only)"),
        BodyField("message_id", Integer(), False, "copied from the ROSLink message, when it had one", None),
        BodyField("sequence_number", Integer(), False, "copied from the ROSLink message, when it had one", None),
        BodyField("client_id", SENDER, False, "the sender's id, when the input named one (as in error reports)",
                  None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> Notice:
        return cls(**read(cls.FIELDS, data, shape="notice: expected a JSON object", strict=False,
                          what="notice"))


def error_reply(topic: str, reason: str, *, message_id: int | None = None,
                sequence_number: int | None = None, client_id: str | None = None,
                request_id: str | int | None = None) -> bytes:
    """The :class:`ErrorReport` body for ``to/<user>/error``: the bridge's one way of wording a refusal report.

    ``client_id`` repeats the sender's id from the refused request, so that only
    the program that sent it shows the report.
    """
    return ErrorReport(topic, reason, message_id, sequence_number, client_id, request_id).to_json()


@dataclass(frozen=True, slots=True)
class AccessReport:
    """What one user may do on one robot, retained on ``to/<user>/access`` by the robot's bridge."""

    role: str  # "operator" or "viewer"
    services: tuple[str, ...] = ()  # services this user may call; the broker drops calls to any other
    actions: tuple[str, ...] = ()  # actions this user may send goals to (and cancel them)
    estop: bool = False  # this user may send emergency stops (operators; viewers unless `estop: operators`)
    snapshot: bool = False  # this user may ask for snapshots (the robot keeps them, and `snapshot.who` allows)

    FIELDS = (
        BodyField("role", Choice(ROLES), True, "`operator` (commands, calls, provides, advertises, goals) or "
                                               "`viewer` (reads state; calls only the services and sends goals "
                                               "only to the actions listed)"),
        BodyField("services", Strings(), True, "the robot's services this user may call: all of them for an "
                                               "operator, the `read_only` ones for a viewer", ()),
        BodyField("actions", Strings(), False, "the robot's actions this user may send goals to: all of them for "
                                               "an operator, those with `viewers: true` for a viewer (missing "
                                               "from older bridges: none listed)", ()),
        BodyField("estop", Boolean(), False, "this user may press the robot's emergency stop: operators, and "
                                             "viewers unless robots.yaml says `estop: operators` (missing from "
                                             "older bridges: operators only)"),
        BodyField("snapshot", Boolean(), False, "this user may ask for snapshots: the robot keeps them (its robot "
                                                "file's `snapshot:`) and `snapshot.who` names the user's role "
                                                "(missing from older bridges: false)", False),
    )
    QOS = 1
    RETAINED = True

    @property
    def operator(self) -> bool:
        return self.role == "operator"

    def may_call(self, service: str) -> bool:
        """An operator may call anything (the bridge answers unknown names); a viewer only the listed ones."""
        return self.operator or service in self.services

    def may_send_goal(self, action: str) -> bool:
        """As :meth:`may_call`, for actions."""
        return self.operator or action in self.actions

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> AccessReport:
        values = read(cls.FIELDS, data, shape="access report: expected a JSON object", strict=False,
                      what="access report")
        values.setdefault("estop", values["role"] == "operator")  # older bridges: operators only
        return cls(**values)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


CallId = str | int | None  # a caller's id for its call: echoed, never interpreted


@dataclass(frozen=True, slots=True)
class CallRequest:
    """A call of a robot's ROS service, on ``from/<user>/call/<service>`` (read by the bridge)."""

    id: CallId = None
    args: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Nullable(Id(MAX_CALL_ID, min_len=0)), False,
                  "chosen by the caller and echoed in the reply, to match replies to calls (they may arrive in any "
                  "order); the bridge does not check uniqueness. Missing: the reply has `\"id\": null`", None,
                  names="request", docs_type=f"string (≤ {MAX_CALL_ID} characters) or integer", written="null"),
        BodyField("args", Obj(), False, "the ROS request as JSON (see Generic ROS messages); missing: `{}`", {}),
        BodyField("client_id", SENDER, False,
                  "the caller's id, repeated in the reply (every program of the user reads the reply topic)", None,
                  names="sender"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # an absent id is written as null (the reply echoes it), not left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> CallRequest:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"id": …, "args": {…}}'))


@dataclass(frozen=True, slots=True)
class CallReply:
    """The bridge's answer to a :class:`CallRequest`, on ``to/<user>/reply/<service>`` (read by the caller).

    Exactly one of ``values`` (``result`` true) and ``error`` (``result`` false) is meaningful.
    Parsing is as lenient as the SDK has always been with replies: fields it does not know are ignored
    (the bridge may add some), ``values`` that is not an object reads as ``{}``, any ``result`` other
    than ``true`` is a failure.
    """

    id: CallId
    result: bool
    values: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Nullable(Id(MAX_CALL_ID, min_len=0)), True, "the call's `id`, unchanged (null when the "
                                                                    "call was not a JSON object or its id was "
                                                                    "invalid)", None,
                  docs_type="string, integer or null"),
        BodyField("result", Boolean(), True, "true: the service answered; false: see `error`", False),
        BodyField("values", Obj(), False, "with `result` true: the ROS response as JSON", {}, written="null",
                  written_if=("result", True)),
        BodyField("error", Text(), False, "with `result` false: why (unknown service, refusal, bad arguments, "
                                          "service not available, timeout, service failed)", None, written="null",
                  written_if=("result", False)),
        BodyField("client_id", Text(), False, "the call's `client_id`, when it had one", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # `values` or `error` by `result` (the shape every answer shares)
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> CallReply:
        values = read(cls.FIELDS, data, shape='reply: expected a JSON object {"id": …, "result": …}', strict=False,
                      what="reply")
        if values["result"]:
            values["error"] = None
        else:
            values["values"], values["error"] = None, values["error"] or None
        return cls(**values)


DEFAULT_PROVIDER_TIMEOUT = 5.0  # s, when an offer names none
MAX_PROVIDER_TIMEOUT = 3600.0  # s


@dataclass(frozen=True, slots=True)
class ServiceOffer:
    """A retained offer to provide a ROS service, on ``from/<user>/provide/<service>`` (read by the bridge).

    An empty retained message withdraws it; that is not a body, so the receiver handles it before parsing.
    """

    type: str
    timeout: float = DEFAULT_PROVIDER_TIMEOUT
    client_id: str | None = None

    FIELDS = (
        BodyField("type", Text(1, wording="string `pkg/srv/Type`"), True,
                  "the ROS service type; the bridge must know it"),
        BodyField("timeout", Number(0, MAX_PROVIDER_TIMEOUT, low_open=True), False,
                  f"seconds a ROS call waits for the provider's response (default {DEFAULT_PROVIDER_TIMEOUT:g})",
                  DEFAULT_PROVIDER_TIMEOUT),
        BodyField("client_id", Nullable(Text()), False, "the provider's presence client id: the ROS service "
                                                        "exists while that client is live (without it: while any "
                                                        "client of the user is)", None, names="sender",
                  docs_type="string"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ServiceOffer:
        values = read(cls.FIELDS, data, shape='expected {"type": "pkg/srv/Type"} (optional "timeout", "client_id")')
        if not is_interface(values["type"], "srv"):
            raise refuse(f"'{values['type']}' is not a service type (pkg/srv/Type)", values, cls.FIELDS)
        return cls(**values)


@dataclass(frozen=True, slots=True)
class ProviderRequest:
    """A ROS call forwarded to the provider, on ``to/<provider>/request/<service>`` (read by the provider).

    Fields the provider does not know are ignored (the bridge may add some).
    """

    id: Any  # the bridge's, "<robot>-<n>"; echoed unchanged in the response
    args: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (
        BodyField("id", AnyJson(), True, "chosen by the bridge, `<robot>-<n>`, unique while the bridge runs; "
                                         "the response must carry it unchanged", docs_type="string"),
        BodyField("args", Obj(), True, "the ROS request as JSON", {}),
        BodyField("client_id", Text(), False, "the offer's `client_id`: only that client answers (the user's "
                                              "other clients read the same topic and ignore it)", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ProviderRequest:
        return cls(**read(cls.FIELDS, data, shape='expected {"id": …, "args": {…}}', strict=False,
                          what="provider request"))


DEFAULT_PROVIDER_FAILURE = "provider reported failure"


@dataclass(frozen=True, slots=True)
class ProviderResponse:
    """The provider's answer, on ``from/<provider>/response/<service>`` (read by the bridge).

    Only ``id`` is required of the shape: the bridge matches it to a waiting ROS call (an id that matches
    none, of any JSON type, is reported as such), and the ROS response converter, not this parser,
    refuses ``values`` that are not the response type's fields, so the waiting ROS caller gets that reason.
    """

    id: Any
    result: bool = True
    values: Any = None  # the ROS response as JSON; checked by the converter for the waiting call's type
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", AnyJson(), True, "the request's `id`, unchanged", docs_type="string"),
        BodyField("result", Boolean(), False, "false: the call fails with `error`; anything else: success", True,
                  written="null"),
        BodyField("values", AnyJson(), False, "the ROS response as JSON (missing: the type's defaults)", None,
                  docs_type="object", written="null", written_if=("result", True)),
        BodyField("error", Text(), False, f"with `result` false: why (default `{DEFAULT_PROVIDER_FAILURE}`); "
                                          "the ROS caller sees it in `message` where the type has one", None,
                  written="null", written_if=("result", False)),
        BodyField("client_id", Text(), False, "names the provider in an error report about this response", None,
                  names="sender"),
    )
    QOS = 1
    RETAINED = False

    @property
    def failure(self) -> str:
        """Why the call failed (``result`` false)."""
        return self.error if self.error is not None else DEFAULT_PROVIDER_FAILURE

    def to_json(self) -> bytes:  # `values` or `error` by `result` (the shape every answer shares)
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ProviderResponse:
        # lenient: the converter checks `values` for the waiting call's type, and a provider's extra fields are
        # its own business; only a missing id leaves nothing to answer
        return cls(**read(cls.FIELDS, data, shape='expected {"id": …, "result": true, "values": {…}}',
                          strict=False))


@dataclass(frozen=True, slots=True)
class Advertisement:
    """A retained advertisement of a topic the user publishes, on ``from/<user>/advertise/<name>`` (read by the bridge).

    An empty retained message withdraws it (handled before parsing, like an offer's).
    """

    type: str
    client_id: str | None = None

    FIELDS = (
        BodyField("type", Text(wording="string `pkg/msg/Type`"), True, "the ROS message type; must be the rule's"),
        BodyField("client_id", Text(), False, "the advertiser's presence client id: an on-demand ROS publisher "
                                              "exists while that client is live (without it, or empty: while "
                                              "any client of the user is)", None, names="sender"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> Advertisement:
        # a null client_id is refused (Text): it would mean "implicit" silently
        return cls(**read(cls.FIELDS, data, shape='expected {"type": "pkg/msg/Type", "client_id": "<presence '
                                                  'client id>"}'))


# (title, topic, type): the rendered reference (docs/protocol.md) lists them in this order. Every type says
# with which MQTT QoS and retain flag its topic is published (QOS, RETAINED); the SDK's senders publish with
# those constants (the bridge's error reports too); the bridge retains only access reports (bridge/ros/node.py).
CONTROL_BODIES: tuple[tuple[str, str, type], ...] = (
    ("call request", f"`{_DOC.call(_R, _U, '<service>')}`", CallRequest),
    ("call reply", f"`{_DOC.reply(_R, _U, '<service>')}`", CallReply),
    ("service offer", f"`{_DOC.provide(_R, _U, '<service>')}` (an empty retained message withdraws)", ServiceOffer),
    ("provider request", f"`{_DOC.request(_R, _U, '<service>')}`", ProviderRequest),
    ("provider response", f"`{_DOC.response(_R, _U, '<service>')}`", ProviderResponse),
    ("advertisement", f"`{_DOC.advertise(_R, _U, '<name>')}` (an empty retained message withdraws)", Advertisement),
    ("error report", f"`{_DOC.error(_R, _U)}`", ErrorReport),
    ("notice", f"`{_DOC.notice(_R, _U)}`", Notice),
    ("access report", f"`{_DOC.access(_R, _U)}`", AccessReport),
)
