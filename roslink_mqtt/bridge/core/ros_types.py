"""Load ROS interface classes from their names (``geometry_msgs/msg/Twist``)."""

from __future__ import annotations

import importlib
from functools import cache

from ...ros_names import INTERFACE_KINDS, interface_parts


class UnknownTypeError(ValueError):
    """The named ROS interface is not installed (or the name is malformed)."""


@cache
def load_interface(name: str) -> type:
    """The message, service or action class for ``pkg/msg/Type``, ``pkg/srv/Type`` or ``pkg/action/Type``."""
    parts = interface_parts(name)
    if parts is None or parts[1] not in INTERFACE_KINDS:
        raise UnknownTypeError(f"'{name}' is not a ROS type name like geometry_msgs/msg/Twist")
    package, kind, type_name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
    except ImportError:
        raise UnknownTypeError(f"unknown type '{name}': ROS package '{package}' is not installed") from None
    cls = getattr(module, type_name, None)
    if not isinstance(cls, type):
        raise UnknownTypeError(f"unknown type '{name}': '{package}' has no {kind} '{type_name}'")
    return cls
