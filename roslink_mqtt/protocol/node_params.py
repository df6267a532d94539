"""Control bodies for the parameters of SDK nodes (docs/protocol.md, "Parameters of SDK nodes").

The helium design of ROSLink gives programs without ROS parameters "in exactly the same way as ROS": an SDK
node declares parameters, and ROS tools (``ros2 param``, rqt, any parameter client) read and set them.

* :class:`ParamDeclaration`, retained on ``from/<user>/declare/<node>``: every parameter the SDK node has
  declared, with its value, type, description and read-only flag, and the node's presence ``client_id``. While
  that client is live the bridge holds a ROS node named ``<node>`` (in the bridge's namespace) with these
  parameters. An empty retained message withdraws it; so does the client's last-will.
* :class:`ParamSetRequest`, on ``to/<user>/param_set/<node>``: a ROS client set parameters of that node; the
  SDK runs its on-set callbacks and answers with
* :class:`ParamSetResult`, on ``from/<user>/param_result/<node>``: accepted (the SDK now holds the values) or
  refused with a reason, which the ROS client receives as its ``SetParametersResult``.

Values and types follow :mod:`.params` (:func:`~.params.ros_type_of`, :func:`~.params.check_value`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from ..topics import TopicTree
from .body import SENDER, AnyJson, BodyField, Boolean, Choice, Id, NestedBody, Obj, Text, body_of, read, refuse, write
from .control import MAX_CALL_ID
from .errors import ProtocolError
from .params import TYPE_CODES, check_value

MAX_PARAMETERS = 256  # parameters one SDK node may declare
MAX_DESCRIPTION = 1024  # characters of a description
MAX_REASON = 1024  # characters of a refusal reason
# ROS node names: a letter or underscore first, then letters, digits, underscores (rcl's rule)
NODE_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,254}")
# ROS parameter names: tokens of letters, digits and underscores joined by dots (``pid.kp``)
PARAMETER_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*")
DECLARABLE_TYPES = tuple(name for name in TYPE_CODES if name != "byte_array")
_DOC, _R, _U = TopicTree(), "<robot>", "<user>"


def check_node_name(name: str) -> str:
    """``name`` if it can name a ROS node (``legacy_arm``); ProtocolError otherwise."""
    if not isinstance(name, str) or not NODE_NAME.fullmatch(name):
        raise ProtocolError(f"node name {name!r} cannot name a ROS node: letters, digits and underscores, "
                            "not starting with a digit"[:300])
    return name


def check_parameter_name(name: str) -> str:
    if not isinstance(name, str) or len(name) > 255 or not PARAMETER_NAME.fullmatch(name):
        raise ProtocolError(f"parameter name {name!r} is not a ROS parameter name (letters, digits, underscores, "
                            "dot-separated tokens, e.g. 'pid.kp')"[:300])
    return name


@dataclass(frozen=True, slots=True)
class DeclaredParameter(NestedBody):
    """One declared parameter: its value (None: not set yet), ROS type name, description, read-only flag."""

    value: Any
    type: str
    description: str = ""
    read_only: bool = False

    FIELDS = (
        BodyField("value", AnyJson(), False, "its value, of `type` (null or left out: declared without one)", None,
                  written="null"),
        BodyField("type", Choice(DECLARABLE_TYPES), True, "a ROS parameter type (`not_set`: dynamically typed)"),
        BodyField("description", Text(0, MAX_DESCRIPTION), False, "what it is for", "", written="nonempty"),
        BodyField("read_only", Boolean(), False, "ROS clients may not set it", False, written="nonempty"),
    )

    def to_body(self) -> dict[str, Any]:  # an empty description and a false flag are left out
        return body_of(self.FIELDS, self)

    @classmethod
    def from_body(cls, name: str, body: Any) -> DeclaredParameter:
        """One entry of a declaration's ``parameters`` (its name says where a refusal points)."""
        where = f"parameters.{name}"
        try:
            got = read(cls.FIELDS, body, shape='expected an object {"value": …, "type": "double"}')
        except ProtocolError as err:
            text = str(err)
            raise ProtocolError(f"{where}: {text}" if text.startswith(("expected", "unknown")) else
                                f"{where}.{text}"[:300]) from None
        if got["value"] is not None:
            try:
                got["value"] = check_value(got["value"], got["type"])
            except ProtocolError as err:
                raise ProtocolError(f"{where}.value: {err}") from None
        return cls(**got)


