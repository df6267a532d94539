"""Parameters of the robot's ROS nodes with rclpy: the port of the ``param`` capability, and parameter events.

Who may read or set what, and the replies, are :mod:`roslink_mqtt.bridge.core.capabilities.params`' (ROS-free).
Here: the exposed nodes' parameter service clients (robots.yaml ``parameters``), each request carried out on the
executor (woken by a guard condition, as in :mod:`.action_caller`): a set is checked against the declared types
first (a refusal names the parameter and both types), then the node's own validation answers per parameter.
``/parameter_events`` of the exposed nodes is forwarded to ``state/parameter_events/<name>``.
"""

from __future__ import annotations

import collections
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterValue
from rcl_interfaces.srv import DescribeParameters, GetParameters, ListParameters, SetParameters
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from ... import ros_names
from ...config import ParameterRule, Robot
from ...protocol import ProtocolError
from ...protocol.params import (
    TYPE_CODES,
    TYPE_NAMES,
    ParamEvent,
    ParamRequest,
    check_value,
    ros_type_of,
)
from ...protocol.validate import show_key
from ...topics import TopicTree
from ..core.capabilities.params import ParamOutcome
from ..core.on_executor import OnExecutor
from ..core.pending import PendingCalls

log = logging.getLogger("roslink_mqtt.bridge.ros.parameters")

_ARRAYS = {5: "byte_array_value", 6: "bool_array_value", 7: "integer_array_value", 8: "double_array_value",
           9: "string_array_value"}
_SCALARS = {1: "bool_value", 2: "integer_value", 3: "double_value", 4: "string_value"}


def to_json(value: ParameterValue) -> Any:
    """A ROS ParameterValue as JSON (None: not set)."""
    if value.type in _SCALARS:
        return getattr(value, _SCALARS[value.type])
    if value.type in _ARRAYS:
        items = getattr(value, _ARRAYS[value.type])
        return [int(b) if isinstance(b, bytes) else b for b in (list(items) if value.type != 5 else bytes(items))]
    return None


def from_json(value: Any, type_name: str) -> ParameterValue:
    """A checked JSON value (see protocol.params.check_value) as a ROS ParameterValue of ``type_name``."""
    code = TYPE_CODES[type_name]
    out = ParameterValue(type=code)
    if code in _SCALARS:
        setattr(out, _SCALARS[code], value)
    elif code in _ARRAYS:
        setattr(out, _ARRAYS[code], bytes(value) if code == 5 else list(value))
    return out


def _describe(descriptor: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"type": TYPE_NAMES.get(descriptor.type, str(descriptor.type)),
                           "description": descriptor.description, "read_only": descriptor.read_only,
                           "dynamic_typing": descriptor.dynamic_typing}
    if descriptor.additional_constraints:
        out["additional_constraints"] = descriptor.additional_constraints
    for key, ranges in (("floating_point_range", descriptor.floating_point_range),
                        ("integer_range", descriptor.integer_range)):
        if ranges:
            r = ranges[0]
            out[key] = {"from": r.from_value, "to": r.to_value, "step": r.step}
    return out


@dataclass
class _Request:
    rule: ParameterRule
    request: ParamRequest
    done: ParamOutcome  # called once (the capability makes sure): the reply, a failure or a refusal


@dataclass
class _NodeClients:
    get: Any
    set: Any
    list: Any
    describe: Any
    full_name: str


