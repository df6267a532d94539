"""Reading and setting the parameters of a robot's ROS nodes over MQTT (docs/protocol.md, "Parameters").

A request is ``{"id", "op", …}`` on ``from/<user>/param/<node>``; the reply carries the same id on
``to/<user>/param_reply/<node>``, and a refusal comes on ``to/<user>/error`` with the request's id. Each
request is a ``concurrent.futures.Future`` resolved from the network thread, timed out by the client's
scheduler, like service calls.
"""

from __future__ import annotations

import itertools
import threading
import uuid
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from ..protocol import ProtocolError
from ..protocol.params import ParamReply, ParamRequest, ros_type_of
from ..topics import TopicTree, Verb, check_name
from .connection import Connection
from .dispatch import Scheduler
from .errors import InvalidArgument, ParameterError, RobotError
from .futures import settle


@dataclass
class _Pending:
    robot: str
    node: str
    future: Future[dict[str, Any]]
    timer: int


class ParameterRequests:
    """Outstanding parameter requests of one connection."""

    def __init__(self, connection: Connection, scheduler: Scheduler, topics: TopicTree, user: str, *,
                 client_id: str | None = None) -> None:
        self.connection, self.scheduler, self.topics, self.user = connection, scheduler, topics, user
        self.client_id = client_id
        self._prefix = uuid.uuid4().hex[:10]
        self._ids = itertools.count(1)
        self._lock = threading.Lock()
        self._pending: dict[str, _Pending] = {}

    def start(self, robot: str, node: str, op: str, *, names: tuple[str, ...] = (),
              values: dict[str, Any] | None = None, timeout: float = 10.0) -> Future[dict[str, Any]]:
        check_name(node, "parameter node")
        for name, value in (values or {}).items():
            try:
                ros_type_of(value)
            except ProtocolError as err:
                raise InvalidArgument(f"parameter {name}: {err}") from None
        rid = f"{self._prefix}-{next(self._ids)}"
        payload = ParamRequest(rid, op, tuple(names), dict(values or {}), self.client_id).to_json()
        future: Future[dict[str, Any]] = Future()
        timer = self.scheduler.call_later(timeout, lambda: self._expire(rid, timeout))
        with self._lock:
            self._pending[rid] = _Pending(robot, node, future, timer)
        self.connection.publish(self.topics.param(robot, self.user, node), payload, qos=ParamRequest.QOS)
        return future

    def on_reply(self, robot: str, node: str, payload: bytes) -> None:
        try:
            reply = ParamReply.from_json(payload)
        except ProtocolError:
            return
        pending = self._take(reply.id)
        if pending is None:
            return
        if reply.result:
            settle(pending.future, result=reply.values or {})
        else:
            settle(pending.future, error=ParameterError(robot, node, reply.error or "failed without a reason"))

    def on_error(self, error: RobotError) -> bool:
        """A refusal of one of our requests; True if it was about one."""
        parsed = self.topics.parse(error.topic)
        if parsed is None or parsed.verb is not Verb.PARAM:
            return False
        pending = self._take(error.request_id)
        if pending is None:
            return False
        settle(pending.future, error=ParameterError(pending.robot, pending.node, error.error))
        return True

    def _take(self, rid: Any) -> _Pending | None:
        if not isinstance(rid, str):
            return None
        with self._lock:
            pending = self._pending.pop(rid, None)
        if pending is not None:
            self.scheduler.cancel(pending.timer)
        return pending

    def _expire(self, rid: str, timeout: float) -> None:
        with self._lock:
            pending = self._pending.pop(rid, None)
        if pending is not None:
            settle(pending.future, error=ParameterError(pending.robot, pending.node,
                                                         f"no reply within {timeout:g} s"))

    def fail_all(self, reason: str) -> None:
        with self._lock:
            pending, self._pending = list(self._pending.values()), {}
        for p in pending:
            self.scheduler.cancel(p.timer)
            settle(p.future, error=ParameterError(p.robot, p.node, reason))