@dataclass(frozen=True, slots=True)
class ParamDeclaration:
    """The parameters of one SDK node, retained on ``from/<user>/declare/<node>`` (read by the bridge)."""

    client_id: str
    parameters: dict[str, DeclaredParameter] = field(default_factory=dict)

    FIELDS = (
        BodyField("client_id", SENDER, True,
                  "the SDK node's presence client: the ROS node exists while it is live", names="sender"),
        BodyField("parameters", Obj(MAX_PARAMETERS), True,
                  f"name → `{{\"value\", \"type\", \"description\", \"read_only\"}}` (at most {MAX_PARAMETERS}): "
                  "`type` is a ROS parameter type (`bool`, `integer`, `double`, `string`, `bool_array`, "
                  "`integer_array`, `double_array`, `string_array`, or `not_set` for a dynamically typed "
                  "parameter); `value` null: declared without a value"),
    )
    QOS = 1
    RETAINED = True

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamDeclaration:
        got = read(cls.FIELDS, data, shape='expected a JSON object {"client_id": …, "parameters": {…}}')
        out = {}
        for name, spec in got["parameters"].items():
            try:
                check_parameter_name(name)
                out[name] = DeclaredParameter.from_body(name, spec)
            except ProtocolError as err:
                why = f"parameters: {err}" if not str(err).startswith("parameters.") else str(err)
                raise refuse(why, got, cls.FIELDS) from None
        return cls(got["client_id"], out)


@dataclass(frozen=True, slots=True)
class ParamSetRequest:
    """A ROS client sets parameters of an SDK node: ``to/<user>/param_set/<node>`` (read by the SDK)."""

    id: str | int
    parameters: dict[str, Any]
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Id(MAX_CALL_ID), True, "the bridge's, `<robot>-p<n>`: echo it in the result",
                  docs_type="string"),
        BodyField("parameters", Obj(), True, "name → new value, as one ROS `set_parameters` call asked "
                                             "(all or none: the SDK node accepts or refuses them together)"),
        BodyField("client_id", Text(), False, "the declaring program's presence id (other programs of the "
                                              "user ignore the request)", None),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamSetRequest:
        return cls(**read(cls.FIELDS, data, shape="param_set: expected a JSON object", strict=False,
                          what="param_set"))


@dataclass(frozen=True, slots=True)
class ParamSetResult:
    """The SDK node's answer to a :class:`ParamSetRequest`, on ``from/<user>/param_result/<node>``."""

    id: str | int
    successful: bool
    reason: str = ""
    client_id: str | None = None

    FIELDS = (
        BodyField("id", Id(MAX_CALL_ID), True, "the request's id", docs_type="string or integer"),
        BodyField("successful", Boolean(), True, "true: the node took every value; false: none (see `reason`)"),
        BodyField("reason", Text(0, MAX_REASON), False, f"why it refused (at most {MAX_REASON} characters); the "
                                                        "ROS client receives it", "", docs_type="string",
                  written="nonempty"),
        BodyField("client_id", SENDER, False, "the sender's id", None, names="sender"),
    )
    QOS = 1
    RETAINED = False

    def to_json(self) -> bytes:  # an empty reason is left out
        return write(self.FIELDS, self)

    @classmethod
    def from_json(cls, data: bytes | bytearray | memoryview | str) -> ParamSetResult:
        return cls(**read(cls.FIELDS, data, shape='expected a JSON object {"id": …, "successful": true}'))


NODE_PARAM_BODIES: tuple[tuple[str, str, type], ...] = (
    ("SDK node parameter declaration", f"`{_DOC.declare(_R, _U, '<node>')}`", ParamDeclaration),
    ("SDK node parameter set", f"`{_DOC.param_set(_R, _U, '<node>')}`", ParamSetRequest),
    ("SDK node parameter result", f"`{_DOC.param_result(_R, _U, '<node>')}`", ParamSetResult),
)
