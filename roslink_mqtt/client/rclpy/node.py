"""A ROS-like ``Node`` for programs without ROS: the rclpy names, carried over MQTT.

Code written against this API has rclpy's structure — publishers,
subscriptions, services, clients, timers, a logger and ``spin`` — so porting
it to a ROS node is mechanical, but not just a changed import: messages here
are dicts typed by the ROS type name (``"geometry_msgs/msg/Twist"``,
``"std_srvs/srv/SetBool"``), which real rclpy refuses, and topics are MQTT
names (docs/sdk.md, *Porting to rclpy*, lists the steps). The robot's bridge
converts the dicts to and from real ROS messages.

One node is bound to one robot and is one MQTT connection (with operator
presence). Callbacks — subscriptions, services, timers — run only inside
``spin``/``spin_once``, as in rclpy; service *calls* resolve without spinning,
so ``client.call()`` works anywhere, even inside a callback.
"""

from __future__ import annotations

import os
import secrets
import threading
import warnings
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any, TypeVar

from ... import ros_names
from ...connection_options import env_username
from ...mqtt import LOGIN_WAIT
from ...ros_shape import is_ros_pose, is_ros_twist, point_from_ros, twist_from_ros
from ...topics import DEFAULT_PREFIX, Verb, check_name, state_leaf
from ..calls import Values
from ..commands import command_leaf, roslink_command
from ..dispatch import CallbackQueue, Scheduler
from ..errors import CommandRefused, InvalidArgument, InvalidType, NodeDestroyed, NotConnectedError, RobotError
from ..messages import RoslinkMessage
from ..robot_client import DEFAULT_CALL_TIMEOUT, RobotClient
from ..subscriptions import StateItem, StateSubscription
from .context import default_context
from .logger import Logger
from .parameters import NodeParameters, OnSetCallback, Parameter, ParameterDescriptor, SetParametersResult
from .qos import mqtt_qos

ENV_ROBOT = "ROSLINK_ROBOT"
MsgType = str | type[RoslinkMessage]
_Entity = TypeVar("_Entity", bound="Publisher | Subscription | Service | Client | Timer")  # what a node holds


def ros_shaped_to_roslink(command: str, msg: dict[str, Any]) -> dict[str, Any]:
    """Accept rclpy-shaped dicts on ROSLink command topics (the robot's preset expects ROSLink fields).

    ``{"linear": {"x": .2}, "angular": {"z": .5}}`` on ``cmd/twist`` becomes
    ``{"lx": .2, "az": .5}``; a PoseStamped/Pose/Point on ``cmd/go_to_waypoint``
    becomes ``{"x", "y", "z"}``; ``{"data": true}`` (std_msgs/Bool) on a command
    without fields (``arm``, ``disarm``, ``land``) becomes ``{}``. ROSLink-shaped
    dicts pass unchanged. The field mapping is :mod:`roslink_mqtt.ros_shape`'s, which the bridge reads back.
    """
    if command == "twist" and is_ros_twist(msg):
        return twist_from_ros(msg)
    if command == "go_to_waypoint" and is_ros_pose(msg):
        return point_from_ros(msg)
    if command in ("arm", "disarm", "land", "get_map") and set(msg) == {"data"}:
        if msg["data"] is not True:
            raise InvalidArgument(f"{command}: {{'data': {msg['data']!r}}} would do nothing; send {{'data': True}}")
        return {}
    return msg


