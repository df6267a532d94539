"""A JSON value as a type checker can follow it: what orjson reads, recursively (no ``Any``).

Used where the robot's ROS types decide a payload's fields (a service response, a generic state stream, a field
layout): the SDK returns these, and a program narrows them (``isinstance``) where it relies on a field's type.
"""

from __future__ import annotations

from typing import TypeAlias

JsonValue: TypeAlias = None | bool | int | float | str | list["JsonValue"] | dict[str, "JsonValue"]
JsonObject: TypeAlias = dict[str, JsonValue]
