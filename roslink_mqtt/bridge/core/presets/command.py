"""ROSLink command payload (already validated) → the ROS message a rule publishes.

Velocity limits are not applied here but in :mod:`..safety`, on every Twist
the bridge publishes, so a generic rule cannot bypass them either.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ....ros_shape import fill_point, fill_twist

Payload = dict[str, Any]

WAYPOINT_FRAMES = {0: "map", 2: "base_link"}


class CommandRefused(ValueError):
    """A well-formed command this robot's mapping cannot carry out; the text goes to the sender."""


@dataclass(frozen=True, slots=True)
class CommandBehaviour:
    """What a command does to the robot's motion, as data the bridge's command endpoint reads.

    Velocity is not here: any rule on a velocity type (preset or generic) is motion, recognised by its ROS type,
    so that limits and the dead-man cannot be bypassed by choosing another rule.
    """

    moves_robot: bool = False  # an autonomous goal (waypoint, takeoff): refused while motion is blocked,
    #                            cancelled by the failsafe when its operator or the broker goes away
    blocks_motion: str | None = None  # refuse motion after it, until resumed ("emergency stop by <user>")
    resumes_motion: bool = False  # lifts a block (arm); a service-backed arm lifts it only when the service succeeds
    latched: bool = False  # its ROS publisher is transient-local: a node that starts later still sees it
    never_stale: bool = False  # executed whatever its sequence number and without operator presence
    #                            (a stop from anyone granted must never be dropped as old or unannounced)


ORDINARY = CommandBehaviour()


@dataclass(frozen=True, slots=True)
class CommandPreset:
    name: str
    ros_types: tuple[str, ...]
    build: Callable[[Payload, type], Any]
    behaviour: CommandBehaviour = ORDINARY


def _is_stamped(cls: type[Any]) -> bool:
    return "header" in cls.get_fields_and_field_types()


def twist(payload: Payload, cls: type) -> Any:
    msg = cls()
    fill_twist(msg.twist if _is_stamped(cls) else msg, payload)
    return msg


def go_to_waypoint(payload: Payload, cls: type) -> Any:
    frame = WAYPOINT_FRAMES.get(payload["frame_type"])
    if frame is None:
        raise CommandRefused(
            f"frame_type {payload['frame_type']} is not supported by this robot's go_to_waypoint mapping "
            f"(supported: {', '.join(f'{k} {v}' for k, v in WAYPOINT_FRAMES.items())})")
    msg = cls()
    msg.header.frame_id = frame
    point = msg.pose.position if hasattr(msg, "pose") else msg.point
    fill_point(point, payload)
    if hasattr(msg, "pose"):
        msg.pose.orientation.w = 1.0
    return msg


def _signal(value: bool) -> Callable[[Payload, type], Any]:
    """Commands without arguments: std_msgs/Empty, or std_msgs/Bool carrying ``value``."""
    def build(_payload: Payload, cls: type) -> Any:
        msg = cls()
        if hasattr(msg, "data"):
            msg.data = value
        return msg
    return build


def takeoff(payload: Payload, cls: type) -> Any:
    msg = cls()
    if hasattr(msg, "data"):
        msg.data = float(payload["altitude"])
    return msg


def set_mode(payload: Payload, cls: type) -> Any:
    msg = cls()
    msg.data = payload["mode"]
    return msg


_EMPTY, _BOOL = "std_msgs/msg/Empty", "std_msgs/msg/Bool"

COMMAND_PRESETS: dict[str, CommandPreset] = {p.name: p for p in (
    CommandPreset("twist", ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"), twist),
    CommandPreset("go_to_waypoint", ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PointStamped"),
                  go_to_waypoint, CommandBehaviour(moves_robot=True)),
    CommandPreset("takeoff", ("std_msgs/msg/Float64", "std_msgs/msg/Float32", _EMPTY), takeoff,
                  CommandBehaviour(moves_robot=True)),
    CommandPreset("land", (_EMPTY, _BOOL), _signal(True)),
    CommandPreset("arm", (_EMPTY, _BOOL), _signal(True), CommandBehaviour(resumes_motion=True)),
    CommandPreset("disarm", (_EMPTY, _BOOL), _signal(False), CommandBehaviour(blocks_motion="disarmed")),
    CommandPreset("set_mode", ("std_msgs/msg/String",), set_mode),
    CommandPreset("get_map", (_EMPTY, _BOOL), _signal(True)),
    CommandPreset("emergency_stop", (_BOOL, _EMPTY), _signal(True),
                  CommandBehaviour(blocks_motion="emergency stop", latched=True, never_stale=True)),
)}