class Publisher:
    """Publishes to ``<prefix>/<robot>/from/<user>/<topic>``: a ROSLink command or a generic rule's input."""

    def __init__(self, node: Node, msg_type: MsgType, topic: str, qos_profile: Any) -> None:
        self._node, self.msg_type, self.qos_profile = node, msg_type, qos_profile
        self.mqtt_qos = mqtt_qos(qos_profile)  # None: the SDK's per-command default
        self.leaf = command_leaf(topic)
        self.command = roslink_command(self.leaf)  # "twist" etc., None for generic rules
        self.topic = node.robot_client.topics.from_user(node.robot, node.robot_client.username, self.leaf)
        # a generic rule's ROS publisher may exist only while someone advertises it (on_demand rules)
        self.advertised = bool(self.command is None and isinstance(msg_type, str)
                               and node.robot_client.connection.presence)
        if self.advertised and isinstance(msg_type, str):  # (advertised implies a str: the checker cannot see it)
            node.robot_client.advertise(node.robot, self.leaf, msg_type)

    @property
    def topic_name(self) -> str:
        return self.leaf

    def publish(self, msg: dict[str, Any] | RoslinkMessage) -> None:
        """Send one message (validated locally for ROSLink commands: ProtocolError on a bad field).

        While the connection is down (between a lost broker and the reconnect), or when the
        robot's access report says the broker would drop it (we are a viewer), the message is not
        sent and a warning says so (at most every 5 s): rclpy's ``publish`` does not raise for the
        network, and a timer publishing at 10 Hz must not turn into a traceback per tick. An
        emergency stop raises instead, as it must never be lost unnoticed; so does a refused login.
        """
        payload = msg.payload() if isinstance(msg, RoslinkMessage) else msg
        if not isinstance(payload, dict):
            raise InvalidType(f"publish() takes a dict of message fields, got {type(msg).__name__}")
        if self.command is not None:
            payload = ros_shaped_to_roslink(self.command, payload)
        try:
            self._node.robot_client.command(self._node.robot, self.leaf, payload, qos=self.mqtt_qos)
        except (NotConnectedError, CommandRefused) as err:
            if self.command == "emergency_stop":
                raise
            why = "the connection to the broker is down" if isinstance(err, NotConnectedError) else err.error.error
            # a fixed text per cause: the logger throttles by text
            self._node.get_logger().warning(f"{self.leaf} on {self._node.robot} not sent: {why}",
                                            throttle_duration_sec=5.0)

    def get_subscription_count(self) -> int:
        """1 while the robot is online (its bridge is the only reader), else 0."""
        info = self._node.robot_client.robot(self._node.robot)
        return int(info is not None and info.online)

    def destroy(self) -> None:
        self._node.destroy_publisher(self)


class Subscription:
    """Delivers ``<prefix>/<robot>/state/<topic>`` to a callback during spin.

    With a type name (``"nav_msgs/msg/Odometry"``) the callback gets the
    message as a dict — the ROSLink payload for preset topics (``msg["x"]``,
    whatever type is named: the name reshapes nothing), the ROS message for
    generic rules. With a ROSLink message class (``GlobalMotion``) it gets
    the typed object. A rule with ``encoding: cbor`` or ``raw`` gives the dict
    :mod:`.encodings` describes (bytes and arrays kept binary; a raw image as
    ``{"format", "data"}``), told from the payload unless ``encoding`` is given.
    """

    def __init__(self, node: Node, msg_type: MsgType, topic: str, callback: Callable[[Any], None],
                 qos_profile: Any, encoding: str | None = None) -> None:
        self._node, self.msg_type, self.callback, self.qos_profile = node, msg_type, callback, qos_profile
        mqtt_qos(qos_profile)  # refuse a nonsense profile here too; state arrives at the robot's own MQTT QoS
        self.typed = isinstance(msg_type, type) and issubclass(msg_type, RoslinkMessage)
        self._sub: StateSubscription = node.robot_client.subscribe(node.robot, topic, self._deliver,
                                                                   encoding=encoding)
        self.topic_name = state_leaf(self._sub.name)

    def _deliver(self, item: StateItem) -> None:
        if self.typed:
            if isinstance(item, self.msg_type):  # type: ignore[arg-type]
                self.callback(item)
        else:
            self.callback(item.payload() if isinstance(item, RoslinkMessage) else item)

    def destroy(self) -> None:
        self._node.destroy_subscription(self)

    def _close(self) -> None:
        self._sub.close()


