"""Control bodies of ROS actions over MQTT (docs/protocol.md, "Actions"): goal, cancel, status, feedback, result.

A user sends ``from/<user>/goal/<action>`` with an id of its own choosing; everything the robot says about
that goal comes back on ``to/<user>/…/<action>`` carrying the same id. Ids live in the user's own topics, so
two users' ids never collide and nobody can name (or cancel) another user's goal. The types follow
:mod:`.control`: frozen, ``from_json`` raising :class:`~roslink_mqtt.protocol.ProtocolError` with the exact
reason, ``to_json``; receivers that are clients ignore fields they do not know, the bridge refuses them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..topics import TopicTree, Verb
from .codec import MAX_CLIENT_ID
from .control import BodyField, _dump, _no_unknown, _object, check_client_id
from .errors import ProtocolError

MAX_GOAL_ID = 128  # characters
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"

# GoalStatus.status
ACCEPTED, REJECTED, CANCELING = "accepted", "rejected", "canceling"
# GoalResult.status: the ROS terminal states, and two the bridge gives a goal it ended itself
SUCCEEDED, ABORTED, CANCELED, TIMEOUT, FAILED = "succeeded", "aborted", "canceled", "timeout", "failed"
ROS_STATUS = {4: SUCCEEDED, 5: CANCELED, 6: ABORTED}  # action_msgs/msg/GoalStatus codes
RESULT_STATUSES = (SUCCEEDED, ABORTED, CANCELED, TIMEOUT, FAILED)


def check_goal_id(value: Any, where: str = "id") -> str:
    if not isinstance(value, str) or not 0 < len(value) <= MAX_GOAL_ID:
        raise ProtocolError(f"{where}: expected a string of 1..{MAX_GOAL_ID} characters (your name for the goal), "
                            f"got {value!r}"[:300])
    return value


def _client_id(body: dict[str, Any]) -> str | None:
    return check_client_id(body["client_id"]) if "client_id" in body else None


def _lenient_client_id(body: dict[str, Any]) -> str | None:
    cid = body.get("client_id")
    return cid if isinstance(cid, str) else None


def _lenient_id(body: dict[str, Any], what: str) -> str:
    goal_id = body.get("id")
    if not isinstance(goal_id, str):
        raise ProtocolError(f"{what}: id: expected a string")
    return goal_id


_ID = BodyField("id", f"string, 1..{MAX_GOAL_ID} characters", True,
                "the goal's id, chosen by the sender: unique among its own goals on that action that have not "
                "ended; every status, feedback and result of the goal carries it")
_SENDER = BodyField("client_id", f"string, 1..{MAX_CLIENT_ID} characters", False,
                    "the sender's id, repeated in everything about the goal (every program of the user reads "
                    "the user's topics)")
_ECHO = BodyField("client_id", "string", False, "the goal's `client_id`, when it had one")


@dataclass(frozen=True, slots=True)
class GoalRequest:
    """A goal for a robot's ROS action, on ``from/<user>/goal/<action>`` (read by the bridge)."""

    id: str
    goal: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (_ID, BodyField("goal", "object", False, "the ROS action's goal as JSON (see Generic ROS messages); "
                                                     "missing: `{}`"), _SENDER)
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return _dump({"id": self.id, "goal": self.goal}, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalRequest:
        body = _object(data, 'expected a JSON object {"id": "…", "goal": {…}}')
        client_id = _client_id(body)
        goal_id = _named_id(body, client_id)
        try:
            _no_unknown(body, ("id", "goal", "client_id"))
            goal = body.get("goal", {})
            if not isinstance(goal, dict):
                raise ProtocolError("goal: expected an object")
        except ProtocolError as err:
            raise err.naming(goal_id, client_id) from None
        return cls(goal_id, goal, client_id)


def _named_id(body: dict[str, Any], client_id: str | None) -> str:
    """The goal id of a request body; a bad one is refused naming the sender (it names no request)."""
    try:
        return check_goal_id(body.get("id"))
    except ProtocolError as err:
        raise err.naming(None, client_id) from None


@dataclass(frozen=True, slots=True)
class GoalCancel:
    """Cancel one of your goals, on ``from/<user>/cancel/<action>`` (read by the bridge)."""

    id: str
    client_id: str | None = None

    FIELDS = (BodyField("id", "string", True, "the id the goal was sent with"), _SENDER)
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return _dump({"id": self.id}, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalCancel:
        body = _object(data, 'expected a JSON object {"id": "…"}')
        client_id = _client_id(body)
        goal_id = _named_id(body, client_id)
        try:
            _no_unknown(body, ("id", "client_id"))
        except ProtocolError as err:
            raise err.naming(goal_id, client_id) from None
        return cls(goal_id, client_id)


@dataclass(frozen=True, slots=True)
class GoalStatus:
    """What became of a goal before it ended, on ``to/<user>/goal_status/<action>`` (read by the sender)."""

    id: str
    status: str  # ACCEPTED, REJECTED, CANCELING
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", "string", True, "the goal's id"),
        BodyField("status", "string", True, "`accepted` (the action server took it), `rejected` (it did not, or "
                                            "the server is not available: see `error`), `canceling` (your cancel "
                                            "was accepted; the result follows)"),
        BodyField("error", "string", False, "with `rejected`: why"),
        _ECHO,
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "status": self.status}
        if self.error is not None:
            body["error"] = self.error
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalStatus:
        body = _object(data, "goal status: expected a JSON object")
        status = body.get("status")
        if status not in (ACCEPTED, REJECTED, CANCELING):
            raise ProtocolError(f"goal status: status: expected accepted, rejected or canceling, got {status!r}")
        error = body.get("error")
        return cls(_lenient_id(body, "goal status"), status, str(error) if error else None, _lenient_client_id(body))


@dataclass(frozen=True, slots=True)
class GoalFeedback:
    """A goal's progress, on ``to/<user>/feedback/<action>`` (read by the sender). Rate-limited, newest wins."""

    id: str
    feedback: dict[str, Any]
    client_id: str | None = None

    FIELDS = (BodyField("id", "string", True, "the goal's id"),
              BodyField("feedback", "object", True, "the ROS action's feedback as JSON"), _ECHO)
    QOS = 0  # newest wins: a lost feedback is replaced by the next one
    RETAINED = False

    def to_json(self) -> bytes:
        return _dump({"id": self.id, "feedback": self.feedback}, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalFeedback:
        body = _object(data, "feedback: expected a JSON object")
        feedback = body.get("feedback")
        return cls(_lenient_id(body, "feedback"), feedback if isinstance(feedback, dict) else {},
                   _lenient_client_id(body))


@dataclass(frozen=True, slots=True)
class GoalResult:
    """A goal's end, on ``to/<user>/result/<action>`` (read by the sender); nothing follows it for that id."""

    id: str
    status: str  # one of RESULT_STATUSES
    result: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", "string", True, "the goal's id"),
        BodyField("status", "string", True, "`succeeded`, `aborted`, `canceled` (the ROS terminal states), "
                                            "`timeout` (no result within the action's `timeout`: the bridge "
                                            "canceled it) or `failed` (the bridge could not get a result)"),
        BodyField("result", "object", False, "the ROS action's result as JSON, when the server sent one"),
        BodyField("error", "string", False, "why, when the bridge ended the goal (timeout, your presence ended, "
                                            "the broker was lost, an emergency stop)"),
        _ECHO,
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "status": self.status}
        if self.result is not None:
            body["result"] = self.result
        if self.error is not None:
            body["error"] = self.error
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalResult:
        body = _object(data, "result: expected a JSON object")
        status = body.get("status")
        if not isinstance(status, str):
            raise ProtocolError("result: status: expected a string")
        result, error = body.get("result"), body.get("error")
        return cls(_lenient_id(body, "result"), status, result if isinstance(result, dict) else None,
                   str(error) if error else None, _lenient_client_id(body))


# (title, topic, type) for the rendered reference, after the control bodies of protocol.control
GOAL_BODIES: tuple[tuple[str, str, type], ...] = (
    ("goal", f"`{_DOC.goal(_R, _U, '<action>')}`", GoalRequest),
    ("goal cancel", f"`{_DOC.cancel(_R, _U, '<action>')}`", GoalCancel),
    ("goal status", f"`{_DOC.user_topic(_R, _U, Verb.GOAL_STATUS, '<action>')}`", GoalStatus),
    ("goal feedback", f"`{_DOC.user_topic(_R, _U, Verb.FEEDBACK, '<action>')}`", GoalFeedback),
    ("goal result", f"`{_DOC.user_topic(_R, _U, Verb.RESULT, '<action>')}`", GoalResult),
)
