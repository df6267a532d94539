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
from .body import SENDER, BodyField, Choice, Id, Obj, Text, read, write

MAX_GOAL_ID = 128  # characters
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"

# GoalStatus.status
ACCEPTED, REJECTED, CANCELING = "accepted", "rejected", "canceling"
# GoalResult.status: the ROS terminal states, and two the bridge gives a goal it ended itself
SUCCEEDED, ABORTED, CANCELED, TIMEOUT, FAILED = "succeeded", "aborted", "canceled", "timeout", "failed"
ROS_STATUS = {4: SUCCEEDED, 5: CANCELED, 6: ABORTED}  # action_msgs/msg/GoalStatus codes
RESULT_STATUSES = (SUCCEEDED, ABORTED, CANCELED, TIMEOUT, FAILED)


_ID = BodyField("id", Id(MAX_GOAL_ID, strings_only=True), True,
                "the goal's id, chosen by the sender: unique among its own goals on that action that have not "
                "ended; every status, feedback and result of the goal carries it", names="request")
_SENDER = BodyField("client_id", SENDER, False,
                    "the sender's id, repeated in everything about the goal (every program of the user reads "
                    "the user's topics)", None, names="sender")
_ECHO = BodyField("client_id", Text(), False, "the goal's `client_id`, when it had one", None)
_ITS_ID = BodyField("id", Text(), True, "the goal's id")


@dataclass(frozen=True, slots=True)
class GoalRequest:
    """A goal for a robot's ROS action, on ``from/<user>/goal/<action>`` (read by the bridge)."""

    id: str
    goal: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (_ID, BodyField("goal", Obj(), False, "the ROS action's goal as JSON (see Generic ROS messages); "
                                                  "missing: `{}`", {}), _SENDER)
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalRequest:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"id": "…", "goal": {…}}'))


@dataclass(frozen=True, slots=True)
class GoalCancel:
    """Cancel one of your goals, on ``from/<user>/cancel/<action>`` (read by the bridge)."""

    id: str
    client_id: str | None = None

    FIELDS = (BodyField("id", Id(MAX_GOAL_ID, strings_only=True), True, "the id the goal was sent with",
                        names="request"), _SENDER)
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalCancel:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"id": "…"}'))


@dataclass(frozen=True, slots=True)
class GoalStatus:
    """What became of a goal before it ended, on ``to/<user>/goal_status/<action>`` (read by the sender)."""

    id: str
    status: str  # ACCEPTED, REJECTED, CANCELING
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        _ITS_ID,
        BodyField("status", Choice((ACCEPTED, REJECTED, CANCELING)), True,
                  "`accepted` (the action server took it), `rejected` (it did not, or the server is not available: "
                  "see `error`), `canceling` (your cancel was accepted; the result follows)"),
        BodyField("error", Text(), False, "with `rejected`: why", None),
        _ECHO,
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalStatus:
        values = read(cls.FIELDS, data, shape="goal status: expected a JSON object", strict=False, what="goal status")
        return cls(**{**values, "error": values["error"] or None})


@dataclass(frozen=True, slots=True)
class GoalFeedback:
    """A goal's progress, on ``to/<user>/feedback/<action>`` (read by the sender). Rate-limited, newest wins."""

    id: str
    feedback: dict[str, Any]
    client_id: str | None = None

    FIELDS = (_ITS_ID, BodyField("feedback", Obj(), True, "the ROS action's feedback as JSON", {}), _ECHO)
    QOS = 0  # newest wins: a lost feedback is replaced by the next one
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalFeedback:
        return cls(**read(cls.FIELDS, data, shape="feedback: expected a JSON object", strict=False, what="feedback"))


@dataclass(frozen=True, slots=True)
class GoalResult:
    """A goal's end, on ``to/<user>/result/<action>`` (read by the sender); nothing follows it for that id."""

    id: str
    status: str  # one of RESULT_STATUSES
    result: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        _ITS_ID,
        BodyField("status", Text(), True, "`succeeded`, `aborted`, `canceled` (the ROS terminal states), "
                                          "`timeout` (no result within the action's `timeout`: the bridge "
                                          "canceled it) or `failed` (the bridge could not get a result)"),
        BodyField("result", Obj(), False, "the ROS action's result as JSON, when the server sent one", None),
        BodyField("error", Text(), False, "why, when the bridge ended the goal (timeout, your presence ended, "
                                          "the broker was lost, an emergency stop)", None),
        _ECHO,
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> GoalResult:
        values = read(cls.FIELDS, data, shape="result: expected a JSON object", strict=False, what="result")
        return cls(**{**values, "error": values["error"] or None})


# (title, topic, type) for the rendered reference, after the control bodies of protocol.control
GOAL_BODIES: tuple[tuple[str, str, type], ...] = (
    ("goal", f"`{_DOC.goal(_R, _U, '<action>')}`", GoalRequest),
    ("goal cancel", f"`{_DOC.cancel(_R, _U, '<action>')}`", GoalCancel),
    ("goal status", f"`{_DOC.user_topic(_R, _U, Verb.GOAL_STATUS, '<action>')}`", GoalStatus),
    ("goal feedback", f"`{_DOC.user_topic(_R, _U, Verb.FEEDBACK, '<action>')}`", GoalFeedback),
    ("goal result", f"`{_DOC.user_topic(_R, _U, Verb.RESULT, '<action>')}`", GoalResult),
)