class Service:
    """A ROS service on the robot implemented here: ``callback(request: dict, response: dict) -> dict``.

    As in rclpy the callback fills ``response`` and returns it (returning None
    means "the response I filled in"). Raising fails the ROS call with the text.
    """

    def __init__(self, node: Node, srv_type: str, srv_name: str,
                 callback: Callable[[dict[str, Any], dict[str, Any]], Any], timeout: float) -> None:
        self._node, self.srv_type, self.srv_name, self.callback = node, srv_type, ros_names.relative(srv_name), callback
        self._offer = node.robot_client.provide(node.robot, self.srv_name, srv_type, self._handle, timeout=timeout)

    def _handle(self, request: dict[str, Any]) -> dict[str, Any]:
        response: dict[str, Any] = {}
        result = self.callback(request, response)
        return response if result is None else result

    @property
    def refused(self) -> str | None:
        """Why the robot refused to provide it (e.g. not an operator), None while accepted."""
        return self._offer.refused

    def destroy(self) -> None:
        self._node.destroy_service(self)

    def _close(self) -> None:
        self._offer.withdraw()


class Client:
    """Calls a ROS service on the robot through its bridge (``call``, ``call_async``)."""

    def __init__(self, node: Node, srv_type: str, srv_name: str, timeout: float) -> None:
        self._node, self.srv_type, self.srv_name, self.timeout = node, srv_type, ros_names.relative(srv_name), timeout

    def call_async(self, request: dict[str, Any] | None = None) -> Future[Values]:
        """A future with the response dict (``result()``, ``done()``); ServiceError on failure."""
        return self._node.robot_client.call_future(self._node.robot, self.srv_name, request, self.timeout)

    def call(self, request: dict[str, Any] | None = None, timeout_sec: float | None = None) -> Values:
        """Blocking call; works without spinning. Raises ServiceError / ServiceTimeout."""
        return self._node.robot_client.call(self._node.robot, self.srv_name, request,
                                      self.timeout if timeout_sec is None else timeout_sec)

    def service_is_ready(self) -> bool:
        """Best effort: the robot is online (the bridge answers for its services; it cannot be asked cheaply)."""
        info = self._node.robot_client.robot(self._node.robot)
        return info is not None and info.online

    def wait_for_service(self, timeout_sec: float | None = None) -> bool:
        """Wait until :meth:`service_is_ready`; False on timeout."""
        robot = self._node.robot
        return self._node.robot_client.directory.wait(lambda robots: robot in robots and robots[robot].online,
                                                float("inf") if timeout_sec is None else timeout_sec)

    def destroy(self) -> None:
        self._node.destroy_client(self)


class Timer:
    """Runs ``callback`` every ``period`` s inside spin; a tick is skipped while the previous one still waits."""

    def __init__(self, node: Node, period: float, callback: Callable[[], None]) -> None:
        if period <= 0:
            raise InvalidArgument("timer period must be positive")
        self._node, self.timer_period_ns, self.callback = node, int(period * 1e9), callback
        self._period, self._queued, self.cancelled = period, threading.Event(), False
        self._handle = node._scheduler.call_later(period, self._tick)

    def _tick(self) -> None:
        if self.cancelled:
            return
        if not self._queued.is_set():
            self._queued.set()
            self._node._callbacks.put(self._run)
        self._handle = self._node._scheduler.call_later(self._period, self._tick)

    def _run(self) -> None:
        self._queued.clear()
        if not self.cancelled:
            self.callback()

    def cancel(self) -> None:
        self.cancelled = True
        self._node._scheduler.cancel(self._handle)

    def is_canceled(self) -> bool:
        return self.cancelled

    def destroy(self) -> None:
        self._node.destroy_timer(self)


