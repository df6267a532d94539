"""Control bodies for ROS node parameters over MQTT (docs/protocol.md, "Parameters"), and their JSON values.

A user sends ``from/<user>/param/<node>`` ``{"id", "op", …}`` with ``op`` one of get, set, list, describe;
the answer comes on ``to/<user>/param_reply/<node>`` with the same id. Changes of the node's parameters
(whoever made them) are published on ``state/parameter_events/<node>``. Values are plain JSON: booleans,
integers, floats, strings and arrays of one of those (ROS's parameter types); :func:`ros_type_of` and
:func:`check_value` are the typing rules both the bridge and the SDK apply.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, TypeGuard

from ..topics import TopicTree, Verb
from .body import SENDER, AnyJson, BodyField, Boolean, Choice, Id, Obj, Strings, Text, read, refuse, write
from .control import MAX_CALL_ID
from .errors import ProtocolError
from .validate import show_key

OPS = ("get", "set", "list", "describe")
READ_OPS = ("get", "list", "describe")
MAX_NAMES = 256  # parameters in one request
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"

# ROS parameter types (rcl_interfaces/msg/ParameterType) by name, as bodies show them
TYPE_NAMES = {0: "not_set", 1: "bool", 2: "integer", 3: "double", 4: "string", 5: "byte_array", 6: "bool_array",
              7: "integer_array", 8: "double_array", 9: "string_array"}
TYPE_CODES = {name: code for code, name in TYPE_NAMES.items()}


def _is_int(v: object) -> TypeGuard[int]:
    return isinstance(v, int) and not isinstance(v, bool)


def ros_type_of(value: Any) -> str:
    """The ROS parameter type a JSON value reads as (an empty array cannot say: ``not_set``); ProtocolError else."""
    if isinstance(value, bool):
        return "bool"
    if _is_int(value):
        if not -2**63 <= value < 2**63:
            raise ProtocolError(f"{value} does not fit a 64-bit integer parameter")
        return "integer"
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ProtocolError("a double parameter must be finite")
        return "double"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        if not value:
            return "not_set"
        kinds = {ros_type_of(v) for v in value}
        if kinds <= {"integer", "double"} and "double" in kinds:
            return "double_array"
        if len(kinds) == 1 and (kind := kinds.pop()) in ("bool", "integer", "double", "string"):
            return f"{kind}_array"
        raise ProtocolError("an array parameter holds one type: booleans, integers, doubles or strings")
    raise ProtocolError(f"a parameter value is a boolean, number, string or array of one of those, "
                        f"got {type(value).__name__}")


def check_value(value: Any, declared: str) -> Any:
    """``value`` as a parameter of the ``declared`` type: an integer is a fine double; anything else must match.

    Returns the value to set (integers become floats for doubles); ProtocolError with the reason otherwise.
    """
    given = ros_type_of(value)
    if declared == given or declared == "not_set":
        return value
    if declared == "double" and given == "integer":
        return float(value)
    if declared == "double_array" and given == "integer_array":
        return [float(v) for v in value]
    if given == "not_set" and declared.endswith("_array"):
        return []
    raise ProtocolError(f"expected {declared}, got {given} {value!r}"[:300])


@dataclass(frozen=True, slots=True)
class ParamRequest:
    """A parameter request, on ``from/<user>/param/<node>`` (read by the bridge)."""

    id: str | int
    op: str
    names: tuple[str, ...] = ()
    values: dict[str, Any] = field(default_factory=dict)
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Id(MAX_CALL_ID), True, "yours, echoed in the reply", names="request"),
        BodyField("op", Choice(OPS), True, "`get` (the `names`), `set` (the `values`), `list` (every name; "
                                           "`names` are prefixes, optional), `describe` (the `names`)"),
        BodyField("names", Strings(MAX_NAMES, non_empty=True), False,
                  "parameter names, for get and describe (and list prefixes)", (), written="nonempty"),
        BodyField("values", Obj(MAX_NAMES), False, "for set: name → value (boolean, integer, double, string, or "
                                                   "an array of one of those)", {}, written="nonempty"),
        BodyField("client_id", SENDER, False, "the sender's id, repeated in the reply", None, names="sender"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # empty names and values are left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamRequest:
        got = read(cls.FIELDS, data, shape='expected a JSON object {"id": …, "op": "get", "names": […]}')
        for name, value in got["values"].items():
            try:
                ros_type_of(value)
            except ProtocolError as err:
                raise refuse(f"values.{show_key(name)}: {err}", got, cls.FIELDS) from None
        if got["op"] in ("get", "describe") and not got["names"]:
            raise refuse(f"names: '{got['op']}' needs the parameter names", got, cls.FIELDS)
        if got["op"] == "set" and not got["values"]:
            raise refuse("values: 'set' needs at least one name → value", got, cls.FIELDS)
        return cls(**got)


@dataclass(frozen=True, slots=True)
class ParamReply:
    """The answer to a :class:`ParamRequest`, on ``to/<user>/param_reply/<node>`` (read by the requester)."""

    id: str | int | None
    result: bool
    values: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", AnyJson(), True, "the request's id", None, docs_type="string or integer"),
        BodyField("result", Boolean(), True, "true: the node answered (see `values`); false: see `error`", False),
        BodyField("values", Obj(), False, "get: name → value (null: not set); set: name → `{\"successful\": "
                                          "…, \"reason\": …}` (the node's own validation); list: "
                                          "`{\"names\": […]}`; describe: name → `{\"type\", \"description\", "
                                          "\"read_only\", …}`", {}, written="null", written_if=("result", True)),
        BodyField("error", Text(), False, "with `result` false: why (node not available, timeout)", None,
                  written="null", written_if=("result", False)),
        BodyField("client_id", Text(), False, "the request's `client_id`, when it had one", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # `values` or `error` by `result` (an error null when there is none)
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamReply:
        got = read(cls.FIELDS, data, shape="param reply: expected a JSON object", strict=False, what="param reply")
        return cls(**{**got, "error": got["error"] or None})


@dataclass(frozen=True, slots=True)
class ParamEvent:
    """A change of a node's parameters, on ``state/parameter_events/<node>`` (not retained)."""

    node: str
    new: dict[str, Any] = field(default_factory=dict)
    changed: dict[str, Any] = field(default_factory=dict)
    deleted: tuple[str, ...] = ()

    FIELDS = (
        BodyField("node", Text(), True, "the ROS node's full name"),
        BodyField("new", Obj(), True, "parameters declared since: name → value", {}),
        BodyField("changed", Obj(), True, "parameters set since: name → new value", {}),
        BodyField("deleted", Strings(), True, "parameters undeclared since", ()),
    )
    QOS = 0
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamEvent:
        return cls(**read(cls.FIELDS, data, shape="parameter event: expected a JSON object", strict=False,
                          what="parameter event"))


PARAM_BODIES: tuple[tuple[str, str, type], ...] = (
    ("parameter request", f"`{_DOC.param(_R, _U, '<node>')}`", ParamRequest),
    ("parameter reply", f"`{_DOC.user_topic(_R, _U, Verb.PARAM_REPLY, '<node>')}`", ParamReply),
    ("parameter event", f"`{_DOC.param_events(_R, '<node>')}`", ParamEvent),
)
