"""The velocity checks on the real ROS messages (the pure logic is in tests/unit/)."""

from __future__ import annotations

from geometry_msgs.msg import Twist, TwistStamped

from roslink_mqtt.bridge.core.safety import is_standstill


def test_standstill_is_a_stop_whatever_the_message_type() -> None:
    assert is_standstill(Twist()) and is_standstill(TwistStamped())
    moving = Twist()
    moving.angular.y = 1e-9
    assert not is_standstill(moving)
    stamped = TwistStamped()
    stamped.twist.linear.z = -0.1
    assert not is_standstill(stamped)
