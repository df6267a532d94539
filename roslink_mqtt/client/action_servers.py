"""ROS actions this program serves through a robot's bridge (docs/protocol.md, "Actions provided by MQTT clients").

An offer is a *retained* ``from/<user>/provide_action/<action>`` naming the action type and our presence
client id: the bridge runs a ROS action server while that client's heartbeat is live, so if this process
dies its last-will takes the server down (and the bridge aborts the goals we held). ROS goals arrive as
``action_request/<action>``; each accepted goal runs ``execute(goal)`` in a thread of its own (a goal may take
minutes, and the network thread and other goals must go on), which publishes feedback and returns the result.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from ..protocol import ProtocolError
from ..protocol.provided_actions import (
    ABORTED,
    ACCEPTED,
    CANCELED,
    DEFAULT_ACCEPT_TIMEOUT,
    DEFAULT_RESULT_TIMEOUT,
    FEEDBACK,
    REJECTED,
    SUCCEEDED,
    ActionOffer,
    ActionRequest,
    ActionUpdate,
)
from ..ros_names import is_interface
from ..topics import TopicTree, Verb, check_path
from .connection import Connection
from .errors import InvalidArgument

log = logging.getLogger("roslink_mqtt.client")

MAX_GOALS = 16  # goals one served action runs at once; more are rejected (each holds a thread)


class ServerGoal:
    """One goal a ROS client sent to an action we serve: ``goal`` (dict), feedback, cancel, the end."""

    def __init__(self, action: ServedAction, goal_id: str, goal: dict[str, Any]) -> None:
        self._action, self.id, self.goal = action, goal_id, goal
        self._cancel = threading.Event()
        self._end: tuple[str, str | None] | None = None  # (status, error) set by canceled()/abort()

    @property
    def is_cancel_requested(self) -> bool:
        return self._cancel.is_set()

    def wait_for_cancel(self, timeout: float | None = None) -> bool:
        """Sleep up to ``timeout`` s, waking at once if a cancel arrives; True if one did."""
        return self._cancel.wait(timeout)

    def publish_feedback(self, feedback: dict[str, Any]) -> None:
        self._action.owner.send(self._action, ActionUpdate(self.id, FEEDBACK, feedback=dict(feedback)))

    def canceled(self) -> None:
        """End as canceled (after a cancel request) with the result ``execute`` returns."""
        self._end = (CANCELED, None)

    def abort(self, reason: str = "") -> None:
        """End as aborted with the result ``execute`` returns; ``reason`` goes to the bridge's log."""
        self._end = (ABORTED, reason or None)


Execute = Callable[[ServerGoal], dict[str, Any] | None]  # the result fields; raise to abort
GoalCallback = Callable[[dict[str, Any]], bool]  # accept (True) or reject a goal


class ServedAction:
    """One action we serve; :meth:`withdraw` takes the ROS server down."""

    def __init__(self, owner: ActionServers, robot: str, name: str, action_type: str, execute: Execute,
                 goal_callback: GoalCallback | None, accept_timeout: float, result_timeout: float) -> None:
        self.owner, self.robot, self.name, self.action_type = owner, robot, name, action_type
        self.execute, self.goal_callback = execute, goal_callback
        self.accept_timeout, self.result_timeout = accept_timeout, result_timeout
        self.goals: dict[str, ServerGoal] = {}
        self.lock = threading.Lock()

    def withdraw(self) -> None:
        self.owner.withdraw(self)

    def __repr__(self) -> str:
        return f"<ServedAction {self.robot}/{self.name} ({self.action_type})>"