class Node:
    """rclpy.node.Node's shape for one robot; see the module docstring.

    Connection arguments default to ``ROSLINK_URL``, ``ROSLINK_USERNAME``,
    ``ROSLINK_PASSWORD`` and ``ROSLINK_ROBOT``, so ``create_node("name")``
    alone works when the environment names the robot and the login.

    ``robot_client`` is the node's :class:`RobotClient` (its one MQTT connection),
    for what rclpy has no name for: the robot directory, ``recent_errors``, raw
    commands. It was called ``client``, which read as this module's :class:`Client`
    (an rclpy service client); ``client`` still works for one release and warns.
    """

    def __init__(self, node_name: str, *, robot: str | None = None, url: str | None = None,
                 username: str | None = None, password: str | None = None, client_id: str | None = None,
                 ca_file: str | None = None, insecure_tls: bool = False, prefix: str = DEFAULT_PREFIX,
                 presence: bool = True, connect_timeout: float = LOGIN_WAIT, keepalive: int = 5,
                 call_timeout: float = DEFAULT_CALL_TIMEOUT) -> None:
        self._name = check_name(node_name, "node name")
        robot = robot or os.environ.get(ENV_ROBOT)
        if not robot:
            raise InvalidArgument(f"no robot: pass robot= or set {ENV_ROBOT}")
        self.robot = check_name(robot, "robot")
        self.call_timeout = call_timeout
        self._callbacks = CallbackQueue()
        self._scheduler = Scheduler(f"{node_name}-timers")
        self._logger = Logger(node_name, sink=self._to_rosout)
        username = username or env_username() or ""
        self.robot_client = RobotClient(username or None, password, url=url, robots=[self.robot],
                                  client_id=client_id or f"{username}-{node_name}-{secrets.token_hex(8)}",
                                  presence=presence, ca_file=ca_file, insecure_tls=insecure_tls, prefix=prefix,
                                  keepalive=keepalive, on_error=self._on_robot_error, callbacks=self._callbacks)
        self._entities: list[Publisher | Subscription | Service | Client | Timer] = []
        self._destroyed = False
        self._parameters = NodeParameters(self._name, self.robot, self.robot_client, self._callbacks,
                                          self._scheduler)
        self.robot_client.on_param_set = self._parameters.on_param_set
        try:
            self.robot_client.connect(connect_timeout)
        except Exception:
            self._scheduler.close()
            raise
        default_context().add(self)

    @property
    def callback_queue(self) -> CallbackQueue:
        """The queue ``spin`` and ``spin_once`` run: this node's callbacks run only there, as in rclpy."""
        return self._callbacks

    # -- identity ---------------------------------------------------------------------
    def get_name(self) -> str:
        return self._name

    def get_namespace(self) -> str:
        return "/"  # ROS names are resolved in the namespace of the robot's bridge node

    def get_logger(self) -> Logger:
        return self._logger

    @property
    def destroyed(self) -> bool:
        return self._destroyed

    @property
    def client(self) -> RobotClient:
        """Deprecated name of :attr:`robot_client` (it is not a :class:`Client`); removed in the next release."""
        warnings.warn("Node.client is deprecated: use Node.robot_client (Node.client is not an rclpy-style Client)",
                      DeprecationWarning, stacklevel=2)
        return self.robot_client

    # -- entities -----------------------------------------------------------------------
    def create_publisher(self, msg_type: MsgType, topic: str, qos_profile: Any = 10, **_rclpy_options: Any
                         ) -> Publisher:
        """``topic`` under ``from/<user>/``: ``"cmd/twist"`` (or ``"twist"``) or a generic rule's name."""
        return self._add(Publisher(self, msg_type, topic, qos_profile))

    def create_subscription(self, msg_type: MsgType, topic: str, callback: Callable[[Any], None],
                            qos_profile: Any = 10, *, encoding: str | None = None,
                            **_rclpy_options: Any) -> Subscription:
        """``topic`` under ``state/``: ``"state/global_motion"`` or ``"global_motion"``.

        What the callback gets is decided by the robot's rule for ``topic``, not by a type *name*: a preset topic
        delivers its ROSLink payload as a dict, so ``create_subscription("nav_msgs/msg/Odometry",
        "state/global_motion", cb)`` gets ``{"x": …, "y": …, "yaw": …, "vx": …}`` (``msg["x"]``), not an
        Odometry-shaped message (``msg.pose.pose.position.x`` fails); a generic rule delivers the ROS message
        of its ``ros_type`` as a dict (``msg["pose"]["pose"]["position"]["x"]``). The SDK reshapes nothing on
        the way in (on the way out, ``create_publisher`` does take ROS-shaped twists and poses). For typed
        objects pass a ROSLink class (``GlobalMotion``); for the full ROS message of a preset topic add a
        generic rule of that type to robots.yaml.

        ``encoding`` (``json``, ``cbor``, ``raw``: the rule's) is told from each payload when not given.
        """
        return self._add(Subscription(self, msg_type, topic, callback, qos_profile, encoding))

    def create_service(self, srv_type: str, srv_name: str, callback: Callable[[dict[str, Any], dict[str, Any]], Any], *,
                       timeout: float = 5.0, **_rclpy_options: Any) -> Service:
        """Provide ROS service ``srv_name`` on the robot while this node lives (operators only).

        ``timeout`` is how long the robot lets a ROS caller wait for us.
        """
        return self._add(Service(self, srv_type, srv_name, callback, timeout))

    def create_client(self, srv_type: str, srv_name: str, *, timeout: float | None = None,
                      **_rclpy_options: Any) -> Client:
        return self._add(Client(self, srv_type, srv_name, self.call_timeout if timeout is None else timeout))

    def create_timer(self, timer_period_sec: float, callback: Callable[[], None], **_rclpy_options: Any) -> Timer:
        return self._add(Timer(self, timer_period_sec, callback))

    def destroy_publisher(self, publisher: Publisher) -> bool:
        """Remove it; on an ``on_demand`` rule the robot's ROS publisher goes when its last advertiser does."""
        if not self._remove(publisher):
            return False
        if publisher.advertised:
            self.robot_client.unadvertise(self.robot, publisher.leaf)
        return True

    def destroy_subscription(self, subscription: Subscription) -> bool:
        if self._remove(subscription):
            subscription._close()
            return True
        return False

    def destroy_service(self, service: Service) -> bool:
        """Withdraw the service: the robot removes the ROS side, and calls waiting for us fail at once."""
        if self._remove(service):
            service._close()
            return True
        return False

    def destroy_client(self, client: Client) -> bool:
        return self._remove(client)

    def destroy_timer(self, timer: Timer) -> bool:
        if self._remove(timer):
            timer.cancel()
            return True
        return False

    def destroy_node(self) -> None:
        """Withdraw services, stop timers, clear presence, disconnect."""
        if self._destroyed:
            return
        self._destroyed = True
        for entity in list(self._entities):
            if isinstance(entity, Timer):
                entity.cancel()
        self._parameters.withdraw()  # the robot removes the ROS node holding our parameters
        self.robot_client.close()  # withdraws every provided service first
        self._scheduler.close()
        self._entities.clear()
        self._callbacks.wake()
        default_context().remove(self)

    # -- parameters (held on the robot as a ROS node's while this node lives: node_params.py) ---------------
    def declare_parameter(self, name: str, value: Any = None, descriptor: Any = None,
                          ignore_override: bool = False) -> Parameter:
        """Declare ``name`` with ``value`` (its type fixes the parameter's, unless ``descriptor.dynamic_typing``).

        ``descriptor``: a :class:`ParameterDescriptor`, a dict (``description``, ``read_only``,
        ``dynamic_typing``) or rclpy's message. The on-set callbacks see the value first, as in rclpy
        (InvalidParameterValueException if one refuses). ROS clients see it on the robot shortly after:
        ``ros2 param get /<node name> <name>``. ``ignore_override`` is accepted for rclpy's signature.
        """
        return self._parameters.declare(name, value, descriptor)

    def declare_parameters(self, namespace: str, parameters: list[tuple[Any, ...]], ignore_override: bool = False
                           ) -> list[Parameter]:
        """rclpy's form: ``[(name,), (name, value), (name, value, descriptor)]``, names under ``namespace.``."""
        out = []
        for entry in parameters:
            name, *rest = entry
            out.append(self._parameters.declare(f"{namespace}.{name}" if namespace else name, *rest))
        return out

    def undeclare_parameter(self, name: str) -> None:
        self._parameters.undeclare(name)

    def has_parameter(self, name: str) -> bool:
        return self._parameters.has(name)

    def get_parameter(self, name: str) -> Parameter:
        """The parameter (``.name``, ``.value``, ``.type_``); ParameterNotDeclaredException if not declared."""
        return self._parameters.get(name)

    def get_parameters(self, names: list[str]) -> list[Parameter]:
        return [self._parameters.get(name) for name in names]

    def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter | None:
        return self._parameters.get(name) if self._parameters.has(name) else alternative_value

    def describe_parameter(self, name: str) -> ParameterDescriptor:
        return self._parameters.describe(name)

    def set_parameters(self, parameter_list: list[Parameter] | dict[str, Any]) -> list[SetParametersResult]:
        """Set each parameter (a list of :class:`Parameter`, or a dict name → value); one result each.

        The declared type is checked (an integer is fine for a double), then the on-set callbacks decide,
        as for a ROS client's set; accepted values reach the robot's ROS node too.
        """
        return self._parameters.set(parameter_list)

    def set_parameters_atomically(self, parameter_list: list[Parameter] | dict[str, Any]) -> SetParametersResult:
        return self._parameters.set_atomically(parameter_list)

    def add_on_set_parameters_callback(self, callback: OnSetCallback) -> OnSetCallback:
        """``callback(list_of_parameters)`` returns a :class:`SetParametersResult`; it runs for local sets and
        for ROS clients' sets (then inside ``spin``). A refusal's ``reason`` reaches the ROS client."""
        self._parameters.add_on_set_callback(callback)
        return callback

    def remove_on_set_parameters_callback(self, callback: OnSetCallback) -> None:
        self._parameters.remove_on_set_callback(callback)

    # -- internals ------------------------------------------------------------------------
    def _add(self, entity: _Entity) -> _Entity:
        if self._destroyed:
            raise NodeDestroyed(f"node {self._name} was destroyed")
        self._entities.append(entity)
        return entity

    def _remove(self, entity: Any) -> bool:
        try:
            self._entities.remove(entity)
            return True
        except ValueError:
            return False

    def _to_rosout(self, name: str, level: int, text: str, file: str, function: str, line: int) -> None:
        """Log lines go to the robot's /rosout too, as an rclpy node's do (dropped while not connected)."""
        client = getattr(self, "robot_client", None)  # not yet there while the node is being built
        if client is not None and not self._destroyed:
            client.send_log(self.robot, name, level, text, file, function, line)

    def _on_robot_error(self, error: RobotError) -> None:
        parsed = self.robot_client.topics.parse(error.topic)
        if parsed is not None and parsed.verb is Verb.LOG:
            return  # a refused log line is not logged again (it would be sent, and refused, again)
        if not error.robot:  # the connection itself: the broker refused our login (spin raises it too)
            self._logger.error(error.error)
            return
        for entity in self._entities:
            if isinstance(entity, Service) and entity.refused == error.error:
                self._logger.error(f"{self.robot} refused service '{entity.srv_name}': {error.error}")
                return
        self._logger.warning(f"{self.robot} refused {error.topic}: {error.error}", throttle_duration_sec=5.0)

    def __repr__(self) -> str:
        return f"<Node {self._name} robot={self.robot} user={self.robot_client.username}>"
