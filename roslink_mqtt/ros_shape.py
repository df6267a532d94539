"""Where ROSLink command fields live in the ROS messages they stand for: one table, read both ways.

ROSLink flattens a ``geometry_msgs/Twist`` to ``lx … az`` and a waypoint's
position to ``x, y, z``. The SDK turns ROS-shaped dicts into those fields
(:mod:`roslink_mqtt.client.rclpy.node`), the bridge turns them back into ROS messages
(:mod:`roslink_mqtt.bridge.core.presets.command`). Both read the mapping here, so a
field cannot be renamed on one side only; this module imports neither ROS nor
MQTT, so the SDK (no rclpy) and the bridge can both use it.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

# (ROSLink field, Twist part, axis): ``lx`` is ``linear.x``
TWIST_FIELDS: tuple[tuple[str, str, str], ...] = (
    ("lx", "linear", "x"), ("ly", "linear", "y"), ("lz", "linear", "z"),
    ("ax", "angular", "x"), ("ay", "angular", "y"), ("az", "angular", "z"),
)
# go_to_waypoint's fields are the position's axes (a Point, in a PoseStamped or PointStamped)
POINT_FIELDS: tuple[str, ...] = ("x", "y", "z")


def is_ros_twist(msg: Mapping[str, Any]) -> bool:
    """A dict shaped like a ROS Twist (it has ``linear`` or ``angular``), not ROSLink's flat fields."""
    return "linear" in msg or "angular" in msg


def twist_from_ros(msg: Mapping[str, Any]) -> dict[str, Any]:
    """ROSLink twist fields from a ROS-shaped Twist dict; a missing part or axis is 0.0, as in ROS."""
    parts = {part: msg.get(part) or {} for part in ("linear", "angular")}
    return {field: parts[part].get(axis, 0.0) for field, part, axis in TWIST_FIELDS}


def is_ros_pose(msg: Mapping[str, Any]) -> bool:
    """A dict shaped like a PoseStamped (``pose``) or a Pose (``position``), not ROSLink's flat x, y, z."""
    return "pose" in msg or "position" in msg


def point_from_ros(msg: Mapping[str, Any]) -> dict[str, Any]:
    """ROSLink waypoint fields from a PoseStamped, Pose or Point dict; a missing axis is 0.0."""
    pose = msg.get("pose", msg)
    point = pose.get("position", pose) if isinstance(pose, dict) else {}
    return {axis: point.get(axis, 0.0) for axis in POINT_FIELDS}


def fill_twist(target: Any, payload: Mapping[str, Any]) -> None:
    """Set a ROS Twist object's ``linear``/``angular`` axes from ROSLink twist fields."""
    for field, part, axis in TWIST_FIELDS:
        setattr(getattr(target, part), axis, payload[field])


def fill_point(point: Any, payload: Mapping[str, Any]) -> None:
    """Set a ROS Point object's axes from ROSLink waypoint fields (as floats: ROS refuses ints there)."""
    for axis in POINT_FIELDS:
        setattr(point, axis, float(payload[axis]))
