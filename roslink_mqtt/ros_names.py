"""ROS names, read and written in one place: interface types (``pkg/msg/Type``) and graph names (``/ns/node``).

They share the ``/`` of MQTT topics and nothing else: topics are :mod:`roslink_mqtt.topics`'s. A check
(tests/unit/test_one_topic_grammar.py) keeps every other module from splitting or formatting either by hand.
ROS-free: the SDK and the config checks use it as the bridge does.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from typing import TypeGuard

SEPARATOR = "/"
INTERFACE_KINDS = ("msg", "srv", "action")
_WELL_FORMED = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/(msg|srv|action)/[A-Z][A-Za-z0-9]*$")


def interface_parts(name: str) -> tuple[str, str, str] | None:
    """``geometry_msgs/msg/Twist`` → (``geometry_msgs``, ``msg``, ``Twist``); None unless three non-empty parts."""
    parts = name.split(SEPARATOR) if isinstance(name, str) else []
    if len(parts) != 3 or not all(parts):
        return None
    return parts[0], parts[1], parts[2]


def is_interface(name: str, kind: str) -> bool:
    """Whether ``name`` is a ``pkg/<kind>/Type`` name (``kind``: msg, srv or action)."""
    parts = interface_parts(name)
    return parts is not None and parts[1] == kind


def well_formed(name: object, kind: str) -> TypeGuard[str]:
    """Whether ``name`` is spelled as ROS spells a ``kind`` type: ``pkg_name/<kind>/TypeName`` (the config checks)."""
    return isinstance(name, str) and bool(_WELL_FORMED.match(name)) and is_interface(name, kind)


def mentions_kind(name: str, kind: str) -> bool:
    """Whether ``name`` looks meant as a ``kind`` type, well formed or not (``/std_srvs/srv/SetBool``): which
    example an error message should show."""
    return f"{SEPARATOR}{kind}{SEPARATOR}" in name


def package_of(name: str) -> str:
    """The package of an interface name (``std_srvs/srv/Trigger`` → ``std_srvs``)."""
    return name.partition(SEPARATOR)[0]


def interface_name(namespaces: Sequence[str], type_name: str) -> str:
    """rosidl's (namespaces, name) of a type → ``pkg/msg/Type``."""
    return SEPARATOR.join([*namespaces, type_name])


def nested_message(field_type: str) -> str | None:
    """A field's type as rosidl spells a nested message (``geometry_msgs/Vector3``) → ``geometry_msgs/msg/Vector3``;
    None for primitives, sequences and arrays (``sequence<pkg/Type>``, ``pkg/Type[3]``)."""
    if field_type.count(SEPARATOR) != 1 or field_type.startswith("sequence<") or field_type.endswith("]"):
        return None
    package, _, type_name = field_type.partition(SEPARATOR)
    return interface_name((package, "msg"), type_name)


def relative(name: str) -> str:
    """A graph name without its leading and trailing ``/`` (``/reset`` → ``reset``)."""
    return name.strip(SEPARATOR)


def flat(name: str) -> str:
    """A graph name as one topic level: ``/arm/home`` → ``arm_home`` (a private ``~`` dropped)."""
    return name.strip(SEPARATOR + "~").replace(SEPARATOR, "_")


def absolute(*parts: str) -> str:
    """``absolute("bench", "odom")`` → ``/bench/odom``: a fully qualified topic, service or node name."""
    return SEPARATOR + SEPARATOR.join(relative(p) for p in parts if relative(p))


def child(base: str, name: str) -> str:
    """A name below a node or namespace: ``child("/turtlesim", "get_parameters")`` → ``/turtlesim/get_parameters``."""
    return base.rstrip(SEPARATOR) + SEPARATOR + relative(name)


def action_status_topic(action: str) -> str:
    """The topic every server of ``action`` publishes its goals' status on: ``fibonacci`` →
    ``fibonacci/_action/status`` (a relative name stays relative: resolved in the node's namespace, as the action)."""
    return child(action, "_action/status")


def msg_field_message(field_type: str, package: str) -> tuple[str, str] | None:
    """A ``.msg`` field's type (its first token) → the (package, name) of the message it uses; None for a
    primitive. ``geometry_msgs/Pose[]`` → (geometry_msgs, Pose); ``Pose`` in package ``geometry_msgs`` → the same;
    ``pkg/msg/Type`` too. Bounds and arrays (``string<=5``, ``float64[36]``) are not part of the type."""
    base = field_type.split("[", 1)[0].split("<=", 1)[0]
    if base in MSG_PRIMITIVES:
        return None
    parts = base.split(SEPARATOR)
    return (package, parts[0]) if len(parts) == 1 else (parts[0], parts[-1])


def msg_reference(package: str, name: str) -> str:
    """How a ``ros2msg`` schema names a message type it includes: ``geometry_msgs/Pose``."""
    return SEPARATOR.join((package, name))


MSG_PRIMITIVES = frozenset({"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
                            "uint32", "int64", "uint64", "string", "wstring"})