class RosParameters:
    """The :class:`~roslink_mqtt.bridge.core.capabilities.params.ParameterPort` with rclpy: the exposed nodes' parameter
    service clients and the requests in flight; and the forwarding of their parameter events."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Callable[[str, bytes, int], None],
                 on_executor: OnExecutor) -> None:
        self.node, self.robot, self.topics, self.publish = node, robot, topics, publish
        group = ReentrantCallbackGroup()
        self.rules = {rule.name: rule for rule in robot.parameters}
        self.clients: dict[str, _NodeClients] = {}
        for rule in robot.parameters:
            base = rule.node

            def client(srv: Any, name: str, base: str = base) -> Any:
                return node.create_client(srv, ros_names.child(base, name), callback_group=group)

            self.clients[rule.name] = _NodeClients(
                client(GetParameters, "get_parameters"), client(SetParameters, "set_parameters"),
                client(ListParameters, "list_parameters"), client(DescribeParameters, "describe_parameters"),
                node.resolve_topic_name(base))  # the node's full name, as /parameter_events gives it
        self._by_full_name = {c.full_name: name for name, c in self.clients.items()}
        self.pending: PendingCalls[tuple[_Request, Any]] = PendingCalls()
        self._inbox: collections.deque[_Request] = collections.deque()
        self.on_executor = on_executor
        if self.rules:
            node.create_subscription(ParameterEvent, "/parameter_events", self._on_event, 100,
                                     callback_group=group)

    # -- ParameterPort (MQTT thread) -------------------------------------------------------------------
    def request(self, rule: ParameterRule, request: ParamRequest, done: ParamOutcome) -> None:
        """Queue the request for the executor (every rclpy call runs there)."""
        self._inbox.append(_Request(rule, request, done))
        self.on_executor.run(self._drain)

    # -- executor ----------------------------------------------------------------------------------------
    def _drain(self) -> None:
        while self._inbox:
            req = self._inbox.popleft()
            try:
                self._start(req)
            except Exception as err:  # one request's failure must not stop the others
                log.exception("parameter request failed")
                self._fail(req, f"the bridge failed to make the request: {err}")

    def _start(self, req: _Request) -> None:
        clients, op = self.clients[req.rule.name], req.request.op
        if op == "set":  # the declared types first: a wrong type is refused before anything is set
            self._call(req, clients.describe, DescribeParameters.Request(names=list(req.request.values)),
                       self._set_described)
        elif op == "get":
            self._call(req, clients.get, GetParameters.Request(names=list(req.request.names)), self._got)
        elif op == "list":
            self._call(req, clients.list, ListParameters.Request(prefixes=list(req.request.names), depth=0),
                       lambda r, resp: self._reply(r, {"names": sorted(resp.result.names)}))
        else:
            self._call(req, clients.describe, DescribeParameters.Request(names=list(req.request.names)),
                       lambda r, resp: self._reply(r, {n: _describe(d) for n, d in
                                                       zip(r.request.names, resp.descriptors, strict=False)}))

    def _call(self, req: _Request, client: Any, request: Any, then: Callable[[_Request, Any], None]) -> None:
        if not client.service_is_ready():
            self._fail(req, f"the parameters of node {self.clients[req.rule.name].full_name} are not available "
                            "(is the node running?)")
            return
        future = client.call_async(request)
        key = self.pending.add((req, future), time.monotonic() + req.rule.timeout)
        future.add_done_callback(lambda f: self._answered(key, f, then))

    def _answered(self, key: int, future: Any, then: Callable[[_Request, Any], None]) -> None:
        taken = self.pending.take(key)
        if taken is None:
            return  # answered as a timeout already
        req, _ = taken
        if future.cancelled() or future.exception() is not None:
            self._fail(req, f"the node's parameter service failed: {future.exception()}")
            return
        then(req, future.result())

    def _got(self, req: _Request, response: Any, names: tuple[str, ...] | None = None) -> None:
        names = req.request.names if names is None else names
        if len(response.values) == len(names):
            values = {n: to_json(v) for n, v in zip(names, response.values, strict=True)}
            self._reply(req, {n: values.get(n) for n in req.request.names})  # not declared: null
            return
        if names is not req.request.names:
            self._fail(req, "the node's parameters changed during the request; ask again")
            return
        # ROS answers nothing at all when one name is not declared: find the declared ones, ask for those
        clients = self.clients[req.rule.name]

        def listed(r: _Request, resp: Any) -> None:
            declared = tuple(n for n in r.request.names if n in set(resp.result.names))
            if not declared:
                self._reply(r, dict.fromkeys(r.request.names))
                return
            self._call(r, clients.get, GetParameters.Request(names=list(declared)),
                       lambda r2, resp2: self._got(r2, resp2, declared))

        self._call(req, clients.list, ListParameters.Request(depth=0), listed)

    def _set_described(self, req: _Request, response: Any) -> None:
        declared = {n: TYPE_NAMES.get(d.type, "not_set") for n, d in
                    zip(req.request.values, response.descriptors, strict=False)}
        parameters = []
        for name, value in req.request.values.items():
            kind = declared.get(name, "not_set")
            try:
                checked = check_value(value, kind)
                if kind == "not_set":
                    kind = ros_type_of(value)  # undeclared: the node says whether it takes it
            except ProtocolError as err:
                req.done(error=f"values.{show_key(name)}: {err} (node {self.clients[req.rule.name].full_name})",
                         refused=True)
                return
            parameters.append(Parameter(name=name, value=from_json(checked, kind)))
        self._call(req, self.clients[req.rule.name].set, SetParameters.Request(parameters=parameters),
                   lambda r, resp: self._reply(r, {p.name: {"successful": res.successful, "reason": res.reason}
                                                   for p, res in zip(parameters, resp.results, strict=False)}))

    def expire(self, now: float) -> None:
        for req, future in self.pending.expire(now):
            future.cancel()
            self._fail(req, f"timeout: node {self.clients[req.rule.name].full_name} did not answer within "
                            f"{req.rule.timeout:g} s")

    def _on_event(self, event: ParameterEvent) -> None:
        name = self._by_full_name.get(event.node)
        if name is None:
            return
        body = ParamEvent(event.node, {p.name: to_json(p.value) for p in event.new_parameters},
                          {p.name: to_json(p.value) for p in event.changed_parameters},
                          tuple(p.name for p in event.deleted_parameters))
        self.publish(self.topics.param_events(self.robot.name, name), body.to_json(), ParamEvent.QOS)

    # -- outcomes ----------------------------------------------------------------------------------------
    @staticmethod
    def _reply(req: _Request, values: dict[str, Any]) -> None:
        req.done(values)

    @staticmethod
    def _fail(req: _Request, reason: str) -> None:
        req.done(error=reason)
