"""ROS actions served by MQTT clients (docs/protocol.md, "Actions provided by MQTT clients").

The mirror of :mod:`.service_provider`: a program offers an action with a retained
``from/<user>/provide_action/<action>``; while its presence client is live the bridge runs a ROS action
server ``<action>`` in its namespace. A ROS goal is forwarded as ``to/<user>/action_request/<action>``
(``op: goal``) and waits, as a coroutine, for the provider's ``accepted``/``rejected``; feedback and the end
arrive as ``from/<user>/action_update/<action>``. A ROS cancel request is accepted and forwarded
(``op: cancel``). When the provider withdraws or its presence ends (last-will, silence), every goal it holds
is aborted with the reason and the action server is destroyed once they have answered; a provider that does
not answer in time (``accept_timeout``, ``result_timeout``) has its goal rejected or aborted.

Threads: MQTT messages only parse and queue; goal state, futures and rclpy calls live on the executor (woken
by a guard condition), where the action server's coroutines run.
"""

from __future__ import annotations

import collections
import itertools
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.task import Future

from ...config import Robot
from ...protocol.provided_actions import (
    ACCEPTED,
    CANCELED,
    FEEDBACK,
    REJECTED,
    SUCCEEDED,
    ActionOffer,
    ActionRequest,
    ActionUpdate,
)
from ...topics import TopicTree, Verb
from ..core.on_executor import OnExecutor
from ..core.ros_types import UnknownTypeError, load_interface
from .convert import ConversionError, converter_for

log = logging.getLogger("roslink_mqtt.bridge.ros.action_provider")

DESTROY_GRACE = 0.3  # s after the last goal answered before the server goes (its result must get out)


@dataclass
class _Goal:
    id: str
    request: Any  # the ROS goal message (the same object rclpy hands the execute callback)
    accepted: Future  # ("ok", bool) or ("error", reason)
    done: Future | None = None  # ("ok", ActionUpdate) or ("error", reason), once accepted
    handle: Any = None
    deadline: float = 0.0  # accept deadline, then result deadline


@dataclass
class _Offer:
    user: str
    name: str
    cls: Any
    offer: ActionOffer
    server: Any = None
    goals: dict[str, _Goal] = field(default_factory=dict)
    ending: tuple[float, str] | None = None  # (since, why)


