"""Parameters of SDK nodes, held as ROS parameters by the bridge (docs/protocol.md, "Parameters of SDK nodes").

An SDK node (a program without ROS) declares parameters; it announces them with a retained
``from/<user>/declare/<node>`` naming its presence client. While that client is live the bridge keeps an rclpy
node called ``<node>`` (in the bridge's namespace) holding those parameters, so ``ros2 param get/set/list
/<node> …``, rqt and any parameter client work on them. A ROS ``set_parameters`` is forwarded to the SDK as
``to/<user>/param_set/<node>``; the SDK runs its on-set callbacks and answers on
``from/<user>/param_result/<node>``, which becomes the ROS client's ``SetParametersResult`` (refusal reason
included). When the declaration is withdrawn (empty retained message) or the presence client goes away
(last-will, heartbeat timeout), the ROS node and its parameter services are destroyed.

Threads: rclpy's on-set-parameters callback is synchronous, so answering it means *waiting* for the SDK over
MQTT (bounded by ``timeout``). That must never stall the bridge's own executor, which runs the failsafe, so
these proxy nodes live on their own :class:`SingleThreadedExecutor` in one thread of their own, which also
creates, updates and destroys them (rclpy entities are touched from that thread only). MQTT messages only edit
the table of declarations; :meth:`refresh` (the bridge's supervision timer) decides which are live, as
:mod:`.service_provider` does for provided services.
"""

from __future__ import annotations

import itertools
import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter

from ...config import Robot
from ...protocol.node_params import DeclaredParameter, ParamDeclaration, ParamSetRequest, ParamSetResult
from ...protocol.params import TYPE_CODES
from ...topics import TopicTree
from .parameters import to_json

log = logging.getLogger("roslink_mqtt.bridge.ros.sdk_params")

Publish = Callable[[str, bytes, int], None]
SET_TIMEOUT = 2.0  # s a ROS set_parameters waits for the SDK node's answer
SPIN_PERIOD = 0.1  # s: how often the proxy thread reconciles when nothing else wakes it


@dataclass
class _Waiting:
    """A ROS set forwarded to the SDK, parked until its answer (MQTT thread) or a failure."""

    user: str
    node: str
    done: threading.Event = field(default_factory=threading.Event)
    outcome: tuple[bool, str] = (False, "")


@dataclass
class _Declared:
    user: str
    name: str
    client_id: str
    parameters: dict[str, DeclaredParameter]
    live: bool = False  # set by refresh(): the presence client is live (a demoted user's nodes are withdrawn)
    ros: Any = None  # the proxy rclpy Node while it exists (proxy thread only)
    applied: dict[str, DeclaredParameter] = field(default_factory=dict)  # what the proxy node holds


