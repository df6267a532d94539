"""Load ROS interface classes from their names (``geometry_msgs/msg/Twist``)."""

from __future__ import annotations

import importlib
from functools import cache


class UnknownTypeError(ValueError):
    """The named ROS interface is not installed (or the name is malformed)."""


@cache
def load_interface(name: str) -> type:
    """The message, service or action class for ``pkg/msg/Type``, ``pkg/srv/Type`` or ``pkg/action/Type``."""
    parts = name.split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(parts):
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
