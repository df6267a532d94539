"""ROS type names and preset/type compatibility, checked without ROS.

The bridge checks every rule against the real ROS classes when it starts, but the fleet file is also read
where there is no ROS at all (``roslink-mqtt fleet`` on a laptop, the broker host). A typo such as
``nav_msgs/msg/Odometryy``, or a ``twist`` preset on ``PoseStamped``, should be caught there, with the
file and line, not on the robot. So this module knows:

* the common_interfaces types with their fields (:mod:`.interface_table`, generated from the ROS wheels
  by tools/ros_interfaces.py and checked against them by a test), and
* which ROS types each ROSLink preset accepts (the same lists as the bridge's presets; a test keeps them
  equal, since this package must not import the bridge).

A type from any other package (a robot's own ``my_robot_msgs``) cannot be checked here: that is a note,
not an error, and the bridge still checks it at start.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from functools import cache
from typing import TypedDict, cast

from ..ros_names import interface_name, interface_parts, is_interface, nested_message, package_of
from .interface_table import TABLE

# What each ROSLink preset accepts as ros_type (bridge/core/presets/{state,command}.py hold the converters).
STATE_PRESET_TYPES: dict[str, tuple[str, ...]] = {
    "robot_status": ("sensor_msgs/msg/BatteryState",),
    "global_motion": ("nav_msgs/msg/Odometry", "geometry_msgs/msg/PoseStamped",
                      "geometry_msgs/msg/PoseWithCovarianceStamped"),
    "gps_raw_info": ("sensor_msgs/msg/NavSatFix",),
    "range_finder_data": ("sensor_msgs/msg/LaserScan",),
    "image": ("sensor_msgs/msg/CompressedImage",),
    "map": ("nav_msgs/msg/OccupancyGrid",),
}
_EMPTY, _BOOL = "std_msgs/msg/Empty", "std_msgs/msg/Bool"
COMMAND_PRESET_TYPES: dict[str, tuple[str, ...]] = {
    "twist": ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped"),
    "go_to_waypoint": ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PointStamped"),
    "takeoff": ("std_msgs/msg/Float64", "std_msgs/msg/Float32", _EMPTY),
    "land": (_EMPTY, _BOOL),
    "arm": (_EMPTY, _BOOL),
    "disarm": (_EMPTY, _BOOL),
    "set_mode": ("std_msgs/msg/String",),
    "get_map": (_EMPTY, _BOOL),
    "emergency_stop": (_BOOL, _EMPTY),
}
PRESET_TYPES = {**STATE_PRESET_TYPES, **COMMAND_PRESET_TYPES}
# Command presets that may call a ROS service instead of publishing, and the services they can call.
SERVICE_PRESETS = ("takeoff", "land", "arm", "disarm", "get_map", "emergency_stop")
SERVICE_TARGETS = ("std_srvs/srv/Trigger", "std_srvs/srv/SetBool", "std_srvs/srv/Empty")
# Any mqtt_to_ros rule of these types is a velocity output (clamped, zeroed by every failsafe stop).
VELOCITY_TYPES = ("geometry_msgs/msg/Twist", "geometry_msgs/msg/TwistStamped")

UNCHECKED = "cannot be checked here; the bridge checks it at start"


class _GeneratedTable(TypedDict):
    """The shape of the generated TABLE (tools/ros_interfaces.py writes it; a plain dict literal infers loosely)."""

    source: str
    packages: list[str]
    msg: dict[str, dict[str, str]]
    srv: dict[str, dict[str, dict[str, str]]]


@dataclass(frozen=True)
class InterfaceTable:
    """The shipped table: which packages it covers, and every msg/srv type in them with its fields."""

    source: str
    packages: frozenset[str]
    messages: dict[str, dict[str, str]]
    services: dict[str, dict[str, dict[str, str]]]

    def covers(self, name: str) -> bool:
        """Whether ``name``'s package is one the table lists completely (so a missing type is a mistake)."""
        return package_of(name) in self.packages

    def known(self, name: str) -> bool:
        return name in self.messages or name in self.services

    def type_problem(self, name: str) -> str | None:
        """Why ``name`` (``pkg/msg/Type`` or ``pkg/srv/Type``) is wrong, or None when it exists or is unchecked."""
        if not self.covers(name) or self.known(name):
            return None
        parts = interface_parts(name)
        if parts is None:
            return f"'{name}' is not a ROS type name like geometry_msgs/msg/Twist"
        package, kind, type_name = parts
        same_kind = sorted(p[2] for p in map(interface_parts, self.messages if kind == "msg" else self.services)
                           if p is not None and p[:2] == (package, kind))
        hint = difflib.get_close_matches(type_name, same_kind, n=1, cutoff=0.6)
        other_kind = "srv" if kind == "msg" else "msg"
        other_table = self.services if kind == "msg" else self.messages
        if not hint and interface_name((package, other_kind), type_name) in other_table:
            hint_text = f" ({package}/{other_kind}/{type_name} is a{'' if kind == 'msg' else 'n'} " \
                        f"{'service' if kind == 'msg' else 'message'})"
        elif hint:
            hint_text = f" (did you mean '{package}/{kind}/{hint[0]}'?)"
        else:
            hint_text = f" ({package} {kind} types: {', '.join(same_kind) or 'none'})"
        return f"unknown type '{name}': '{package}' has no {kind} '{type_name}'{hint_text}"

    def field_path_problem(self, name: str, path: str) -> str | None:
        """Why ``path`` (``pose.position.x``) is not a field of message ``name``; None if it is or is unchecked."""
        fields = self.messages.get(name)
        if fields is None:
            return None
        for part in path.split("."):
            if fields is None or part not in fields:
                return f"'{path}' is not a field of {name}"
            sub = fields[part]
            # nested messages are 'pkg/Type'; sequences, arrays and primitives end the walk (as in the bridge)
            nested = nested_message(sub)
            fields = self.messages.get(nested) if nested is not None else None
        return None


@cache
def interface_table() -> InterfaceTable:
    """The table, built once from the generated module."""
    table = cast(_GeneratedTable, TABLE)
    return InterfaceTable(source=table["source"], packages=frozenset(table["packages"]), messages=table["msg"],
                          services=table["srv"])


def preset_type_problem(preset: str, ros_type: str) -> str | None:
    """Why a rule with ``preset`` cannot carry ``ros_type`` (the bridge's words), or None."""
    if is_interface(ros_type, "srv"):
        if preset not in SERVICE_PRESETS:
            return f"preset '{preset}' publishes a message; a ROS service ({ros_type}) cannot carry it"
        if ros_type not in SERVICE_TARGETS:
            return f"preset '{preset}' can call {' or '.join(SERVICE_TARGETS)}, not {ros_type}"
        return None
    accepted = PRESET_TYPES.get(preset)
    if accepted is None:
        return (f"preset '{preset}' has no ROS conversion (presets: {', '.join(STATE_PRESET_TYPES)}; "
                f"{', '.join(COMMAND_PRESET_TYPES)})")
    if ros_type not in accepted:
        return f"preset '{preset}' needs ros_type {' or '.join(accepted)}, not {ros_type}"
    return None
