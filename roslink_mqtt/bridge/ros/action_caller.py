"""The robot's ROS actions with rclpy: the port of the goal and cancel capabilities (docs/protocol.md, "Actions").

Who may send or cancel what is :mod:`roslink_mqtt.bridge.core.capabilities.goals`' (ROS-free). Here: one
``ActionClient`` per configured action and the goals in flight, keyed by (user, action, id): ids are the user's
own, so two users' ids never collide and nobody can cancel another user's goal. Each goal is answered on
``to/<user>/goal_status/<action>`` (accepted / rejected), ``to/<user>/feedback/<action>`` (at most
``feedback_rate`` per second, newest wins) and one ``to/<user>/result/<action>``.

Safety: :meth:`ActionCaller.cancel_goals` cancels a user's goals (their presence ended) or everyone's (the
broker was lost, an emergency stop); the command endpoint calls it exactly where it stops velocity. A goal
without a result after its ``timeout`` is canceled and reported as ``timeout``. Every goal goes out with an id
of the bridge's own, so it can be canceled before its answer arrives (an emergency stop right after a goal), and
a goal whose answer never comes (a DDS reply lost: the server may be running it) is canceled by that id after
GOAL_ANSWER_WAIT and reported as failed; an answer that comes after that is canceled at once.

Threads: MQTT messages only check and queue; every rclpy action-client call runs on the executor (woken by a
guard condition), because rclpy's ``ActionClient`` records a request's sequence number only after sending it,
so a response handled on the executor in between would be lost.
"""

from __future__ import annotations

import collections
import logging
import os
import threading
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Any

from rclpy.action import ActionClient
from rclpy.action.client import ClientGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from unique_identifier_msgs.msg import UUID

from ... import ros_names
from ...config import ActionRule, Robot
from ...protocol.goals import (
    ACCEPTED,
    CANCELED,
    CANCELING,
    FAILED,
    REJECTED,
    ROS_STATUS,
    TIMEOUT,
    GoalFeedback,
    GoalRequest,
    GoalResult,
    GoalStatus,
)
from ...topics import TopicTree, Verb
from ..core.on_executor import OnExecutor
from ..core.ros_types import UnknownTypeError, load_interface
from .convert import ConversionError, converter_for

log = logging.getLogger("roslink_mqtt.bridge.actions")

RESULT_GRACE = 5.0  # s a canceled goal may take to send its result before the bridge reports it as failed
SERVER_WAIT = 2.0  # s a goal waits for its action server to be discovered (a bridge or robot just started)
# s an action server must have been seen before a goal goes to it: discovery is not symmetric, and Fast DDS (Jazzy)
# drops a goal response to a client whose reply reader the server has not discovered yet ("failed to send response
# (timeout)" in the server's log); the goal then waited for an answer that never came (a clean-clone run: a goal
# sent 0.1 s after the bridge started)
SERVER_SETTLE = 1.0
# s a sent goal may wait for the server's answer (accepted or rejected; rclpy answers at once, a slow goal callback
# takes what it takes): after that, canceled by its id, in case the server took it and only its answer was lost
GOAL_ANSWER_WAIT = 5.0
MAX_GOALS_PER_USER = 64  # goals one user may have in flight on one robot


@dataclass
class _Goal:
    user: str
    action: str
    id: str
    client_id: str | None
    rule: ActionRule
    msg: Any
    handle: Any = None  # the ClientGoalHandle once accepted
    deadline: float = 0.0  # monotonic: the result is due (timeout)
    end_status: str | None = None  # the bridge ended it: reported instead of the ROS status
    end_reason: str | None = None
    cancel_asked: bool = False  # the user canceled before the server accepted it
    waiting_since: float | None = None  # the action server was not there yet: supervise() retries
    cancel_sent: bool = False
    forget_at: float | None = None  # canceled: give up waiting for the result then
    last_feedback: float = 0.0
    pending_feedback: dict[str, Any] | None = None
    ros_id: Any = None  # the unique_identifier_msgs/UUID it was sent with (None: not sent yet)
    sent_at: float | None = None  # monotonic: sent, its answer awaited (GOAL_ANSWER_WAIT)

    @property
    def key(self) -> tuple[str, str, str]:
        return (self.user, self.action, self.id)


