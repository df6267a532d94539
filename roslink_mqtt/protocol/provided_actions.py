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
from .codec import MAX_CLIENT_ID
from .control import BodyField, _dump, _no_unknown, _object, check_client_id
from .errors import ProtocolError

DEFAULT_ACCEPT_TIMEOUT = 5.0  # s for the provider to accept or reject a goal
DEFAULT_RESULT_TIMEOUT = 600.0  # s from acceptance to the final update
MAX_TIMEOUT = 86400.0
ACCEPTED, REJECTED, FEEDBACK = "accepted", "rejected", "feedback"
SUCCEEDED, ABORTED, CANCELED = "succeeded", "aborted", "canceled"
FINAL = (SUCCEEDED, ABORTED, CANCELED)
UPDATE_STATUSES = (ACCEPTED, REJECTED, FEEDBACK, *FINAL)
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"


def _seconds(body: dict[str, Any], key: str, default: float) -> float:
    value = body.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 < value <= MAX_TIMEOUT:
        raise ProtocolError(f"{key}: expected seconds, 0 < {key} <= {MAX_TIMEOUT:g}")
    return float(value)


@dataclass(frozen=True, slots=True)
class ActionOffer:
    """A retained offer to serve a ROS action, on ``from/<user>/provide_action/<action>`` (empty: withdrawn)."""

    type: str
    accept_timeout: float = DEFAULT_ACCEPT_TIMEOUT
    result_timeout: float = DEFAULT_RESULT_TIMEOUT
    client_id: str | None = None

    FIELDS = (
        BodyField("type", "string `pkg/action/Type`", True, "the ROS action type; the bridge must know it"),
        BodyField("accept_timeout", f"number, 0 < s ≤ {MAX_TIMEOUT:g}", False,
                  f"seconds a ROS goal waits for your accepted/rejected (default {DEFAULT_ACCEPT_TIMEOUT:g})"),
        BodyField("result_timeout", f"number, 0 < s ≤ {MAX_TIMEOUT:g}", False,
                  f"seconds from acceptance to your final update; then the goal is aborted (default "
                  f"{DEFAULT_RESULT_TIMEOUT:g})"),
        BodyField("client_id", "string", False, "your presence client id: the action server exists while that "
                                                "client is live"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return _dump({"type": self.type, "accept_timeout": self.accept_timeout,
                      "result_timeout": self.result_timeout}, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionOffer:
        shape = 'expected {"type": "pkg/action/Type"} (optional "accept_timeout", "result_timeout", "client_id")'
        body = _object(data, shape)
        client_id = check_client_id(body["client_id"]) if "client_id" in body else None
        try:
            _no_unknown(body, ("type", "accept_timeout", "result_timeout", "client_id"))
            kind = body.get("type")
            if not isinstance(kind, str):
                raise ProtocolError(shape)
            if not is_interface(kind, "action"):
                raise ProtocolError(f"'{kind}' is not an action type (pkg/action/Type)")
            return cls(kind, _seconds(body, "accept_timeout", DEFAULT_ACCEPT_TIMEOUT),
                       _seconds(body, "result_timeout", DEFAULT_RESULT_TIMEOUT), client_id)
        except ProtocolError as err:
            raise err.naming(None, client_id) from None


@dataclass(frozen=True, slots=True)
class ActionRequest:
    """A ROS goal or cancel request for a provider, on ``to/<user>/action_request/<action>``."""

    id: str
    op: str  # "goal" or "cancel"
    goal: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (
        BodyField("id", "string", True, "the bridge's id for the goal (`<robot>-g<n>`): echo it in every update"),
        BodyField("op", "string", True, "`goal` (accept or reject it, then work on it) or `cancel` (a ROS client "
                                        "asked to cancel it: finish it with `canceled`)"),
        BodyField("goal", "object", False, "with `goal`: the ROS goal as JSON"),
        BodyField("client_id", "string", False, "the offer's `client_id`"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "op": self.op}
        if self.op == "goal":
            body["goal"] = self.goal
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionRequest:
        body = _object(data, "action request: expected a JSON object")
        rid, op, goal, cid = body.get("id"), body.get("op"), body.get("goal", {}), body.get("client_id")
        if not isinstance(rid, str) or op not in ("goal", "cancel") or not isinstance(goal, dict):
            raise ProtocolError('action request: expected {"id": "…", "op": "goal"|"cancel", "goal": {…}}')
        return cls(rid, op, goal, cid if isinstance(cid, str) else None)


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
        BodyField("id", "string", True, "the request's id"),
        BodyField("status", "string", True, "`accepted` or `rejected` (answer to a goal), `feedback`, then one "
                                            "of `succeeded`, `aborted`, `canceled` (the end)"),
        BodyField("feedback", "object", False, "with `feedback`: the action's feedback as JSON"),
        BodyField("result", "object", False, "with the end: the action's result as JSON (missing: defaults)"),
        BodyField("error", "string", False, "with `rejected` or `aborted`: why (logged by the bridge)"),
        BodyField("client_id", f"string, 1..{MAX_CLIENT_ID} characters", False, "names you in an error report"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "status": self.status}
        if self.feedback is not None:
            body["feedback"] = self.feedback
        if self.result is not None:
            body["result"] = self.result
        if self.error is not None:
            body["error"] = self.error
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ActionUpdate:
        body = _object(data, 'expected a JSON object {"id": "…", "status": "…"}')
        client_id = check_client_id(body["client_id"]) if "client_id" in body else None
        rid = body.get("id")
        if not isinstance(rid, str) or not rid:
            raise ProtocolError("id: expected the request's id (a string)").naming(None, client_id)
        try:
            return cls._checked(rid, body, client_id)
        except ProtocolError as err:
            raise err.naming(rid, client_id) from None

    @classmethod
    def _checked(cls, rid: str, body: dict[str, Any], client_id: str | None) -> ActionUpdate:
        _no_unknown(body, ("id", "status", "feedback", "result", "error", "client_id"))
        status = body.get("status")
        if status not in UPDATE_STATUSES:
            raise ProtocolError(f"status: expected one of {', '.join(UPDATE_STATUSES)}, got {status!r}"[:200])
        feedback, result, error = body.get("feedback"), body.get("result"), body.get("error")
        if status == FEEDBACK and not isinstance(feedback, dict):
            raise ProtocolError("feedback: expected an object with status feedback")
        if result is not None and not isinstance(result, dict):
            raise ProtocolError("result: expected an object")
        if error is not None and not isinstance(error, str):
            raise ProtocolError("error: expected a string")
        return cls(rid, status, feedback if status == FEEDBACK else None, result, error, client_id)


PROVIDED_ACTION_BODIES: tuple[tuple[str, str, type], ...] = (
    ("action offer", f"`{_DOC.user_topic(_R, _U, Verb.PROVIDE_ACTION, '<action>')}` (an empty retained message "
                     "withdraws)", ActionOffer),
    ("action request", f"`{_DOC.user_topic(_R, _U, Verb.ACTION_REQUEST, '<action>')}`", ActionRequest),
    ("action update", f"`{_DOC.user_topic(_R, _U, Verb.ACTION_UPDATE, '<action>')}`", ActionUpdate),
)