class ActionServers:
    """The served actions of one connection."""

    def __init__(self, connection: Connection, topics: TopicTree, user: str) -> None:
        self.connection, self.topics, self.user = connection, topics, user
        self._lock = threading.Lock()
        self._served: dict[tuple[str, str], ServedAction] = {}
        connection.on_connected.append(self._republish)

    def serve(self, robot: str, name: str, action_type: str, execute: Execute, *,
              goal_callback: GoalCallback | None = None, accept_timeout: float = DEFAULT_ACCEPT_TIMEOUT,
              result_timeout: float = DEFAULT_RESULT_TIMEOUT) -> ServedAction:
        check_path(name, "action")
        if not isinstance(action_type, str) or not is_interface(action_type, "action"):
            raise InvalidArgument(f"action type must look like 'test_msgs/action/Fibonacci', got {action_type!r}")
        if self.connection.presence is None:
            raise InvalidArgument("serving an action needs operator presence: the robot keeps the ROS action "
                                  "server only while our presence heartbeat is live (presence=True)")
        served = ServedAction(self, robot, name, action_type, execute, goal_callback, accept_timeout,
                              result_timeout)
        with self._lock:
            if (robot, name) in self._served:
                raise InvalidArgument(f"already serving '{name}' on {robot}")
            self._served[(robot, name)] = served
        self._publish_offer(served)
        return served

    def withdraw(self, served: ServedAction, wait: float = 2.0) -> None:
        with self._lock:
            if self._served.get((served.robot, served.name)) is not served:
                return
            del self._served[(served.robot, served.name)]
        info = self.connection.publish(self._topic(served, Verb.PROVIDE_ACTION), b"", qos=ActionOffer.QOS,
                                       retain=ActionOffer.RETAINED)
        if wait and not self.connection.on_network_thread() and self.connection.connected.is_set():
            info.wait_for_publish(wait)

    def withdraw_all(self) -> None:
        with self._lock:
            served = list(self._served.values())
        for action in served:
            self.withdraw(action)

    def _topic(self, served: ServedAction, verb: Verb) -> str:
        return self.topics.user_topic(served.robot, self.user, verb, served.name)

    def _publish_offer(self, served: ServedAction) -> None:
        body = ActionOffer(served.action_type, served.accept_timeout, served.result_timeout, self.connection.client_id)
        self.connection.publish(self._topic(served, Verb.PROVIDE_ACTION), body.to_json(), qos=ActionOffer.QOS,
                                retain=ActionOffer.RETAINED)

    def _republish(self) -> None:
        with self._lock:
            served = list(self._served.values())
        for action in served:
            self._publish_offer(action)

    def send(self, served: ServedAction, update: ActionUpdate) -> None:
        body = ActionUpdate(update.id, update.status, update.feedback, update.result, update.error,
                            self.connection.client_id)
        self.connection.publish(self._topic(served, Verb.ACTION_UPDATE), body.to_json(), qos=ActionUpdate.QOS)

    # -- network thread --------------------------------------------------------------------------------
    def on_request(self, robot: str, name: str, payload: bytes) -> None:
        try:
            request = ActionRequest.from_json(payload)
        except ProtocolError as err:
            log.warning("malformed action request for %s on %s: %s", name, robot, err)
            return
        if request.client_id is not None and request.client_id != self.connection.client_id:
            return  # for another program of this user
        with self._lock:
            served = self._served.get((robot, name))
        if served is None:
            return
        if request.op == "cancel":
            with served.lock:
                goal = served.goals.get(request.id)
            if goal is not None:
                goal._cancel.set()
            return
        goal = ServerGoal(served, request.id, request.goal)
        with served.lock:
            busy = len(served.goals) >= MAX_GOALS
            if not busy:
                served.goals[goal.id] = goal
        if busy:
            self.send(served, ActionUpdate(goal.id, REJECTED, error=f"{MAX_GOALS} goals already running"))
            return
        threading.Thread(target=self._run, args=(served, goal), name=f"goal-{goal.id}", daemon=True).start()

    def _run(self, served: ServedAction, goal: ServerGoal) -> None:
        try:
            if served.goal_callback is not None and not served.goal_callback(goal.goal):
                self.send(served, ActionUpdate(goal.id, REJECTED, error="rejected by the provider"))
                return
            self.send(served, ActionUpdate(goal.id, ACCEPTED))
            try:
                result = served.execute(goal) or {}
            except Exception as err:  # the program's failure ends the goal, not the program
                log.exception("serving goal %s of %s failed", goal.id, served.name)
                self.send(served, ActionUpdate(goal.id, ABORTED, result={}, error=f"{type(err).__name__}: {err}"))
                return
            status, error = goal._end or (SUCCEEDED, None)
            self.send(served, ActionUpdate(goal.id, status, result=dict(result), error=error))
        finally:
            with served.lock:
                served.goals.pop(goal.id, None)
