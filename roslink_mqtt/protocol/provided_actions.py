"""Control bodies of ROS actions provided by MQTT clients (docs/protocol.md, "Actions provided by MQTT clients").

The mirror of provided services: a program offers an action with a retained ``provide_action/<action>``; while
its presence is live the robot's bridge runs a ROS action server ``<action>``. Each ROS goal (and each cancel
request) reaches the provider as an ``action_request/<action>``; the provider answers with
``action_update/<action>`` messages: accepted or rejected, feedback, and one final succeeded / aborted /
canceled with the result. Ids are the bridge's (``<robot>-g<n>``) and must be echoed unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..ros_names import is_interface
from ..topics import TopicTree, Verb
from .body import SENDER, AnyJson, BodyField, Choice, Nullable, Number, Obj, Text, read, refuse, write

DEFAULT_ACCEPT_TIMEOUT = 5.0  # s for the provider to accept or reject a goal
DEFAULT_RESULT_TIMEOUT = 600.0  # s from acceptance to the final update
MAX_TIMEOUT = 86400.0
ACCEPTED, REJECTED, FEEDBACK = "accepted", "rejected", "feedback"
SUCCEEDED, ABORTED, CANCELED = "succeeded", "aborted", "canceled"
FINAL = (SUCCEEDED, ABORTED, CANCELED)
UPDATE_STATUSES = (ACCEPTED, REJECTED, FEEDBACK, *FINAL)
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"


@dataclass(frozen=True, slots=True)
class ActionOffer:
    """A retained offer to serve a ROS action, on ``from/<user>/provide_action/<action>`` (empty: withdrawn)."""

    type: str
    accept_timeout: float = DEFAULT_ACCEPT_TIMEOUT
    result_timeout: float = DEFAULT_RESULT_TIMEOUT
    client_id: str | None = None

    FIELDS = (
        BodyField("type", Text(1, wording="string `pkg/action/Type`"), True,
                  "the ROS action type; the bridge must know it"),
        BodyField("accept_timeout", Number(0, MAX_TIMEOUT, low_open=True), False,
                  f"seconds a ROS goal waits for your accepted/rejected (default {DEFAULT_ACCEPT_TIMEOUT:g})",
                  DEFAULT_ACCEPT_TIMEOUT),
        BodyField("result_timeout", Number(0, MAX_TIMEOUT, low_open=True), False,
                  f"seconds from acceptance to your final update; then the goal is aborted (default "
                  f"{DEFAULT_RESULT_TIMEOUT:g})", DEFAULT_RESULT_TIMEOUT),
        BodyField("client_id", SENDER, False, "your presence client id: the action server exists while that "
                                              "client is live", None, names="sender"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionOffer:
        got = read(cls.FIELDS, data, shape='expected {"type": "pkg/action/Type"} (optional "accept_timeout", '
                                           '"result_timeout", "client_id")')
        if not is_interface(got["type"], "action"):
            raise refuse(f"'{got['type']}' is not an action type (pkg/action/Type)", got, cls.FIELDS)
        return cls(**got)


@dataclass(frozen=True, slots=True)
class ActionRequest:
    """A ROS goal or cancel request for a provider, on ``to/<user>/action_request/<action>``."""

    id: str
    op: str  # "goal" or "cancel"
    goal: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Text(), True, "the bridge's id for the goal (`<robot>-g<n>`): echo it in every update"),
        BodyField("op", Choice(("goal", "cancel")), True, "`goal` (accept or reject it, then work on it) or "
                                                          "`cancel` (a ROS client asked to cancel it: finish it "
                                                          "with `canceled`)"),
        BodyField("goal", Obj(), False, "with `goal`: the ROS goal as JSON", {}, written="null",
                  written_if=("op", "goal")),
        BodyField("client_id", Text(), False, "the offer's `client_id`", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # `goal` only with op goal (a cancel carries none)
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionRequest:
        return cls(**read(cls.FIELDS, data, shape="action request: expected a JSON object", strict=False,
                          what="action request"))


@dataclass(frozen=True, slots=True)
class ActionUpdate:
    """A provider's word on a goal, on ``from/<user>/action_update/<action>`` (read by the bridge)."""

    id: str
    status: str  # one of UPDATE_STATUSES
    feedback: dict[str, Any] | None = None
    result: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Text(1), True, "the request's id", names="request"),
        BodyField("status", Choice(UPDATE_STATUSES), True, "`accepted` or `rejected` (answer to a goal), "
                                                           "`feedback`, then one of `succeeded`, `aborted`, "
                                                           "`canceled` (the end)"),
        BodyField("feedback", AnyJson(), False, "with `feedback`: the action's feedback as JSON", None,
                  docs_type="object"),
        BodyField("result", Nullable(Obj()), False, "with the end: the action's result as JSON (missing: "
                                                    "defaults)", None, docs_type="object"),
        BodyField("error", Nullable(Text()), False, "with `rejected` or `aborted`: why (logged by the bridge)", None,
                  docs_type="string"),
        BodyField("client_id", SENDER, False, "names you in an error report", None, names="sender"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionUpdate:
        got = read(cls.FIELDS, data, shape='expected a JSON object {"id": "…", "status": "…"}')
        if got["status"] == FEEDBACK and not isinstance(got["feedback"], dict):
            raise refuse("feedback: expected an object with status feedback", got, cls.FIELDS)
        return cls(**{**got, "feedback": got["feedback"] if got["status"] == FEEDBACK else None})


PROVIDED_ACTION_BODIES: tuple[tuple[str, str, type], ...] = (
    ("action offer", f"`{_DOC.user_topic(_R, _U, Verb.PROVIDE_ACTION, '<action>')}` (an empty retained message "
                     "withdraws)", ActionOffer),
    ("action request", f"`{_DOC.user_topic(_R, _U, Verb.ACTION_REQUEST, '<action>')}`", ActionRequest),
    ("action update", f"`{_DOC.user_topic(_R, _U, Verb.ACTION_UPDATE, '<action>')}`", ActionUpdate),
)
