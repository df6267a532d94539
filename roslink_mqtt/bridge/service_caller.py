"""MQTT users call the robot's ROS services (docs/protocol.md, "Services").

``from/<user>/call/<name>`` ``{"id", "args"}`` → ``to/<user>/reply/<name>``
``{"id", "result", "values" | "error"}``. Calls are asynchronous: the MQTT
thread never waits for ROS, and a slow service never blocks topics. Every call
is answered once: by its future, or by :meth:`ServiceCaller.expire` at its
timeout (:class:`~roslink_mqtt.bridge.pending.PendingCalls` decides which).
The mirror image, services provided by MQTT clients, is :mod:`.service_provider`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from ..config import Robot, Role, ServiceRule
from ..protocol import ProtocolError, sender_id
from ..protocol.control import CallReply, CallRequest
from ..topics import TopicTree, Verb
from .authorize import refusal
from .budget import RequestBudget
from .convert import ConversionError, converter_for
from .pending import PendingCalls
from .ros_types import load_interface

log = logging.getLogger("roslink_mqtt.bridge.services")

Publish = Callable[[str, bytes], None]


def _reply(call_id: Any, *, values: dict | None = None, error: str | None = None,
           client_id: str | None = None) -> bytes:
    """A reply body; ``client_id`` repeats the caller's (every program of the user reads the reply topic)."""
    return CallReply(call_id, error is None, values, error, client_id).to_json()


@dataclass
class _Pending:
    call_id: Any
    reply_topic: str
    timeout: float
    future: Any
    client: Any
    srv: Any
    client_id: str | None = None  # the caller's, repeated in the reply
    user: str = ""  # whose request slot it holds (bridge.max_requests_per_user)


class ServiceCaller:
    """Calls the robot's configured ROS services on behalf of MQTT users."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Publish,
                 role_of: Callable[[str], Role | None], budget: RequestBudget | None = None) -> None:
        self.robot, self.topics, self.publish, self.role_of = robot, topics, publish, role_of
        self.budget = budget or RequestBudget(robot.bridge.max_requests_per_user)
        self.pending: PendingCalls[_Pending] = PendingCalls()
        self.clients: dict[str, tuple[ServiceRule, Any, Any]] = {}
        group = ReentrantCallbackGroup()
        for rule in robot.services:
            srv = load_interface(rule.ros_type)
            self.clients[rule.name] = (rule, srv, node.create_client(srv, rule.ros_service, callback_group=group))

    def handle(self, user: str, name: str, payload: bytes) -> None:
        """A call from ``user`` to service ``name`` (MQTT thread: never blocks)."""
        reply_topic = self.topics.reply(self.robot.name, user, name)
        try:
            call = CallRequest.from_json(payload)
        except ProtocolError as err:
            self.publish(reply_topic, _reply(None, error=str(err), client_id=sender_id(payload)))
            return
        call_id, args, sender = call.id, call.args, call.client_id
        entry = self.clients.get(name)
        if entry is None:
            known = ", ".join(sorted(self.clients)) or "none"
            self.publish(reply_topic, _reply(call_id, error=f"unknown service '{name}' (services: {known})",
                                             client_id=sender))
            return
        rule, srv, client = entry
        why = refusal(user, self.role_of(user), Verb.CALL, name, robot=self.robot.name, read_only=rule.read_only)
        if why:
            self.publish(reply_topic, _reply(call_id, error=why, client_id=sender))
            return
        try:
            request = converter_for(srv.Request).from_dict(args)
        except ConversionError as err:
            self.publish(reply_topic, _reply(call_id, error=f"bad arguments: args.{err}", client_id=sender))
            return
        if not client.service_is_ready():
            self.publish(reply_topic, _reply(call_id, error=f"service not available: {rule.ros_service} "
                                                            f"({rule.ros_type}) has no server", client_id=sender))
            return
        if not self.budget.acquire(user):
            self.publish(reply_topic, _reply(call_id, error=self.budget.refusal(user), client_id=sender))
            return
        future = client.call_async(request)
        key = self.pending.add(_Pending(call_id, reply_topic, rule.timeout, future, client, srv, sender, user),
                               time.monotonic() + rule.timeout)
        future.add_done_callback(lambda f, key=key: self._done(key, f))

    def _done(self, key: int, future: Any) -> None:
        pending = self.pending.take(key)
        if pending is None:  # already answered as a timeout
            return
        self.budget.release(pending.user)
        if future.cancelled() or future.exception() is not None:
            self.publish(pending.reply_topic, _reply(pending.call_id, error=f"service failed: {future.exception()}",
                                                     client_id=pending.client_id))
            return
        values = converter_for(pending.srv.Response).to_dict(future.result())
        self.publish(pending.reply_topic, _reply(pending.call_id, values=values, client_id=pending.client_id))

    def expire(self, now: float) -> None:
        """Answer calls past their timeout (called from the bridge's supervision timer)."""
        for p in self.pending.expire(now):
            self.budget.release(p.user)
            p.client.remove_pending_request(p.future)
            self.publish(p.reply_topic, _reply(p.call_id, error=f"timeout: no answer within {p.timeout:g} s",
                                               client_id=p.client_id))
