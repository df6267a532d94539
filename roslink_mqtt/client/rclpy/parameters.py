"""Parameters of an SDK node, rclpy-shaped, held on the robot as a ROS node's (docs/sdk.md, "Parameters of your node").

``node.declare_parameter("max_force", 2.5)`` works as in rclpy, and more: the node announces its declared
parameters to its robot (a retained ``from/<user>/declare/<node>``), whose bridge then holds a ROS node named
after this one with the same parameters. ``ros2 param set /legacy_arm max_force 3.0`` (or any ROS parameter
client) reaches this program: its on-set callbacks run inside ``spin`` (as rclpy's do) and decide; the ROS
client gets their answer, refusal reason included. Local ``set_parameters`` goes through the same callbacks.

The classes here keep rclpy's names so porting is mechanical: :class:`Parameter` (``.name``, ``.value``,
``.type_`` with ``Parameter.Type.DOUBLE`` …), :class:`ParameterDescriptor` (description, read_only,
dynamic_typing) and :class:`SetParametersResult` (``successful``, ``reason``). Values are plain Python:
bool, int, float, str, or a list of one of those.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

from ...protocol import ProtocolError
from ...protocol.node_params import (
    DeclaredParameter,
    ParamDeclaration,
    ParamSetRequest,
    ParamSetResult,
    check_node_name,
    check_parameter_name,
)
from ...protocol.params import check_value, ros_type_of
from ...topics import Verb
from ..errors import InvalidArgument, RobotError, RoslinkError

if TYPE_CHECKING:
    from ..dispatch import CallbackQueue, Scheduler
    from ..robot_client import RobotClient

log = logging.getLogger("roslink_mqtt.client")

ANNOUNCE_DELAY = 0.05  # s: declarations and changes made together are announced in one message


class ParameterNotDeclaredException(RoslinkError, KeyError):
    """The parameter was never declared on this node (as rclpy's)."""


class ParameterAlreadyDeclaredException(RoslinkError, ValueError):
    """The parameter is declared already (as rclpy's)."""


class InvalidParameterValueException(RoslinkError, ValueError):
    """An on-set callback (or the declared type) refused the value given to ``declare_parameter``."""


class Parameter:
    """One parameter: ``name``, ``value`` and ``type_`` (a :class:`Parameter.Type`), as rclpy's Parameter.

    ``Parameter("max_force", Parameter.Type.DOUBLE, 3.0)`` or ``Parameter("max_force", value=3.0)``
    (the type is read from the value).
    """

    class Type(Enum):
        """ROS parameter types; the value is the name the protocol uses."""

        NOT_SET = "not_set"
        BOOL = "bool"
        INTEGER = "integer"
        DOUBLE = "double"
        STRING = "string"
        BYTE_ARRAY = "byte_array"
        BOOL_ARRAY = "bool_array"
        INTEGER_ARRAY = "integer_array"
        DOUBLE_ARRAY = "double_array"
        STRING_ARRAY = "string_array"

        @classmethod
        def from_parameter_value(cls, value: Any) -> Parameter.Type:
            if value is None:
                return cls.NOT_SET
            try:
                return cls(ros_type_of(value))
            except ProtocolError as err:
                raise InvalidArgument(str(err)) from None

    def __init__(self, name: str, type_: Parameter.Type | None = None, value: Any = None) -> None:
        if isinstance(value, tuple):
            value = list(value)
        self._name = name
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        elif not isinstance(type_, Parameter.Type):
            raise InvalidArgument(f"type_ must be a Parameter.Type, got {type_!r}")
        elif value is not None and type_ is not Parameter.Type.NOT_SET:
            try:
                value = check_value(value, type_.value)
            except ProtocolError as err:
                raise InvalidArgument(f"parameter '{name}': {err}") from None
        self._type, self._value = type_, value

    @property
    def name(self) -> str:
        return self._name

    @property
    def value(self) -> Any:
        return self._value

    @property
    def type_(self) -> Parameter.Type:
        return self._type

    def __eq__(self, other: object) -> bool:
        return (isinstance(other, Parameter) and (self.name, self.type_, self.value) ==
                (other.name, other.type_, other.value))

    def __hash__(self) -> int:
        return hash((self.name, self.type_))

    def __repr__(self) -> str:
        return f"Parameter({self.name!r}, {self.type_}, {self.value!r})"


@dataclass
class ParameterDescriptor:
    """What ROS tools show about a parameter (rclpy's ``rcl_interfaces.msg.ParameterDescriptor``, in part).

    ``read_only``: ROS clients (and :meth:`Node.set_parameters`) may not change it; ``dynamic_typing``: its
    type may change with a new value (as a parameter declared without a value).
    """

    name: str = ""
    description: str = ""
    read_only: bool = False
    dynamic_typing: bool = False


@dataclass
class SetParametersResult:
    """An on-set callback's answer, and the result of each set (as rclpy's)."""

    successful: bool = True
    reason: str = ""


OnSetCallback = Callable[[list[Parameter]], Any]


def _descriptor(name: str, descriptor: Any) -> ParameterDescriptor:
    if descriptor is None:
        return ParameterDescriptor(name)
    if isinstance(descriptor, Mapping):
        unknown = set(descriptor) - {"name", "description", "read_only", "dynamic_typing"}
        if unknown:
            raise InvalidArgument(f"descriptor: unknown keys {sorted(unknown)} (description, read_only, "
                                  "dynamic_typing)")
        descriptor = ParameterDescriptor(**descriptor)
    # a ParameterDescriptor of ours, or rclpy's message: read the fields we carry
    return ParameterDescriptor(name, str(getattr(descriptor, "description", "") or ""),
                               bool(getattr(descriptor, "read_only", False)),
                               bool(getattr(descriptor, "dynamic_typing", False)))


@dataclass
class _Declared:
    parameter: Parameter
    descriptor: ParameterDescriptor
    static_type: Parameter.Type | None  # None: dynamically typed

    def announced(self) -> DeclaredParameter:
        kind = "not_set" if self.static_type is None else self.static_type.value
        return DeclaredParameter(self.parameter.value, kind, self.descriptor.description,
                                 self.descriptor.read_only)


class NodeParameters:
    """The parameters of one SDK node: declared values, on-set callbacks, and their announcement to the robot.

    Threads: user calls (declare/get/set) come from any thread; ROS sets arrive on the network thread and run
    in the node's callback queue (``spin``); announcements go out from the node's scheduler thread.
    """

    def __init__(self, node_name: str, robot: str, client: RobotClient, callbacks: CallbackQueue,
                 scheduler: Scheduler) -> None:
        self.node_name, self.robot, self.client = node_name, robot, client
        self.callbacks, self.scheduler = callbacks, scheduler
        self._lock = threading.RLock()
        self._declared: dict[str, _Declared] = {}
        self._on_set: list[OnSetCallback] = []
        self._announce_handle: int | None = None
        self._announced = False  # a declaration is (or may be) retained on the broker
        self._closed = False
        self.refused: str | None = None  # why the robot will not hold our parameters (e.g. a viewer)
        client.connection.on_connected.append(self._on_reconnect)

    # -- rclpy's API ---------------------------------------------------------------------------------------
    def declare(self, name: str, value: Any = None, descriptor: Any = None) -> Parameter:
        try:
            check_parameter_name(name)
        except ProtocolError as err:
            raise InvalidArgument(str(err)) from None
        desc = _descriptor(name, descriptor)
        static: Parameter.Type | None
        if isinstance(value, Parameter.Type):  # rclpy: declare_parameter("x", Parameter.Type.DOUBLE)
            static, value = value, None
        else:
            static = None if value is None or desc.dynamic_typing else Parameter.Type.from_parameter_value(value)
        if static is Parameter.Type.NOT_SET:
            static = None
        parameter = Parameter(name, static, value) if static is not None else Parameter(name, value=value)
        with self._lock:
            if name in self._declared:
                raise ParameterAlreadyDeclaredException(f"parameter '{name}' is already declared")
            if value is not None:
                result = self._ask([parameter])
                if not result.successful:
                    raise InvalidParameterValueException(f"parameter '{name}' = {value!r} refused: {result.reason}")
            self._declared[name] = _Declared(parameter, desc, static)
        self._schedule_announce()
        return parameter

    def undeclare(self, name: str) -> None:
        with self._lock:
            if self._declared.pop(name, None) is None:
                raise ParameterNotDeclaredException(f"parameter '{name}' is not declared")
        self._schedule_announce()

    def has(self, name: str) -> bool:
        with self._lock:
            return name in self._declared

    def get(self, name: str) -> Parameter:
        with self._lock:
            declared = self._declared.get(name)
        if declared is None:
            raise ParameterNotDeclaredException(f"parameter '{name}' is not declared")
        return declared.parameter

    def describe(self, name: str) -> ParameterDescriptor:
        with self._lock:
            declared = self._declared.get(name)
        if declared is None:
            raise ParameterNotDeclaredException(f"parameter '{name}' is not declared")
        return declared.descriptor

    def names(self) -> list[str]:
        with self._lock:
            return sorted(self._declared)

    def set(self, parameters: Iterable[Parameter] | Mapping[str, Any]) -> list[SetParametersResult]:
        """Each parameter set on its own (as rclpy's ``set_parameters``): one result per parameter."""
        return [self.set_atomically([p]) for p in _as_parameters(parameters)]

    def set_atomically(self, parameters: Iterable[Parameter] | Mapping[str, Any]) -> SetParametersResult:
        """All of them, or none (one result): types, read-only flags, then the on-set callbacks decide."""
        wanted = _as_parameters(parameters)
        with self._lock:
            for p in wanted:
                if p.name not in self._declared:
                    raise ParameterNotDeclaredException(f"parameter '{p.name}' is not declared")
            result = self._apply(wanted, local=True)
        if result.successful:
            self._schedule_announce()
        return result

    def add_on_set_callback(self, callback: OnSetCallback) -> None:
        with self._lock:
            self._on_set.insert(0, callback)  # rclpy calls the newest first

    def remove_on_set_callback(self, callback: OnSetCallback) -> None:
        with self._lock:
            self._on_set.remove(callback)

    # -- checking and applying -------------------------------------------------------------------------------
    def _apply(self, wanted: list[Parameter], *, local: bool) -> SetParametersResult:
        """Type-check ``wanted`` against the declarations, ask the callbacks, store (lock held)."""
        typed = []
        for p in wanted:
            declared = self._declared.get(p.name)
            if declared is None:
                return SetParametersResult(False, f"parameter '{p.name}' is not declared on {self.node_name}")
            if declared.descriptor.read_only and local:
                return SetParametersResult(False, f"parameter '{p.name}' is read-only")
            if declared.static_type is not None:
                try:
                    value = check_value(p.value, declared.static_type.value) if p.value is not None else None
                except ProtocolError as err:
                    return SetParametersResult(False, f"parameter '{p.name}': {err}")
                if value is None:
                    return SetParametersResult(False, f"parameter '{p.name}' is statically typed "
                                                      f"({declared.static_type.value}): it needs a value")
                p = Parameter(p.name, declared.static_type, value)
            typed.append(p)
        result = self._ask(typed)
        if result.successful:
            for p in typed:
                self._declared[p.name].parameter = p
        return result

    def _ask(self, parameters: list[Parameter]) -> SetParametersResult:
        for callback in list(self._on_set):
            try:
                answer = callback(list(parameters))
            except Exception as err:  # a crashing callback refuses, with the reason
                log.exception("on-set-parameters callback of %s failed", self.node_name)
                return SetParametersResult(False, f"{type(err).__name__}: {err}")
            successful = getattr(answer, "successful", answer if isinstance(answer, bool) else None)
            if not isinstance(successful, bool):
                return SetParametersResult(False, f"the on-set callback returned {answer!r}, expected a "
                                                  "SetParametersResult")
            if not successful:
                return SetParametersResult(False, str(getattr(answer, "reason", "") or "refused"))
        return SetParametersResult(True)

    # -- from the robot: a ROS client sets our parameters (network thread, then the callback queue) --------------
    def on_param_set(self, robot: str, name: str, payload: bytes) -> None:
        if robot != self.robot or name != self.node_name or self._closed:
            return
        try:
            request = ParamSetRequest.from_json(payload)
        except ProtocolError as err:
            log.warning("malformed parameter set for %s from %s: %s", name, robot, err)
            return
        if request.client_id is not None and request.client_id != self.client.client_id:
            return  # another program of this user holds that node
        self.callbacks.put(lambda: self._remote_set(request))

    def _remote_set(self, request: ParamSetRequest) -> None:
        try:
            wanted = [Parameter(n, value=v) for n, v in request.parameters.items()]
            with self._lock:
                result = self._apply(wanted, local=False)
        except Exception as err:  # e.g. a value no parameter can hold
            result = SetParametersResult(False, f"{type(err).__name__}: {err}")
        body = ParamSetResult(request.id, result.successful, result.reason[:1024], self.client.client_id)
        try:
            self.client.connection.publish(self.client.topics.param_result(self.robot, self.client.username,
                                                                           self.node_name),
                                           body.to_json(), qos=ParamSetResult.QOS)
        except Exception as err:  # disconnected: the robot answers the ROS client with its timeout
            log.warning("could not answer a parameter set of %s: %s", self.node_name, err)
        if result.successful:
            self._schedule_announce()

    # -- announcing to the robot ------------------------------------------------------------------------------
    def _schedule_announce(self) -> None:
        with self._lock:
            if self._closed or self._announce_handle is not None:
                return
            self._announce_handle = self.scheduler.call_later(ANNOUNCE_DELAY, self._announce)

    def _announce(self) -> None:
        with self._lock:
            self._announce_handle = None
            if self._closed:
                return
            body = ParamDeclaration(self.client.client_id, {n: d.announced() for n, d in self._declared.items()})
        connection = self.client.connection
        if connection.presence is None:
            self._refuse("the robot holds an SDK node's parameters only while its presence heartbeat is live "
                         "(create the node with presence=True)")
            return
        if not connection.connected.is_set():
            return  # announced again on reconnect
        try:
            check_node_name(self.node_name)
        except ProtocolError as err:
            self._refuse(str(err))
            return
        why = self.client.refusal(self.robot, Verb.DECLARE, self.node_name)  # waits briefly for the access report
        if why is not None:
            self._refuse(why)
            return
        self.refused = None
        self._announced = True
        connection.publish(self._topic(), body.to_json(), qos=ParamDeclaration.QOS, retain=ParamDeclaration.RETAINED)

    def _refuse(self, why: str) -> None:
        if self.refused == why:
            return
        self.refused = why
        self.client.report_refusal(RobotError(self.robot, self._topic(), why, client_id=self.client.client_id))

    def _topic(self) -> str:
        return self.client.topics.declare(self.robot, self.client.username, self.node_name)

    def _on_reconnect(self) -> None:
        """The broker may have forgotten our retained declaration (restart without persistence): say it again."""
        with self._lock:
            if self._declared and not self._closed:
                self._announce_handle = None
        if self._declared and not self._closed:
            self._schedule_announce()

    def withdraw(self, wait: float = 2.0) -> None:
        """The robot removes the ROS node: an empty retained declaration (on destroy_node)."""
        with self._lock:
            self._closed = True
            if self._announce_handle is not None:
                self.scheduler.cancel(self._announce_handle)
                self._announce_handle = None
            announced = self._announced
        connection = self.client.connection
        if announced and connection.connected.is_set():
            info = connection.publish(self._topic(), b"", qos=ParamDeclaration.QOS, retain=True)
            if wait and not connection.on_network_thread():
                info.wait_for_publish(wait)


def _as_parameters(parameters: Iterable[Parameter] | Mapping[str, Any]) -> list[Parameter]:
    if isinstance(parameters, Mapping):
        return [Parameter(name, value=value) for name, value in parameters.items()]
    out = list(parameters)
    for p in out:
        if not isinstance(p, Parameter):
            raise InvalidArgument(f"set_parameters takes Parameter objects or a dict of name → value, got {p!r}")
    return out
