"""The shapes of what RobotClient returns from the robot's ROS side, as types a checker can follow.

A service's response and a state stream's generic payload are JSON objects whose fields the robot's ROS type decides
(the description's layout says which): :data:`JsonObject`. Parameters are ROS parameter values: :data:`ParameterValue`.
A set's outcome and a description are JSON objects of known fields: TypedDicts, so they stay the dicts they always
were (``result["successful"]``) while a type checker knows each field.
"""

from __future__ import annotations

from typing import TypeAlias, TypedDict

from ..protocol.json_value import JsonObject, JsonValue

__all__ = ["JsonObject", "JsonValue", "ParameterDescription", "ParameterValue", "SetResult"]

# A ROS parameter's value (null: not set); arrays hold one type (docs/protocol.md, "Parameters")
ParameterValue: TypeAlias = None | bool | int | float | str | list[bool] | list[int] | list[float] | list[str]


class SetResult(TypedDict):
    """One parameter's outcome of :meth:`RobotClient.set_parameters`, as the node's own validation answered."""

    successful: bool
    reason: str


class _Descriptor(TypedDict):
    type: str  # bool, integer, double, string, byte_array, bool_array … not_set
    description: str
    read_only: bool
    dynamic_typing: bool


class ParameterDescription(_Descriptor, total=False):
    """One parameter's descriptor (:meth:`RobotClient.describe_parameters`); the ranges only when it has one."""

    additional_constraints: str
    floating_point_range: dict[str, float]  # {"from", "to", "step"}
    integer_range: dict[str, int]
