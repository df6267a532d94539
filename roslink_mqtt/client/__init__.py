"""Client SDK for programs without ROS (core install: paho-mqtt, orjson, pyyaml — no rclpy, no amqtt).

Two ways in:

* :class:`RobotClient` — one login to the fleet's broker: robots and their presence, typed ROSLink state,
  commands, service calls and actions (sync and asyncio), parameters, snapshots, video, services and actions
  provided to ROS. Everything it returns is exported here, with the errors a program catches (every error class
  is in :mod:`roslink_mqtt.client.errors`; typed dict shapes in :mod:`roslink_mqtt.client.results`).
* :mod:`roslink_mqtt.client.rclpy` — the rclpy-shaped API (``create_node``, ``spin``, publishers, subscriptions,
  services, clients, actions, parameters) with rclpy's names and module layout, so porting code written there to a
  ROS node is mostly a change of imports; but messages are dicts and types are names, which rclpy refuses
  (docs/sdk.md, *Porting to rclpy*).

The ROSLink message classes (``GlobalMotion``, ``Twist`` …) are in :mod:`roslink_mqtt.client.messages`.
See docs/sdk.md.

Names this package exported before (the rclpy-shaped API, the message classes) still work for one release, with a
``DeprecationWarning`` that gives the new import (:func:`__getattr__` below).
"""

from typing import Any

from .._deprecation import moved_name
from ..protocol.control import AccessReport
from ..protocol.description import RobotDescription
from ..protocol.lease import ControlState
from ..protocol.link import LinkReport
from .action_servers import ServedAction
from .control import StopReport
from .directory import RobotInfo
from .errors import (
    CommandNotConfirmed,
    CommandRefused,
    ConnectError,
    GoalError,
    InvalidArgument,
    LoginRefused,
    NotConnectedError,
    NotGranted,
    ParameterError,
    RobotError,
    RobotNotice,
    RoslinkError,
    ServiceError,
    ServiceTimeout,
    SnapshotError,
    SubscriptionFailed,
    WaitTimeout,
)
from .goals import GoalHandle
from .providers import ProvidedService
from .robot_client import RobotClient
from .snapshots import Snapshot
from .subscriptions import StateSubscription
from .video import VideoSubscription

__all__ = [
    "AccessReport", "CommandNotConfirmed", "CommandRefused", "ConnectError", "ControlState", "GoalError",
    "GoalHandle", "InvalidArgument", "LinkReport", "LoginRefused", "NotConnectedError", "NotGranted",
    "ParameterError", "ProvidedService", "RobotClient", "RobotDescription", "RobotError", "RobotInfo",
    "RobotNotice", "RoslinkError", "ServedAction", "ServiceError", "ServiceTimeout", "Snapshot", "SnapshotError",
    "StateSubscription", "StopReport", "SubscriptionFailed", "VideoSubscription", "WaitTimeout",
]

_RCLPY = "roslink_mqtt.client.rclpy"
_MOVED: dict[str, str] = {
    **dict.fromkeys(("Ack", "Arm", "Disarm", "EmergencyStop", "GeoTaggedImage", "GetMap", "GlobalMotion",
                     "GoToWaypoint", "GpsRawInfo", "Heartbeat", "Image", "Land", "Map", "RangeFinderData",
                     "RobotStatus", "RoslinkMessage", "SetMode", "Takeoff", "Twist"), "roslink_mqtt.client.messages"),
    **dict.fromkeys(("create_node", "init", "ok", "shutdown", "spin", "spin_once", "spin_until_future_complete",
                     "try_shutdown"), _RCLPY),
    **dict.fromkeys(("Client", "Node", "Publisher", "Service", "Subscription", "Timer"), f"{_RCLPY}.node"),
    **dict.fromkeys(("Parameter", "ParameterDescriptor", "SetParametersResult"), f"{_RCLPY}.parameter"),
    **dict.fromkeys(("InvalidParameterValueException", "ParameterAlreadyDeclaredException",
                     "ParameterNotDeclaredException"), f"{_RCLPY}.exceptions"),
    "NodeDestroyed": f"{_RCLPY}.exceptions",
    "InvalidType": "roslink_mqtt.client.errors",
    "OperatorPresence": "roslink_mqtt.client.presence",
}


def __getattr__(name: str) -> Any:
    """The names that moved (PEP 562): still there for one release, with a warning giving the new import."""
    return moved_name(__name__, name, _MOVED)
