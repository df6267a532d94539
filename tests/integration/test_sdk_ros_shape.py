"""The SDK and the bridge read one ROS-shape <-> ROSLink field mapping (issue 14, SDK surface).

Round trip through both sides: the bridge builds a real ROS message from a
ROSLink payload, the message is written as the ROS-shaped dict an rclpy
program would publish, and the SDK turns that back into the same payload. A
field renamed on one side only breaks the trip; the source check keeps either
side from restating the table.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import pytest

import roslink_mqtt
from roslink_mqtt.bridge.core.presets.command import COMMAND_PRESETS
from roslink_mqtt.client.rclpy.node import ros_shaped_to_roslink
from roslink_mqtt.ros_shape import POINT_FIELDS, TWIST_FIELDS

geometry = pytest.importorskip("geometry_msgs.msg")
PACKAGE = Path(roslink_mqtt.__file__).parent
TWIST = {"lx": 0.25, "ly": -0.5, "lz": 1.0, "ax": 0.125, "ay": -2.0, "az": 0.75}
WAYPOINT = {"x": 1.5, "y": -2.25, "z": 3.0, "frame_type": 0}


def _xyz(vector: Any) -> dict[str, float]:
    return {"x": vector.x, "y": vector.y, "z": vector.z}


@pytest.mark.parametrize("ros_type", ["Twist", "TwistStamped"])
def test_twist_round_trip(ros_type: str) -> None:
    msg = COMMAND_PRESETS["twist"].build(TWIST, getattr(geometry, ros_type))
    twist = msg.twist if ros_type == "TwistStamped" else msg
    as_rclpy_dict = {"linear": _xyz(twist.linear), "angular": _xyz(twist.angular)}
    assert ros_shaped_to_roslink("twist", as_rclpy_dict) == TWIST


@pytest.mark.parametrize("ros_type", ["PoseStamped", "PointStamped"])
def test_waypoint_round_trip(ros_type: str) -> None:
    msg = COMMAND_PRESETS["go_to_waypoint"].build(WAYPOINT, getattr(geometry, ros_type))
    point = msg.pose.position if ros_type == "PoseStamped" else msg.point
    as_rclpy_dict = {"pose": {"position": _xyz(point)}}
    assert ros_shaped_to_roslink("go_to_waypoint", as_rclpy_dict) == {k: WAYPOINT[k] for k in POINT_FIELDS}


def test_partial_ros_twist_defaults_to_zero() -> None:
    assert ros_shaped_to_roslink("twist", {"linear": {"x": 0.2}}) == {**dict.fromkeys(TWIST, 0.0), "lx": 0.2}


def test_roslink_shaped_dicts_pass_unchanged() -> None:
    assert ros_shaped_to_roslink("twist", {"lx": 0.2}) == {"lx": 0.2}
    assert ros_shaped_to_roslink("go_to_waypoint", WAYPOINT) == WAYPOINT


@pytest.mark.parametrize("module", ["client/rclpy/node.py", "bridge/core/presets/command.py"])
def test_neither_side_restates_the_twist_fields(module: str) -> None:
    fields = {field for field, _part, _axis in TWIST_FIELDS}
    tree = ast.parse((PACKAGE / module).read_text())
    literals = {node.value for node in ast.walk(tree) if isinstance(node, ast.Constant)}
    assert not fields & literals, f"{module} names ROSLink twist fields itself: use roslink_mqtt.ros_shape"
