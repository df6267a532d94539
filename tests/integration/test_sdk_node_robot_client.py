"""``Node.robot_client`` is the node's RobotClient; ``Node.client`` still answers, with a DeprecationWarning.

The old name read as the rclpy-style :class:`Client` (a service client), so it
was renamed; code using it keeps working for one release and is told to move.
No broker is needed: the property is checked on a node built without connecting.
"""

from __future__ import annotations

import warnings

import pytest

from roslink_mqtt.client.rclpy.node import Client, Node


def _unconnected_node(robot_client: object) -> Node:
    node = Node.__new__(Node)  # skip __init__: it connects
    node.robot_client = robot_client  # type: ignore[assignment]
    return node


def test_client_is_a_deprecated_alias_of_robot_client() -> None:
    marker = object()
    node = _unconnected_node(marker)
    with pytest.warns(DeprecationWarning, match="Node.robot_client"):
        assert node.client is marker


def test_robot_client_does_not_warn() -> None:
    marker = object()
    node = _unconnected_node(marker)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert node.robot_client is marker


def test_the_old_name_is_not_the_service_client_class() -> None:
    assert "robot_client" in (Node.__doc__ or "")
    assert Client is not Node.client  # the property, not the rclpy-style Client
