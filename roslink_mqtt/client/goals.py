"""Sending goals to a robot's ROS actions over MQTT: goal handles with feedback, result and cancel.

A goal is ``{"id", "goal"}`` on ``from/<user>/goal/<action>``; its status, feedback and result come back on
``to/<user>/goal_status|feedback|result/<action>`` with the same id (docs/protocol.md, "Actions"). Ids are
this connection's (a random prefix and a counter), so they never collide with the user's other programs.
Like service calls, each handle's outcome is a ``concurrent.futures.Future``: it works for blocking code,
rclpy-style code and asyncio alike. Feedback callbacks run in the client's dispatcher thread.
"""

from __future__ import annotations

import itertools
import threading
import uuid
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any

from ..protocol import ProtocolError
from ..protocol.goals import (
    ACCEPTED,
    CANCELING,
    REJECTED,
    GoalCancel,
    GoalFeedback,
    GoalRequest,
    GoalResult,
    GoalStatus,
)
from ..topics import TopicTree, Verb, check_path
from .connection import Connection
from .dispatch import CallbackQueue
from .errors import GoalError, InvalidType, RobotError, WaitTimeout
from .futures import settle

FeedbackCallback = Callable[[dict[str, Any]], None]


class GoalHandle:
    """One goal in flight: ``accepted()``, ``result()``, ``cancel()``, and ``status`` as the robot last said.

    ``result()`` returns the :class:`~roslink_mqtt.protocol.goals.GoalResult` whatever its status (succeeded,
    aborted, canceled, timeout, failed); it raises :class:`GoalError` when the goal never ran (refused by the
    robot, rejected by the action server).
    """

    def __init__(self, goals: ActionGoals, robot: str, action: str, goal_id: str,
                 feedback_callback: FeedbackCallback | None) -> None:
        self._goals, self.robot, self.action, self.id = goals, robot, action, goal_id
        self.feedback_callback = feedback_callback
        self.status = "sent"  # then accepted / rejected / canceling / the result's status
        self.accepted_future: Future[bool] = Future()
        self.result_future: Future[GoalResult] = Future()

    def accepted(self, timeout: float | None = None) -> bool:
        """True once the action server took the goal; GoalError if it was refused or rejected."""
        try:
            return self.accepted_future.result(timeout)
        except FutureTimeout:
            raise WaitTimeout(f"{self.robot}/{self.action} goal '{self.id}': no answer within {timeout:g} s") \
                from None

    def result(self, timeout: float | None = None) -> GoalResult:
        """The goal's end (blocks); GoalError if it never ran, WaitTimeout after ``timeout`` s."""
        try:
            return self.result_future.result(timeout)
        except FutureTimeout:
            raise WaitTimeout(f"{self.robot}/{self.action} goal '{self.id}': no result within {timeout:g} s") \
                from None

    def cancel(self) -> None:
        """Ask the robot to cancel the goal; the result (status ``canceled``) follows."""
        self._goals.cancel(self)

    def done(self) -> bool:
        return self.result_future.done()

    def __repr__(self) -> str:
        return f"GoalHandle({self.robot}/{self.action} id={self.id!r} status={self.status})"



class ActionGoals:
    """The goals of one connection, resolved from the network thread."""

    def __init__(self, connection: Connection, callbacks: CallbackQueue, topics: TopicTree, user: str, *,
                 client_id: str | None = None) -> None:
        self.connection, self.callbacks, self.topics, self.user = connection, callbacks, topics, user
        self.client_id = client_id
        self._prefix = uuid.uuid4().hex[:10]
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._goals: dict[tuple[str, str, str], GoalHandle] = {}

    def send(self, robot: str, action: str, goal: dict[str, Any] | None,
             feedback_callback: FeedbackCallback | None = None, *, goal_id: str | None = None) -> GoalHandle:
        check_path(action, "action")
        if goal is not None and not isinstance(goal, dict):
            raise InvalidType(f"a goal must be a dict of the action's goal fields, got {type(goal).__name__}")
        goal_id = goal_id or f"{self._prefix}-{next(self._ids)}"
        payload = GoalRequest(goal_id, goal or {}, self.client_id).to_json()
        handle = GoalHandle(self, robot, action, goal_id, feedback_callback)
        with self._lock:
            self._goals[(robot, action, goal_id)] = handle
        self.connection.publish(self.topics.goal(robot, self.user, action), payload, qos=GoalRequest.QOS)
        return handle

    def cancel(self, handle: GoalHandle) -> None:
        if handle.done():
            return
        self.connection.publish(self.topics.cancel(handle.robot, self.user, handle.action),
                                GoalCancel(handle.id, self.client_id).to_json(), qos=GoalCancel.QOS)

    def _find(self, robot: str, action: str, goal_id: Any) -> GoalHandle | None:
        with self._lock:
            return self._goals.get((robot, action, goal_id)) if isinstance(goal_id, str) else None

    def _end(self, handle: GoalHandle) -> None:
        with self._lock:
            self._goals.pop((handle.robot, handle.action, handle.id), None)

    # -- network thread --------------------------------------------------------------------------------
    def on_status(self, robot: str, action: str, payload: bytes) -> None:
        try:
            status = GoalStatus.from_json(payload)
        except ProtocolError:
            return
        handle = self._find(robot, action, status.id)
        if handle is None:
            return
        handle.status = status.status
        if status.status == ACCEPTED:
            settle(handle.accepted_future, result=True)
        elif status.status == REJECTED:
            self._fail(handle, status.error or "rejected by the action server")
        elif status.status == CANCELING:
            settle(handle.accepted_future, result=True)

    def on_feedback(self, robot: str, action: str, payload: bytes) -> None:
        try:
            feedback = GoalFeedback.from_json(payload)
        except ProtocolError:
            return
        handle = self._find(robot, action, feedback.id)
        if handle is not None and handle.feedback_callback is not None:
            callback, body = handle.feedback_callback, feedback.feedback
            self.callbacks.put(lambda: callback(body))

    def on_result(self, robot: str, action: str, payload: bytes) -> None:
        try:
            result = GoalResult.from_json(payload)
        except ProtocolError:
            return
        handle = self._find(robot, action, result.id)
        if handle is None:
            return
        handle.status = result.status
        self._end(handle)
        settle(handle.accepted_future, result=True)  # it ran (a result means the server had it)
        settle(handle.result_future, result=result)

    def on_error(self, error: RobotError) -> bool:
        """A refusal of one of our goals (or cancels); True if it was about one."""
        parsed = self.topics.parse(error.topic)
        if parsed is None or parsed.verb is None or parsed.robot is None or not parsed.name:
            return False
        handle = self._find(parsed.robot, parsed.name, error.request_id)
        if handle is None:
            return False
        if parsed.verb is Verb.GOAL:
            self._fail(handle, error.error)
        return True  # a refused cancel: the goal goes on; the report is shown as any other

    def _fail(self, handle: GoalHandle, reason: str) -> None:
        self._end(handle)
        error = GoalError(handle.robot, handle.action, handle.id, reason)
        settle(handle.accepted_future, error=error)
        settle(handle.result_future, error=error)

    def fail_all(self, reason: str) -> None:
        with self._lock:
            handles, self._goals = list(self._goals.values()), {}
        for handle in handles:
            error = GoalError(handle.robot, handle.action, handle.id, reason)
            settle(handle.accepted_future, error=error)
            settle(handle.result_future, error=error)

    def pending(self) -> int:
        with self._lock:
            return len(self._goals)
