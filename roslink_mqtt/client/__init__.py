"""Client SDK for programs without ROS (core install: paho-mqtt, orjson, pyyaml — no rclpy, no amqtt).

Two ways in:

* :class:`RobotClient` — one login to the fleet's broker: robots and their
  presence, typed ROSLink state, commands, service calls (sync and asyncio),
  services provided to ROS.
* the rclpy-shaped API — ``create_node``, ``spin``, publishers,
  subscriptions, services and clients — with rclpy's names and structure, so
  porting code written here to a ROS node is mechanical; but messages are dicts
  and types are names here, which rclpy refuses (docs/sdk.md, *Porting to rclpy*).

See docs/sdk.md.

The rclpy-shaped classes (``Node``, ``Publisher`` …) load on first use
(:func:`__getattr__` below), so importing the package, or its context module,
does not load ``node.py``: a RobotClient-only program skips it, and the
context stays free of an import cycle with the node.
"""

from typing import TYPE_CHECKING, Any

from .context import create_node, init, ok, shutdown, spin, spin_once, spin_until_future_complete, try_shutdown
from .directory import RobotInfo
from .errors import (
    CommandNotConfirmed,
    CommandRefused,
    ConnectError,
    GoalError,
    InvalidArgument,
    InvalidType,
    LoginRefused,
    NodeDestroyed,
    NotConnectedError,
    NotGranted,
    ParameterError,
    RobotError,
    RobotNotice,
    RoslinkError,
    ServiceError,
    ServiceTimeout,
    SubscriptionFailed,
    WaitTimeout,
)
from .goals import GoalHandle
from .messages import (
    Ack,
    Arm,
    Disarm,
    EmergencyStop,
    GeoTaggedImage,
    GetMap,
    GlobalMotion,
    GoToWaypoint,
    GpsRawInfo,
    Heartbeat,
    Image,
    Land,
    Map,
    RangeFinderData,
    RobotStatus,
    RoslinkMessage,
    SetMode,
    Takeoff,
    Twist,
)
from .node_params import (
    InvalidParameterValueException,
    Parameter,
    ParameterAlreadyDeclaredException,
    ParameterDescriptor,
    ParameterNotDeclaredException,
    SetParametersResult,
)
from .presence import OperatorPresence
from .providers import ProvidedService
from .robot_client import RobotClient
from .subscriptions import StateSubscription

if TYPE_CHECKING:  # for type checkers and IDEs; at run time __getattr__ loads them
    from .node import Client, Node, Publisher, Service, Subscription, Timer

_FROM_NODE = frozenset({"Client", "Node", "Publisher", "Service", "Subscription", "Timer"})

__all__ = [
    "Ack", "Arm", "Client", "CommandNotConfirmed", "CommandRefused", "ConnectError", "Disarm", "EmergencyStop",
    "GeoTaggedImage", "GetMap", "GlobalMotion", "GoalError", "GoalHandle", "GoToWaypoint", "GpsRawInfo", "Heartbeat",
    "Image", "InvalidArgument", "InvalidParameterValueException", "InvalidType", "Land", "LoginRefused", "Map",
    "Node", "NodeDestroyed",
    "NotConnectedError", "NotGranted", "OperatorPresence", "Parameter", "ParameterAlreadyDeclaredException",
    "ParameterDescriptor", "ParameterError", "ParameterNotDeclaredException",
    "ProvidedService", "Publisher", "RangeFinderData", "RobotClient", "RobotError", "RobotInfo",
    "RobotNotice", "RobotStatus",
    "RoslinkError", "RoslinkMessage", "Service", "ServiceError", "ServiceTimeout", "SetMode",
    "SetParametersResult", "StateSubscription",
    "Subscription", "SubscriptionFailed", "Takeoff", "Timer", "Twist", "WaitTimeout", "create_node", "init", "ok",
    "shutdown", "spin", "spin_once", "spin_until_future_complete", "try_shutdown",
]


def __getattr__(name: str) -> Any:
    """Load the rclpy-shaped classes from ``node.py`` on first access (PEP 562)."""
    if name in _FROM_NODE:
        from . import node

        value = getattr(node, name)
        globals()[name] = value  # later lookups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
