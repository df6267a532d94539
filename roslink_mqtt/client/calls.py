"""Calling a robot's ROS services over MQTT: correlation ids, futures, timeouts.

A call is ``{"id", "args"}`` on ``from/<user>/call/<service>``; the reply
carries the same id on ``to/<user>/reply/<service>``. Every call gets a
``concurrent.futures.Future`` — the one future type that works for blocking
callers (``result(timeout)``), rclpy-style code (``done()``) and asyncio
(``asyncio.wrap_future``) alike. Timeouts come from one scheduler thread, so
a caller that never waits still sees its future fail.
"""

from __future__ import annotations

import itertools
import threading
import uuid
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from ..protocol import ProtocolError
from ..protocol.control import CallReply, CallRequest
from ..topics import TopicTree, check_path
from .connection import Connection
from .dispatch import Scheduler
from .errors import InvalidType, ServiceError, ServiceTimeout
from .futures import settle
from .results import JsonObject

Values = JsonObject  # a response's fields, as the service's ROS type has them


@dataclass
class _Pending:
    robot: str
    service: str
    future: Future[Values]
    timer: int


class ServiceCalls:
    """Outstanding calls of one connection, resolved from the network thread."""

    def __init__(self, connection: Connection, scheduler: Scheduler, topics: TopicTree, user: str, *,
                 client_id: str | None = None) -> None:
        """``client_id`` goes into every call, so that the robot's reply names this program."""
        self.connection, self.scheduler, self.topics, self.user = connection, scheduler, topics, user
        self.client_id = client_id
        self._prefix = uuid.uuid4().hex[:10]  # ids from another process (or an earlier run) never match ours
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._pending: dict[str, _Pending] = {}

    def start(self, robot: str, service: str, args: dict[str, Any] | None, timeout: float) -> Future[Values]:
        """Publish a call; the future gets the reply's ``values`` or a :class:`ServiceError`."""
        check_path(service, "service")
        if args is not None and not isinstance(args, dict):
            raise InvalidType(f"service arguments must be a dict, got {type(args).__name__}")
        call_id = f"{self._prefix}-{next(self._ids)}"
        payload = CallRequest(call_id, args or {}, self.client_id).to_json()  # fails here, before anything is pending
        future: Future[Values] = Future()
        timer = self.scheduler.call_later(timeout, lambda: self._expire(call_id, timeout))
        with self._lock:
            self._pending[call_id] = _Pending(robot, service, future, timer)
        future.add_done_callback(lambda _f: self._forget(call_id))  # a cancelled call leaves nothing behind
        self.connection.publish(self.topics.call(robot, self.user, service), payload, qos=CallRequest.QOS)
        return future

    def on_reply(self, robot: str, service: str, payload: bytes) -> None:
        """A message on ``to/<user>/reply/<service>`` (network thread)."""
        try:
            reply = CallReply.from_json(payload)
        except ProtocolError:
            return
        if not isinstance(reply.id, str):
            return  # not ours (we always send string ids)
        with self._lock:
            pending = self._pending.pop(reply.id, None)
        if pending is None:
            return  # answered after its timeout, or another client's id
        self.scheduler.cancel(pending.timer)
        if reply.result:
            settle(pending.future, result=reply.values or {})
        else:
            reason = reply.error or "the robot reported a failure without a reason"
            settle(pending.future, error=ServiceError(robot, service, reason))

    def pending(self) -> int:
        with self._lock:
            return len(self._pending)

    def _expire(self, call_id: str, timeout: float) -> None:
        with self._lock:
            pending = self._pending.pop(call_id, None)
        if pending is not None:
            settle(pending.future, error=ServiceTimeout(
                pending.robot, pending.service, f"no reply within {timeout:g} s (robot offline, or the broker "
                                                "dropped the call?)"))

    def _forget(self, call_id: str) -> None:
        with self._lock:
            pending = self._pending.pop(call_id, None)
        if pending is not None:
            self.scheduler.cancel(pending.timer)

    def fail_all(self, reason: str) -> None:
        """Fail every outstanding call now (the client is closing)."""
        with self._lock:
            pending, self._pending = list(self._pending.values()), {}
        for p in pending:
            self.scheduler.cancel(p.timer)
            settle(p.future, error=ServiceError(p.robot, p.service, reason))

