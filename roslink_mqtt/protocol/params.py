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
from .codec import MAX_CLIENT_ID
from .control import MAX_CALL_ID, BodyField, _dump, _no_unknown, _object, check_client_id
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
        BodyField("id", f"string (≤ {MAX_CALL_ID} characters) or integer", True, "yours, echoed in the reply"),
        BodyField("op", "string", True, "`get` (the `names`), `set` (the `values`), `list` (every name; `names` "
                                        "are prefixes, optional), `describe` (the `names`)"),
        BodyField("names", "array of strings", False, "parameter names, for get and describe (and list prefixes)"),
        BodyField("values", "object", False, "for set: name → value (boolean, integer, double, string, or an "
                                             "array of one of those)"),
        BodyField("client_id", f"string, 1..{MAX_CLIENT_ID} characters", False, "the sender's id, repeated in "
                                                                                "the reply"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "op": self.op}
        if self.names:
            body["names"] = list(self.names)
        if self.values:
            body["values"] = self.values
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamRequest:
        body = _object(data, 'expected a JSON object {"id": …, "op": "get", "names": […]}')
        client_id = check_client_id(body["client_id"]) if "client_id" in body else None
        rid = body.get("id")
        if not (isinstance(rid, str) and 0 < len(rid) <= MAX_CALL_ID or _is_int(rid)):
            raise ProtocolError(f"id: expected a string of 1..{MAX_CALL_ID} characters or an integer").naming(
                None, client_id)
        try:
            return cls._checked(rid, body, client_id)
        except ProtocolError as err:
            raise err.naming(rid, client_id) from None

    @classmethod
    def _checked(cls, rid: str | int, body: dict[str, Any], client_id: str | None) -> ParamRequest:
        _no_unknown(body, ("id", "op", "names", "values", "client_id"))
        op = body.get("op")
        if op not in OPS:
            raise ProtocolError(f"op: expected one of {', '.join(OPS)}, got {op!r}"[:200])
        names = body.get("names", [])
        if not isinstance(names, list) or not all(isinstance(n, str) and n for n in names) or len(names) > MAX_NAMES:
            raise ProtocolError(f"names: expected an array of at most {MAX_NAMES} non-empty strings")
        values = body.get("values", {})
        if not isinstance(values, dict) or len(values) > MAX_NAMES:
            raise ProtocolError(f"values: expected an object of at most {MAX_NAMES} parameters")
        for name, value in values.items():
            try:
                ros_type_of(value)
            except ProtocolError as err:
                raise ProtocolError(f"values.{show_key(name)}: {err}") from None
        if op in ("get", "describe") and not names:
            raise ProtocolError(f"names: '{op}' needs the parameter names")
        if op == "set" and not values:
            raise ProtocolError("values: 'set' needs at least one name → value")
        return cls(rid, op, tuple(names), values, client_id)


@dataclass(frozen=True, slots=True)
class ParamReply:
    """The answer to a :class:`ParamRequest`, on ``to/<user>/param_reply/<node>`` (read by the requester)."""

    id: str | int | None
    result: bool
    values: dict[str, Any] | None = None
    error: str | None = None
    client_id: str | None = None

    FIELDS = (
        BodyField("id", "string or integer", True, "the request's id"),
        BodyField("result", "boolean", True, "true: the node answered (see `values`); false: see `error`"),
        BodyField("values", "object", False, "get: name → value (null: not set); set: name → `{\"successful\": "
                                             "…, \"reason\": …}` (the node's own validation); list: "
                                             "`{\"names\": […]}`; describe: name → `{\"type\", \"description\", "
                                             "\"read_only\", …}`"),
        BodyField("error", "string", False, "with `result` false: why (node not available, timeout)"),
        BodyField("client_id", "string", False, "the request's `client_id`, when it had one"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        body: dict[str, Any] = {"id": self.id, "result": self.result}
        if self.result:
            body["values"] = self.values or {}
        else:
            body["error"] = self.error
        return _dump(body, self.client_id)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamReply:
        body = _object(data, "param reply: expected a JSON object")
        cid = body.get("client_id")
        values, error = body.get("values"), body.get("error")
        return cls(body.get("id"), body.get("result") is True, values if isinstance(values, dict) else {},
                   str(error) if error else None, cid if isinstance(cid, str) else None)


@dataclass(frozen=True, slots=True)
class ParamEvent:
    """A change of a node's parameters, on ``state/parameter_events/<node>`` (not retained)."""

    node: str
    new: dict[str, Any] = field(default_factory=dict)
    changed: dict[str, Any] = field(default_factory=dict)
    deleted: tuple[str, ...] = ()

    FIELDS = (
        BodyField("node", "string", True, "the ROS node's full name"),
        BodyField("new", "object", True, "parameters declared since: name → value"),
        BodyField("changed", "object", True, "parameters set since: name → new value"),
        BodyField("deleted", "array of strings", True, "parameters undeclared since"),
    )
    QOS = 0
    RETAINED = False

    def to_json(self) -> bytes:
        return _dump({"node": self.node, "new": self.new, "changed": self.changed, "deleted": list(self.deleted)},
                     None)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamEvent:
        body = _object(data, "parameter event: expected a JSON object")
        node = body.get("node")
        if not isinstance(node, str):
            raise ProtocolError("parameter event: node: expected a string")
        new, changed, deleted = body.get("new"), body.get("changed"), body.get("deleted")
        return cls(node, new if isinstance(new, dict) else {}, changed if isinstance(changed, dict) else {},
                   tuple(d for d in deleted if isinstance(d, str)) if isinstance(deleted, list) else ())


PARAM_BODIES: tuple[tuple[str, str, type], ...] = (
    ("parameter request", f"`{_DOC.param(_R, _U, '<node>')}`", ParamRequest),
    ("parameter reply", f"`{_DOC.user_topic(_R, _U, Verb.PARAM_REPLY, '<node>')}`", ParamReply),
    ("parameter event", f"`{_DOC.param_events(_R, '<node>')}`", ParamEvent),
)