Publish = Callable[[str, bytes, int], None]


class ActionCaller:
    """One rclpy ActionClient per configured action, and the table of goals in flight."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Publish, on_executor: OnExecutor) -> None:
        self.robot, self.topics, self.publish = robot, topics, publish
        self.on_executor = on_executor
        self._node = node
        group = ReentrantCallbackGroup()
        self.actions: dict[str, tuple[ActionRule, Any, ActionClient]] = {}
        for rule in robot.actions:
            try:
                cls = load_interface(rule.ros_type)
            except UnknownTypeError as err:
                raise UnknownTypeError(f"actions: {rule.name}: {err}") from None
            self.actions[rule.name] = (rule, cls, ActionClient(node, cls, rule.ros_action, callback_group=group))
        self._goals: dict[tuple[str, str, str], _Goal] = {}
        self._seen_since: dict[str, float] = {}  # action -> since when its server has been seen (SERVER_SETTLE)
        self._lock = threading.Lock()
        self._inbox: collections.deque[Callable[[], None]] = collections.deque()

    # -- ActionPort (MQTT thread): check, then queue for the executor ------------------------------------
    def send_goal(self, user: str, rule: ActionRule, request: GoalRequest) -> str | None:
        """A goal the capability let through (bridge/core/capabilities/goals.py): why not, or None once queued."""
        _rule, cls, _client = self.actions[rule.name]
        try:
            msg = converter_for(cls.Goal).from_dict(request.goal)
        except ConversionError as err:
            return f"goal.{err} ({rule.ros_type})"
        goal = _Goal(user, rule.name, request.id, request.client_id, rule, msg)
        with self._lock:
            if goal.key in self._goals:
                return (f"goal id '{request.id}' is already in use on '{rule.name}': choose an id that is unique "
                        "among your goals that have not ended")
            if sum(1 for g in self._goals.values() if g.user == user) >= MAX_GOALS_PER_USER:
                return f"too many goals in flight ({MAX_GOALS_PER_USER}) for {user} on {self.robot.name}"
            self._goals[goal.key] = goal
        self._queue(lambda: self._send(goal))
        return None

    def cancel_goal(self, user: str, action: str, goal_id: str) -> str | None:
        """Cancel one of ``user``'s own goals: why not, or None once queued."""
        with self._lock:
            goal = self._goals.get((user, action, goal_id))
        if goal is None:
            return f"no goal '{goal_id}' of yours on '{action}' is in flight (ended, never sent, or another user's)"
        self._queue(lambda: self._cancel(goal, None, None))
        return None

    def cancel_goals(self, user: str | None, reason: str) -> int:
        """Cancel every goal of ``user`` (None: of everyone); the results say ``reason``. Any thread."""
        with self._lock:
            goals = [g for g in self._goals.values() if user is None or g.user == user]
        for goal in goals:
            self._queue(partial(self._cancel, goal, CANCELED, reason))
        if goals:
            log.warning("canceling %d goal(s)%s: %s", len(goals), f" of {user}" if user else "", reason)
        return len(goals)

    def _queue(self, work: Callable[[], None]) -> None:
        self._inbox.append(work)
        self.on_executor.run(self._drain)

    # -- executor ------------------------------------------------------------------------------
    def _drain(self) -> None:
        while self._inbox:
            work = self._inbox.popleft()
            try:
                work()
            except Exception:  # one goal's failure must not stop the others (nor the executor)
                log.exception("action work failed")

    def _send(self, goal: _Goal) -> None:
        if goal.end_status is not None:  # canceled by the bridge before it was sent
            self._finish(goal, goal.end_status, None, goal.end_reason)
            return
        now = time.monotonic()
        seen = self._server_seen(goal.action, now)
        if not (seen and now - self._seen_since[goal.action] >= SERVER_SETTLE):
            if goal.waiting_since is None:
                goal.waiting_since = now  # supervise() tries again until SERVER_WAIT has passed
            elif (not seen and now - goal.waiting_since > SERVER_WAIT) or goal.cancel_asked:
                self._status(goal, REJECTED, f"action server not available: {goal.rule.ros_action} "
                                             f"({goal.rule.ros_type})")
                self._forget(goal)
            return
        goal.waiting_since = None
        if (servers := self._servers(goal.rule)) > 1:
            why = (f"{servers} action servers answer ROS action {goal.rule.ros_action}: refused, as each would take "
                   f"the goal (another ROS graph on ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')}? "
                   "a second robot with the same names?)")
            log.warning("goal %s of %s: %s", goal.id, goal.user, why)
            self._status(goal, REJECTED, why)
            self._forget(goal)
            return
        client = self.actions[goal.action][2]
        goal.ros_id, goal.sent_at = UUID(uuid=list(uuid.uuid4().bytes)), now
        future = client.send_goal_async(goal.msg, feedback_callback=lambda fb: self._feedback(goal, fb),
                                        goal_uuid=goal.ros_id)
        future.add_done_callback(lambda f: self._responded(goal, f))

    def _server_seen(self, action: str, now: float) -> bool:
        """Whether ``action``'s server is discovered now; keeps since when (SERVER_SETTLE). Executor."""
        if not self.actions[action][2].server_is_ready():
            self._seen_since.pop(action, None)
            return False
        self._seen_since.setdefault(action, now)
        return True

    def _servers(self, rule: ActionRule) -> int:
        """How many action servers serve ``rule``'s action (each publishes its goals' status).

        More than one is a broken setup -- and with rclpy 7.1's EventsExecutor the second server's
        replies to a goal crashed the bridge (a segfault, reproduced with two servers in one domain).
        """
        return self._node.count_publishers(ros_names.action_status_topic(rule.ros_action))

    def _responded(self, goal: _Goal, future: Any) -> None:
        handle = future.result() if future.exception() is None else None
        goal.sent_at = None
        if not self._live(goal):  # answered after the bridge gave up on it (GOAL_ANSWER_WAIT): nobody owns it
            if handle is not None and handle.accepted:
                log.warning("goal %s of %s on %s: accepted after the bridge gave up on its answer (%g s): canceled",
                            goal.id, goal.user, goal.action, GOAL_ANSWER_WAIT)
                handle.cancel_goal_async()
            return
        if handle is None or not handle.accepted:
            why = "the action server rejected the goal" if handle is not None else \
                f"sending failed: {future.exception()}"
            self._status(goal, REJECTED, why)
            self._forget(goal)
            return
        goal.handle = handle
        goal.deadline = time.monotonic() + goal.rule.timeout
        self._status(goal, ACCEPTED)
        handle.get_result_async().add_done_callback(lambda f: self._result(goal, f))
        if (goal.end_status is not None or goal.cancel_asked) and not goal.cancel_sent:  # canceled while sent
            self._cancel(goal, goal.end_status, goal.end_reason)

    def _cancel(self, goal: _Goal, status: str | None, reason: str | None) -> None:
        """Cancel ``goal``; ``status``/``reason``: the bridge ends it (reported instead of the ROS status)."""
        if status is not None and goal.end_status is None:
            goal.end_status, goal.end_reason = status, reason
        if goal.handle is None:
            goal.cancel_asked = True  # not accepted yet: _responded cancels it as soon as it is, and if it was sent
            if goal.sent_at is not None:  # the server may have it already (its answer late, or lost): by its id now
                self._cancel_by_id(goal)
            return
        if goal.cancel_sent:
            return
        goal.cancel_sent = True
        goal.forget_at = time.monotonic() + RESULT_GRACE
        goal.handle.cancel_goal_async().add_done_callback(lambda f: self._cancel_answered(goal, f))

    def _cancel_by_id(self, goal: _Goal) -> None:
        """Ask the server to cancel the goal sent with ``goal.ros_id``, without its answer (no handle yet)."""
        ClientGoalHandle(self.actions[goal.action][2], goal.ros_id, None).cancel_goal_async()

    def _live(self, goal: _Goal) -> bool:
        with self._lock:
            return self._goals.get(goal.key) is goal

    def _cancel_answered(self, goal: _Goal, future: Any) -> None:
        response = future.result() if future.exception() is None else None
        if response is not None and response.goals_canceling:
            self._status(goal, CANCELING)

    def _feedback(self, goal: _Goal, message: Any) -> None:
        if not self._live(goal):
            return  # a goal the bridge gave up on (being canceled): nobody to tell
        body = converter_for(type(message.feedback)).to_dict(message.feedback)
        now = time.monotonic()
        if now - goal.last_feedback >= 1.0 / goal.rule.feedback_rate:
            goal.last_feedback, goal.pending_feedback = now, None
            self._send_feedback(goal, body)
        else:
            goal.pending_feedback = body  # newest wins; supervise() sends it when its turn comes

    def _result(self, goal: _Goal, future: Any) -> None:
        response = future.result() if future.exception() is None else None
        if response is None:
            self._finish(goal, goal.end_status or FAILED, None, goal.end_reason or f"no result: {future.exception()}")
            return
        result = converter_for(type(response.result)).to_dict(response.result)
        status = ROS_STATUS.get(response.status, FAILED)
        if goal.end_status is not None and status == CANCELED:
            status = goal.end_status  # canceled by the bridge: say why (timeout, presence ended, …)
        self._finish(goal, status, result, goal.end_reason if goal.end_status == status else None)

    def supervise(self, now: float) -> None:
        """Flush due feedback, cancel goals past their timeout, give up on results that never came (executor)."""
        for action in self.actions:  # a server seen long enough takes a goal at once (SERVER_SETTLE)
            self._server_seen(action, now)
        with self._lock:
            goals = list(self._goals.values())
        for goal in goals:
            if goal.waiting_since is not None:
                self._send(goal)
                continue
            if goal.sent_at is not None and now - goal.sent_at > GOAL_ANSWER_WAIT:
                self._cancel_by_id(goal)
                log.warning("goal %s of %s on %s: no answer from the action server within %g s: canceled by its id",
                            goal.id, goal.user, goal.action, GOAL_ANSWER_WAIT)
                unanswered = (f"the action server did not answer within {GOAL_ANSWER_WAIT:g} s (accepted or "
                              "rejected): the bridge canceled the goal in case the server took it")
                # a goal the bridge ended meanwhile (a stop, its operator gone) says so, as an answered one would
                self._finish(goal, goal.end_status or FAILED, None, goal.end_reason or unanswered)
                continue
            if goal.pending_feedback is not None and now - goal.last_feedback >= 1.0 / goal.rule.feedback_rate:
                body, goal.pending_feedback, goal.last_feedback = goal.pending_feedback, None, now
                self._send_feedback(goal, body)
            if goal.handle is not None and not goal.cancel_sent and now > goal.deadline:
                self._cancel(goal, TIMEOUT, f"no result within {goal.rule.timeout:g} s: the bridge canceled it")
            elif goal.forget_at is not None and now > goal.forget_at:
                self._finish(goal, goal.end_status or FAILED, None,
                             (goal.end_reason or "canceled") + f"; no result {RESULT_GRACE:g} s after the cancel")

    # -- MQTT out ----------------------------------------------------------------------------
    def _status(self, goal: _Goal, status: str, error: str | None = None) -> None:
        body = GoalStatus(goal.id, status, error, goal.client_id)
        self.publish(self.topics.user_topic(self.robot.name, goal.user, Verb.GOAL_STATUS, goal.action), body.to_json(),
                     GoalStatus.QOS)

    def _send_feedback(self, goal: _Goal, feedback: dict[str, Any]) -> None:
        body = GoalFeedback(goal.id, feedback, goal.client_id)
        self.publish(self.topics.user_topic(self.robot.name, goal.user, Verb.FEEDBACK, goal.action), body.to_json(),
                     GoalFeedback.QOS)

    def _finish(self, goal: _Goal, status: str, result: dict[str, Any] | None, error: str | None) -> None:
        if not self._forget(goal):
            return  # already reported (the result and the grace timer raced)
        if goal.pending_feedback is not None:
            self._send_feedback(goal, goal.pending_feedback)
        body = GoalResult(goal.id, status, result, error, goal.client_id)
        self.publish(self.topics.user_topic(self.robot.name, goal.user, Verb.RESULT, goal.action), body.to_json(),
                     GoalResult.QOS)

    def _forget(self, goal: _Goal) -> bool:
        with self._lock:
            return self._goals.pop(goal.key, None) is not None

    def in_flight(self, user: str | None = None) -> int:
        with self._lock:
            return sum(1 for g in self._goals.values() if user is None or g.user == user)
