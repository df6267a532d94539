"""Moved to :mod:`roslink_mqtt.client.rclpy.action` (rclpy's name for it); this name goes in the next release."""

from typing import Any

from .._deprecation import moved_module
from .rclpy import action as _moved

moved_module(__name__, _moved.__name__)


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