class SdkParameterNodes:
    """The proxy ROS nodes of SDK nodes' parameters, their executor thread and the sets in flight."""

    def __init__(self, node: Node, robot: Robot, topics: TopicTree, publish: Publish,
                 is_live: Callable[[str, str | None], bool],
                 timeout: float = SET_TIMEOUT) -> None:
        self.robot, self.topics, self.publish = robot, topics, publish
        self.is_live, self.timeout = is_live, timeout
        self.context, self.namespace = node.context, node.get_namespace()
        self._lock = threading.RLock()
        self.declared: dict[str, _Declared] = {}  # by node name (one ROS node per name, whoever declares it)
        self._retired: list[_Declared] = []  # withdrawn, their proxy node still to destroy
        self._waiting: dict[str, _Waiting] = {}
        self._ids = itertools.count(1)
        self._syncing = False  # the proxy thread is writing the SDK's own values: no forwarding
        self._stopping = threading.Event()
        self.executor = SingleThreadedExecutor(context=self.context)
        self._thread: threading.Thread | None = None
        self.context.on_shutdown(self.close)

    # -- MQTT thread ------------------------------------------------------------------------------
    def offer(self, user: str, name: str, declaration: ParamDeclaration) -> str | None:
        """``user``'s program holds node ``name``'s parameters (SdkParameterPort): why not, or None."""
        with self._lock:
            old = self.declared.get(name)
            if old is not None and old.user != user:
                return f"node '{name}' is already declared on {self.robot.name} by {old.user}"
            if old is None:
                self.declared[name] = _Declared(user, name, declaration.client_id, declaration.parameters)
            else:
                if old.client_id != declaration.client_id:
                    old.live = False  # another program of the user took the name: live once refresh says so
                old.client_id, old.parameters = declaration.client_id, declaration.parameters
        self._start()
        return None

    def withdraw(self, user: str, name: str, reason: str) -> None:
        with self._lock:
            declared = self.declared.get(name)
            if declared is None or declared.user != user:
                return
            del self.declared[name]
            self._retired.append(declared)
            self._fail_waiting(name, reason)
        self._wake()

    def withdraw_user(self, user: str, reason: str) -> None:
        """``user`` is no longer an operator (bridge/core/fleet_follower.py): every node they declared goes, the
        sets waiting on them failed with ``reason``."""
        with self._lock:
            names = [name for name, declared in self.declared.items() if declared.user == user]
        for name in names:
            self.withdraw(user, name, reason)

    def result(self, user: str, name: str, answer: ParamSetResult) -> str | None:
        """The SDK node's answer (SdkParameterPort): wakes the ROS set waiting for it. Why not, or None."""
        with self._lock:
            call = self._waiting.get(answer.id) if isinstance(answer.id, str) else None
            if call is None or call.user != user or call.node != name:
                call = None
            elif isinstance(answer.id, str):  # it is: the call was found by it
                del self._waiting[answer.id]
        if call is None:
            return f"no pending parameter set with id {answer.id!r} for node '{name}'"
        call.outcome = (answer.successful, answer.reason)
        call.done.set()
        return None

    # -- supervision (the bridge's executor) ---------------------------------------------------------------
    def refresh(self) -> None:
        """Mark which declarations are live (their presence client is; a user no longer an operator has none: their
        declarations were withdrawn, bridge/core/fleet_follower.py)."""
        changed = False
        with self._lock:
            for declared in self.declared.values():
                live = self.is_live(declared.user, declared.client_id)
                if live != declared.live:
                    declared.live, changed = live, True
                    if not live:
                        self._fail_waiting(declared.name, f"{declared.name} went away")
        if changed:
            self._wake()

    def _fail_waiting(self, name: str, reason: str) -> None:
        for call_id in [i for i, c in self._waiting.items() if c.node == name]:
            call = self._waiting.pop(call_id)
            call.outcome = (False, reason)
            call.done.set()

    # -- the proxy thread ----------------------------------------------------------------------------
    def _start(self) -> None:
        with self._lock:
            if self._thread is not None or self._stopping.is_set():
                return
            self._thread = threading.Thread(target=self._run, name="sdk-parameter-nodes", daemon=True)
            self._thread.start()

    def _wake(self) -> None:
        if self._thread is not None:
            try:
                self.executor.wake()
            except Exception:  # shutting down
                pass

    def close(self) -> None:
        """Stop the proxy thread (the context is shutting down); its nodes go with the context."""
        self._stopping.set()
        with self._lock:
            for declared in self.declared.values():
                self._fail_waiting(declared.name, "the bridge is stopping")
        self._wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stopping.is_set() and self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=SPIN_PERIOD)
                self._reconcile()
            except ExternalShutdownException:
                return
            except Exception:  # one node's trouble must not end the others'
                if self._stopping.is_set() or not self.context.ok():
                    return
                log.exception("SDK parameter nodes")

    def _reconcile(self) -> None:
        with self._lock:
            retired, self._retired = self._retired, []
            declared = list(self.declared.values())
        for item in retired:
            self._destroy(item, "withdrawn")
        for item in declared:
            with self._lock:
                live, parameters = item.live, item.parameters
            if live and item.ros is None:
                self._create(item, parameters)
            elif live and parameters is not item.applied:
                self._sync(item, parameters)
            elif not live and item.ros is not None:
                self._destroy(item, f"its presence client {item.client_id} went away")

    def _create(self, item: _Declared, parameters: dict[str, DeclaredParameter]) -> None:
        ros = Node(item.name, namespace=self.namespace, context=self.context, use_global_arguments=False,
                   start_parameter_services=True)
        ros.add_on_set_parameters_callback(partial(self._on_ros_set, item))
        item.ros, item.applied = ros, {}
        self._sync(item, parameters)
        self.executor.add_node(ros)
        log.info("holding the parameters of SDK node %s of %s as ROS node %s (%d parameters)", item.name, item.user,
                 ros.get_fully_qualified_name(), len(parameters))

    def _destroy(self, item: _Declared, why: str) -> None:
        ros, item.ros, item.applied = item.ros, None, {}
        if ros is None:
            return
        self.executor.remove_node(ros)
        ros.destroy_node()
        log.info("removed ROS node %s (SDK node of %s): %s", item.name, item.user, why)

    def _sync(self, item: _Declared, parameters: dict[str, DeclaredParameter]) -> None:
        """Make the proxy node hold ``parameters`` (the SDK's own values: nothing is forwarded back)."""
        ros, applied = item.ros, item.applied
        self._syncing = True
        try:
            for name in [n for n in applied if n not in parameters]:
                self._apply_one(item, name, partial(ros.undeclare_parameter, name))
            for name, p in parameters.items():
                old = applied.get(name)
                if old == p:
                    continue
                same_kind = old is not None and (old.type, old.description, old.read_only) == (
                    p.type, p.description, p.read_only)
                if same_kind and not p.read_only and p.value is not None:
                    self._apply_one(item, name, partial(_set_parameter, ros, name, p))
                    continue
                if old is not None:
                    self._apply_one(item, name, partial(ros.undeclare_parameter, name))
                self._apply_one(item, name, partial(_declare, ros, name, p))
        finally:
            self._syncing = False
        item.applied = parameters

    @staticmethod
    def _apply_one(item: _Declared, name: str, change: Callable[[], Any]) -> None:
        try:
            change()
        except Exception as err:  # e.g. a name rclpy declares itself (use_sim_time): the others still apply
            log.warning("SDK node %s: parameter %s not applied on ROS: %s", item.name, name, err)

    def _on_ros_set(self, item: _Declared, params: list[Parameter]) -> SetParametersResult:
        """rclpy's on-set callback (proxy thread): ask the SDK node, wait for its answer (bounded)."""
        if self._syncing:
            return SetParametersResult(successful=True)
        values = {p.name: to_json(p.get_parameter_value()) for p in params}
        call_id = f"{self.robot.name}-p{next(self._ids)}"
        call = _Waiting(item.user, item.name)
        with self._lock:
            if not item.live or self.declared.get(item.name) is not item:
                return SetParametersResult(successful=False, reason=f"{item.name} went away")
            self._waiting[call_id] = call
            client_id = item.client_id
        body = ParamSetRequest(call_id, values, client_id)
        self.publish(self.topics.param_set(self.robot.name, item.user, item.name), body.to_json(),
                     ParamSetRequest.QOS)
        answered = call.done.wait(self.timeout)
        with self._lock:
            self._waiting.pop(call_id, None)
            if answered and call.outcome[0]:  # the SDK holds these now; its next declaration will say so too
                merged = dict(item.parameters)
                for name, value in values.items():
                    if name in merged:
                        merged[name] = replace(merged[name], value=value)
                item.parameters = item.applied = merged
        if not answered:
            return SetParametersResult(successful=False,
                                       reason=f"timeout: {item.name} did not answer within {self.timeout:g} s")
        successful, reason = call.outcome
        return SetParametersResult(successful=successful, reason=reason)


def _ros_parameter(name: str, p: DeclaredParameter) -> Parameter:
    return Parameter(name, Parameter.Type(TYPE_CODES[p.type]), p.value)


def _set_parameter(ros: Node, name: str, p: DeclaredParameter) -> None:
    ros.set_parameters([_ros_parameter(name, p)])


def _declare(ros: Node, name: str, p: DeclaredParameter) -> None:
    descriptor = ParameterDescriptor(name=name, description=p.description, read_only=p.read_only,
                                     dynamic_typing=p.type == "not_set")
    if p.type == "not_set":
        ros.declare_parameter(name, p.value, descriptor)
    elif p.value is None or p.value == []:  # a type without a value (rclpy cannot tell an empty array's type)
        descriptor.type = TYPE_CODES[p.type]
        ros.declare_parameter(name, Parameter.Type(TYPE_CODES[p.type]), descriptor)
        if p.value == [] and not p.read_only:
            ros.set_parameters([_ros_parameter(name, p)])
    else:
        ros.declare_parameter(name, _ros_parameter(name, p).value, descriptor)
