"""The robot's ROS services, called with rclpy: the :class:`~roslink_mqtt.bridge.core.capabilities.call.ServicePort`.

Everything about who may call what, and the replies, is the call capability's
(:mod:`roslink_mqtt.bridge.core.capabilities.call`, ROS-free). Here: one ROS client per configured service, the
arguments converted to the ROS request, asynchronous calls (the MQTT thread never waits for ROS, and a slow
service never blocks topics), and each call's outcome reported exactly once: by its future, or by
:meth:`RosServices.expire` at its timeout (:class:`~roslink_mqtt.bridge.core.pending.PendingCalls` decides which).
The mirror image, services provided by MQTT clients, is :mod:`.service_provider`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from ...config import Robot, ServiceRule
from ..core.capabilities.call import Outcome
from ..core.pending import PendingCalls
from ..core.ros_types import load_interface
from .convert import ConversionError, converter_for


@dataclass
class _Pending:
    timeout: float
    future: Any
    client: Any
    srv: Any
    done: Outcome


class RosServices:
    """A ROS service client for each of the robot's configured services."""

    def __init__(self, node: Node, robot: Robot) -> None:
        self.pending: PendingCalls[_Pending] = PendingCalls()
        self.clients: dict[str, tuple[Any, Any]] = {}
        group = ReentrantCallbackGroup()
        for rule in robot.services:
            srv = load_interface(rule.ros_type)
            self.clients[rule.name] = (srv, node.create_client(srv, rule.ros_service, callback_group=group))

    def call(self, rule: ServiceRule, args: dict[str, Any], done: Outcome) -> str | None:
        srv, client = self.clients[rule.name]
        try:
            request = converter_for(srv.Request).from_dict(args)
        except ConversionError as err:
            return f"bad arguments: args.{err}"
        if not client.service_is_ready():
            return f"service not available: {rule.ros_service} ({rule.ros_type}) has no server"
        future = client.call_async(request)
        key = self.pending.add(_Pending(rule.timeout, future, client, srv, done), time.monotonic() + rule.timeout)
        future.add_done_callback(lambda f, key=key: self._done(key, f))
        return None

    def _done(self, key: int, future: Any) -> None:
        pending = self.pending.take(key)
        if pending is None:  # already answered as a timeout
            return
        if future.cancelled() or future.exception() is not None:
            pending.done(None, f"service failed: {future.exception()}")
            return
        try:
            values = converter_for(pending.srv.Response).to_dict(future.result())
        except Exception as err:  # the call is answered (and its request slot given back) whatever happens
            pending.done(None, f"the bridge could not read the service's response: {err}")
            return
        pending.done(values, None)

    def expire(self, now: float) -> None:
        """Answer calls past their timeout (called from the bridge's supervision timer)."""
        for p in self.pending.expire(now):
            try:
                p.client.remove_pending_request(p.future)
            finally:  # answered (and its request slot given back) whatever rclpy says
                p.done(None, f"timeout: no answer within {p.timeout:g} s")