class ProvidedActions:
    """Action servers whose implementation lives in MQTT clients."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Callable[[str, bytes], None],
                 is_live: Callable[[str, str | None], bool], on_executor: OnExecutor) -> None:
        self.node, self.robot, self.topics, self.publish = node, robot, topics, publish
        self.on_executor = on_executor
        self.is_live = is_live
        self.group = ReentrantCallbackGroup()
        self.offers: dict[tuple[str, str], _Offer] = {}
        self._retired: list[_Offer] = []
        self._lock = threading.RLock()
        self._ids = itertools.count(1)
        self._inbox: collections.deque[Callable[[], None]] = collections.deque()

    # -- MQTT thread ------------------------------------------------------------------------------------
    # -- ActionProviderPort (MQTT thread) --------------------------------------------------------------
    def offer(self, user: str, name: str, offer: ActionOffer) -> str | None:
        """``user`` provides ``name`` (the capability checked the grant): why not, or None once queued."""
        try:
            cls = load_interface(offer.type)
        except UnknownTypeError as err:
            return str(err)
        with self._lock:
            taken = [u for (u, n) in self.offers if n == name and u != user]
            if taken:
                return f"action '{name}' is already provided by {taken[0]}"
        self._queue(lambda: self._take_offer(user, name, cls, offer))
        return None

    def update(self, user: str, name: str, update: ActionUpdate, refused: Callable[[str], None]) -> None:
        """``action_update/<name>`` from the provider: carried out on the executor."""
        self._queue(lambda: self._on_update(user, name, update, refused))

    def _queue(self, work: Callable[[], None]) -> None:
        self._inbox.append(work)
        self.on_executor.run(self._drain)

    # -- executor ------------------------------------------------------------------------------------------
    def _drain(self) -> None:
        while self._inbox:
            try:
                self._inbox.popleft()()
            except Exception:  # one provider's failure must not stop the others
                log.exception("provided action work failed")

    def _take_offer(self, user: str, name: str, cls: Any, offer: ActionOffer) -> None:
        with self._lock:
            old = self.offers.get((user, name))
            if old is not None and old.cls is cls:
                old.offer = offer  # the same offer again (a retained redelivery after a reconnect)
                return
            if old is not None:
                self._retire(old, "re-offered with another type")
            self.offers[(user, name)] = _Offer(user, name, cls, offer)

    def withdraw(self, user: str, name: str, reason: str) -> None:
        """``user`` withdraws ``name`` (ActionProviderPort): on the executor, after what is queued."""
        self._queue(lambda: self._withdraw(user, name, reason))

    def _withdraw(self, user: str, name: str, reason: str) -> None:
        with self._lock:
            offer = self.offers.pop((user, name), None)
            if offer is not None:
                self._retire(offer, reason)

    def busy(self) -> bool:
        """Whether any offer or retiring server needs the periodic expire/refresh (any thread)."""
        with self._lock:
            return bool(self.offers or self._retired or self._inbox)

    def withdraw_user(self, user: str, reason: str) -> None:
        with self._lock:
            for key in [k for k in self.offers if k[0] == user]:
                self._retire(self.offers.pop(key), reason)

    def _retire(self, offer: _Offer, reason: str) -> None:
        self._end(offer, reason)
        self._retired.append(offer)

    def _end(self, offer: _Offer, reason: str) -> None:
        """Answer every goal of ``offer`` now (rejected or aborted with ``reason``); the server goes later."""
        if offer.ending is None:
            offer.ending = (time.monotonic(), reason)
        for goal in list(offer.goals.values()):
            self._fail(goal, reason)

    def _fail(self, goal: _Goal, reason: str) -> None:
        if not goal.accepted.done():
            goal.accepted.set_result(("error", reason))
        elif goal.done is not None and not goal.done.done():
            goal.done.set_result(("error", reason))
        self._wake_executor()

    def _wake_executor(self) -> None:
        self.on_executor.wake()  # a goal's coroutine awaits the future just set

    def _on_update(self, user: str, name: str, update: ActionUpdate, refused: Callable[[str], None]) -> None:
        offer = self.offers.get((user, name))
        goal = offer.goals.get(update.id) if offer is not None else None
        if offer is None or goal is None:
            refused(f"no goal {update.id!r} waits for you on '{name}' (ended, timed out, or never sent)")
            return
        if update.status in (ACCEPTED, REJECTED):
            if not goal.accepted.done():
                goal.accepted.set_result(("ok", update.status == ACCEPTED))
                if update.status == REJECTED and update.error:
                    log.info("%s rejected goal %s on %s: %s", user, goal.id, name, update.error)
        elif update.status == FEEDBACK:
            if goal.handle is not None and update.feedback is not None:
                try:
                    goal.handle.publish_feedback(converter_for(offer.cls.Feedback).from_dict(update.feedback))
                except ConversionError as err:
                    refused(f"feedback.{err}")
        elif goal.done is not None and not goal.done.done():
            goal.done.set_result(("ok", update))
        elif not goal.accepted.done():  # an end without accepting first: accept, then end
            goal.accepted.set_result(("ok", True))
            goal.done = Future()
            goal.done.set_result(("ok", update))
        self._wake_executor()

    def expire(self, now: float) -> None:
        """Fail goals whose provider did not answer in time (supervision timer, executor)."""
        with self._lock:
            pending = [(o, g) for o in [*self.offers.values(), *self._retired] for g in o.goals.values()]
        for offer, goal in pending:
            if now > goal.deadline:
                waiting_for = "accept or reject" if not goal.accepted.done() else "finish"
                timeout = offer.offer.accept_timeout if not goal.accepted.done() else offer.offer.result_timeout
                self._fail(goal, f"provider {offer.user} did not {waiting_for} goal {goal.id} within {timeout:g} s")

    def refresh(self) -> None:
        """Create servers whose provider is live; end and destroy withdrawn ones and those whose provider left."""
        with self._lock:
            self._retired = [o for o in self._retired if not self._destroy_when_done(o)]
            for offer in self.offers.values():
                live = self.is_live(offer.user, offer.offer.client_id)
                if live and offer.server is None:
                    offer.ending = None
                    offer.server = ActionServer(
                        self.node, offer.cls, offer.name, execute_callback=self._executor_for(offer),
                        goal_callback=self._goal_callback_for(offer), cancel_callback=self._cancel_callback_for(offer),
                        callback_group=self.group)
                    log.info("providing ROS action %s (%s) for %s", offer.name, offer.offer.type, offer.user)
                elif live and offer.ending is not None:
                    offer.ending = None
                elif not live and offer.server is not None:
                    self._end(offer, f"provider {offer.user} went away")
                    self._destroy_when_done(offer)

    def _destroy_when_done(self, offer: _Offer) -> bool:
        if offer.server is not None:
            if offer.goals or offer.ending is None or time.monotonic() - offer.ending[0] < DESTROY_GRACE:
                return False
            offer.server.destroy()
            offer.server = None
            log.info("removed ROS action %s: %s", offer.name, offer.ending[1])
        return True

    # -- the ROS side (coroutines on the executor) ---------------------------------------------------------
    def _goal_callback_for(self, offer: _Offer) -> Callable[[Any], Any]:
        async def on_goal(request: Any) -> GoalResponse:
            if offer.ending is not None:
                return GoalResponse.REJECT
            goal = _Goal(f"{self.robot.name}-g{next(self._ids)}", request, Future(),
                         deadline=time.monotonic() + offer.offer.accept_timeout)
            offer.goals[goal.id] = goal
            body = ActionRequest(goal.id, "goal", converter_for(type(request)).to_dict(request),
                                 offer.offer.client_id)
            self.publish(self._request_topic(offer), body.to_json())
            status, accepted = await goal.accepted
            if status == "ok" and accepted:
                if goal.done is None:  # (an end that came without an accept has set it already)
                    goal.done = Future()
                goal.deadline = time.monotonic() + offer.offer.result_timeout
                return GoalResponse.ACCEPT
            offer.goals.pop(goal.id, None)
            if status == "error":
                log.warning("goal %s on %s rejected: %s", goal.id, offer.name, accepted)
            return GoalResponse.REJECT
        return on_goal

    def _cancel_callback_for(self, offer: _Offer) -> Callable[[Any], Any]:
        def on_cancel(handle: Any) -> CancelResponse:
            goal = next((g for g in offer.goals.values() if g.handle is handle), None)
            if goal is None:
                return CancelResponse.REJECT
            self.publish(self._request_topic(offer), ActionRequest(goal.id, "cancel",
                                                                    client_id=offer.offer.client_id).to_json())
            return CancelResponse.ACCEPT
        return on_cancel

    def _executor_for(self, offer: _Offer) -> Callable[[Any], Any]:
        async def execute(handle: Any) -> Any:
            goal = next((g for g in offer.goals.values() if g.request is handle.request), None)
            result_cls = offer.cls.Result
            if goal is None or goal.done is None:
                handle.abort()
                return result_cls()
            goal.handle = handle
            try:
                status, update = await goal.done
            finally:
                offer.goals.pop(goal.id, None)
            if status == "error":
                log.warning("goal %s on %s aborted: %s", goal.id, offer.name, update)
                handle.abort()
                return result_cls()
            try:
                result = converter_for(result_cls).from_dict(update.result or {})
            except ConversionError as err:
                log.warning("goal %s on %s: the provider's result does not fit %s: %s", goal.id, offer.name,
                            offer.offer.type, err)
                handle.abort()
                return result_cls()
            if update.status == CANCELED and handle.is_cancel_requested:
                handle.canceled()
            elif update.status == SUCCEEDED:
                handle.succeed()
            else:  # aborted, or canceled without a cancel request (ROS allows canceled only after one)
                handle.abort()
            return result
        return execute

    def _request_topic(self, offer: _Offer) -> str:
        return self.topics.user_topic(self.robot.name, offer.user, Verb.ACTION_REQUEST, offer.name)

